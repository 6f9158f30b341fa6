"""Inference-time variants of one DriveRestorer on held-out restoration pairs.

Does anything done at restore time, without training, move a restorer's PSNR gain? For every
held-out clip (as ``benchmarks/restorer.py`` picks them) the restorer runs once per seed with 1
DDIM step, and the script prints the mean gain (dB, restored minus degraded PSNR against ground
truth, over all clips and split orig / novel) of:

- ``seed 0``: the plain restore;
- ``mean of K seeds``: the average of the restored frames of seeds 0..K-1 (a Monte-Carlo estimate
  of the restorer's mean output, which is what minimises the expected squared error when the
  sampled outputs scatter around the truth);
- ``correction gain a``: ``degraded + a * (restored - degraded)``, i.e. the restorer's change to its
  input scaled by ``a`` (a < 1 shrinks corrections the restorer gets wrong as often as right);
- ``restored twice``: the restorer applied to its own output;
- ``mirrored``: the clip and its structure maps flipped left-right, restored, flipped back (the
  streets are not mirror-symmetric: vehicles drive on one side).

Example::

    python benchmarks/restorer_variants.py --restorer results/restorer-dev/s8/from9500_whole_px50_900.pt \\
        --pairs results/restorer-dev/pairs-heldout --stages-per-run 2 --seeds 4 --gains 0.8 1.2 1.4
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from restorer import scored_clips  # noqa: E402  benchmarks/restorer.py


def mean_psnr(clip: np.ndarray, gt: np.ndarray) -> float:  # (T,H,W,3) float or uint8 vs uint8
    """Mean per-frame PSNR of a clip rounded and clipped to uint8 (what a saved frame holds)."""
    from recondreamer.evaluation.image_metrics import psnr

    frames = np.clip(np.round(clip), 0, 255).astype(np.uint8)
    return float(np.mean([psnr(a, b) for a, b in zip(frames, gt)]))


def print_gain_table(gains: dict[str, list[tuple[str, float]]]) -> None:
    """One row per variant: its mean gain (dB) over all clips and over the orig and novel ones."""
    print(f"{'variant':24s} {'gain dB':>7s} {'orig':>6s} {'novel':>6s}")
    for name, rows in gains.items():
        by_kind = {k: [g for kind, g in rows if kind == k] for k in ("orig", "novel")}
        split = [f"{np.mean(v):6.2f}" if v else f"{'-':>6s}" for v in by_kind.values()]
        print(f"{name:24s} {np.mean([g for _, g in rows]):7.2f} {split[0]} {split[1]}")


def variant_outputs(restorer, degraded: np.ndarray, structure, seeds: int, gains: list[float]) -> dict[str, np.ndarray]:
    """Every variant's output clip (float, 0-255) for one degraded clip."""
    from recondreamer.restorer.inference import restore_clip

    restored = [restore_clip(restorer, degraded, structure, num_steps=1, seed=seed).astype(np.float64) for seed in range(seeds)]
    change = restored[0] - degraded
    outputs = {"seed 0": restored[0]}
    outputs.update({f"mean of {k} seeds": np.mean(restored[:k], axis=0) for k in range(2, seeds + 1)})
    outputs.update({f"correction gain {gain:g}": degraded + gain * change for gain in gains})
    outputs["restored twice"] = restore_clip(restorer, restored[0].astype(np.uint8), structure, num_steps=1, seed=0)
    mirrored_structure = None if structure is None else np.ascontiguousarray(structure[..., ::-1])
    mirrored = restore_clip(restorer, np.ascontiguousarray(degraded[:, :, ::-1]), mirrored_structure, num_steps=1, seed=0)
    outputs["mirrored"] = mirrored[:, :, ::-1]
    return outputs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--restorer", required=True, help="restorer checkpoint")
    parser.add_argument("--pairs", nargs="+", required=True, help="held-out restoration-pairs directories or .npz files")
    parser.add_argument("--stages-per-run", type=int, default=2, help="training stages per pairs file, earliest to latest (0 = all; default 2)")
    parser.add_argument("--seeds", type=int, default=4, help="seeds to average, >= 1 (default 4)")
    parser.add_argument("--gains", type=float, nargs="+", default=[0.8, 1.2, 1.4], help="correction gains to try (default 0.8 1.2 1.4)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    args = parser.parse_args()
    if args.seeds < 1:
        parser.error(f"--seeds must be >= 1, got {args.seeds}")

    import torch

    from recondreamer.restorer.checkpoint import load_checkpoint
    from recondreamer.restorer.data import find_pairs_files
    from recondreamer.restorer.inference import load_restorer

    torch.set_num_threads(args.threads)
    restorer = load_restorer(args.restorer)
    clips = scored_clips(restorer, load_checkpoint(args.restorer, "restorer"), find_pairs_files(args.pairs), args.stages_per_run)
    if not clips:
        raise SystemExit(f"no held-out clips in {args.pairs}: every scene is in {args.restorer}'s training set")
    gains: dict[str, list[tuple[str, float]]] = {}  # variant -> [(kind, gain dB)]
    for index, (kind, degraded, gt, structure) in enumerate(clips):
        before = mean_psnr(degraded, gt)
        for name, output in variant_outputs(restorer, degraded, structure, args.seeds, args.gains).items():
            gains.setdefault(name, []).append((kind, mean_psnr(output, gt) - before))
        print(f"clip {index + 1}/{len(clips)} ({kind}) done", file=sys.stderr, flush=True)

    print(f"{args.restorer}: {len(clips)} held-out clips, 1 DDIM step")
    print_gain_table(gains)


if __name__ == "__main__":
    main()
