"""Whether scaling a DriveRestorer's correction could reach the +2 dB gate.

    python experiments/residual_scale.py --restorer weights/restorer_dd2_mask.pt \
        --pairs results/foundation/gate_pairs/gate-000 results/foundation/gate_pairs/gate-001 ... \
        [--scales 0 0.5 1 1.5 2 3]

Restores every gate clip once (as the gate does) and scores ``render + a * (restored - render)``
for each scale ``a``: 1 is the restorer's output, 0 the render, below 1 a shrunk correction,
above 1 an amplified one. Prints the mean PSNR gain over the render per trajectory and scale.
The best scale per trajectory is chosen on the gate clips themselves, so it is an upper bound
on what any fixed scaling could give, not a recipe. docs/foundation.md cites it.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from recondreamer.foundation.gates import gate_clips
from recondreamer.generative.data import find_pairs_files
from recondreamer.generative.inference import load_restorer, restore_clip
from recondreamer.generative.scoring import mean_psnr


def scaled(render: np.ndarray, restored: np.ndarray, scale: float) -> np.ndarray:  # (T,H,W,3) uint8 each -> uint8
    correction = restored.astype(np.float64) - render.astype(np.float64)
    return np.clip(np.round(render + scale * correction), 0, 255).astype(np.uint8)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--restorer", type=Path, required=True)
    parser.add_argument("--pairs", type=Path, nargs="+", required=True, help="gate scenes' pairs directories")
    parser.add_argument("--scales", type=float, nargs="+", default=[0.0, 0.5, 1.0, 1.5, 2.0, 3.0])
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    restorer = load_restorer(args.restorer)
    clips = gate_clips(find_pairs_files(args.pairs), restorer.unet_config.uses_structure)
    print(f"{'trajectory':10} {'clips':>5}  " + "  ".join(f"a={scale:<4g}" for scale in args.scales))
    for trajectory, items in sorted(clips.items()):
        gains = np.zeros(len(args.scales))
        for _, render, truth, structure, _ in items:
            restored = restore_clip(restorer, render, structure)
            base = mean_psnr(render, truth)
            gains += [mean_psnr(scaled(render, restored, scale), truth) - base for scale in args.scales]
        print(f"{trajectory:10} {len(items):5d}  " + "  ".join(f"{gain / len(items):+6.2f}" for gain in gains))


if __name__ == "__main__":
    main()
