"""How far should a pixel refiner be allowed to move a pixel? (``RefinerConfig.max_correction``)

For every held-out clip (as ``benchmarks/restorer.py`` picks them) the restorer restores the clip
once without its refiner, the refiner corrects that output once without a bound, and the script
prints the mean PSNR gain (dB, against the degraded clip, over all clips and split orig / novel)
of the restorer alone, of the refiner with its correction clipped to each ``--bounds`` grey levels,
and unbounded. For a whole number of grey levels, clipping the rounded correction after the fact
equals running the refiner with that ``max_correction`` (a clamp of the correction commutes with
rounding to whole levels); the script checks this on the first clip with a bound of 12 and prints
the largest difference in grey levels.

docs/generative.md cites it for the default bound of 12 grey levels (Design decisions, Refiner), measured on 4
scenes neither network trained on::

    python experiments/refiner_bound.py --restorer results/restorer-dev/s23/stage4_ref.pt \\
        --pairs results/restorer-dev/pairs-train/corpus-09[5-8]__street*.npz --bounds 2 4 8 12 16 24 32 64
"""

from __future__ import annotations

import argparse
import dataclasses
import sys

import numpy as np

from recondreamer.generative.scoring import mean_psnr, print_gain_table, scored_clips

CHECK_BOUND = 12


def clipped(restored: np.ndarray, refined: np.ndarray, bound: int) -> np.ndarray:  # (T,H,W,3) uint8 each
    """The refined clip with each pixel's change to the restored one clipped to +-``bound`` grey levels."""
    change = refined.astype(np.int16) - restored.astype(np.int16)
    return (restored.astype(np.int16) + np.clip(change, -bound, bound)).astype(np.uint8)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--restorer", required=True, help="restorer checkpoint with a pixel refiner (train-refiner output)")
    parser.add_argument("--pairs", nargs="+", required=True, help="held-out restoration-pairs directories or .npz files")
    parser.add_argument("--bounds", type=int, nargs="+", default=[2, 4, 8, 12, 16, 24, 32, 64],
                        help="bounds to try, whole grey levels >= 1 (default 2 4 8 12 16 24 32 64)")
    parser.add_argument("--stages-per-run", type=int, default=2, help="training stages per pairs file, earliest to latest (0 = all; default 2)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    args = parser.parse_args()
    if min(args.bounds) < 1:
        parser.error(f"--bounds must be whole grey levels >= 1, got {args.bounds}")

    import torch

    from recondreamer.generative.checkpoint import load_checkpoint
    from recondreamer.generative.data import find_pairs_files, structure_from_uint8
    from recondreamer.generative.inference import load_restorer, restore_clip
    from recondreamer.generative.refiner import refine_frames

    torch.set_num_threads(args.threads)
    restorer = load_restorer(args.restorer)
    if restorer.refiner is None:
        raise SystemExit(f"{args.restorer} has no pixel refiner (train one with train-refiner)")
    own_bound = restorer.refiner.config.max_correction
    restorer.refiner.config = dataclasses.replace(restorer.refiner.config, max_correction=0.0)
    clips = scored_clips(restorer, load_checkpoint(args.restorer, "restorer"), find_pairs_files(args.pairs), args.stages_per_run)
    if not clips:
        raise SystemExit(f"no held-out clips in {args.pairs}: every scene is in {args.restorer}'s training set")
    names = ["restorer alone", *(f"refiner clipped at {bound}" for bound in args.bounds), "refiner unbounded"]
    gains: dict[str, list[tuple[str, float]]] = {name: [] for name in names}  # variant -> [(kind, gain dB)]
    for index, (kind, degraded, gt, structure) in enumerate(clips):
        maps = None if structure is None else structure_from_uint8(structure)
        restored = restore_clip(restorer, degraded, structure, refine=False)
        refined = refine_frames(restorer.refiner, restored, degraded, maps)
        outputs = [restored, *(clipped(restored, refined, bound) for bound in args.bounds), refined]
        before = mean_psnr(degraded, gt)
        for name, output in zip(names, outputs):
            gains[name].append((kind, mean_psnr(output, gt) - before))
        if index == 0:
            restorer.refiner.config = dataclasses.replace(restorer.refiner.config, max_correction=float(CHECK_BOUND))
            direct = refine_frames(restorer.refiner, restored, degraded, maps)
            restorer.refiner.config = dataclasses.replace(restorer.refiner.config, max_correction=0.0)
            difference = np.abs(direct.astype(np.int16) - clipped(restored, refined, CHECK_BOUND)).max()
        print(f"clip {index + 1}/{len(clips)} ({kind}) done", file=sys.stderr, flush=True)

    print(f"{args.restorer}: {len(clips)} held-out clips; its refiner's own bound: {own_bound:g} grey levels (0: unbounded)")
    print(f"check: refiner run with max_correction {CHECK_BOUND} against its unbounded output clipped at {CHECK_BOUND}: "
          f"largest difference {difference} grey levels")
    print_gain_table(gains)


if __name__ == "__main__":
    main()
