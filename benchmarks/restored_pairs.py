"""Restoration pairs whose degraded clips are a restorer's outputs: the data of a second pass.

A restorer applied to its own output loses gain (``benchmarks/restorer_variants.py``, "restored
twice"), because it was trained on renders, not on its outputs. A second restorer trained on
pairs of (first restorer's output, ground truth) learns the errors the first one leaves. This
script writes such pairs: every input pairs file is copied with each stage's degraded clip
replaced by the first restorer's 1-step restore of it; ground truth, structure maps, sky masks
and vanishing points stay as they were. ``benchmarks/restorer.py`` on the restored held-out pairs
then prints the second pass's gain over the first pass's output, and the two-pass gain over the
render is the sum of both passes' mean gains (PSNR differences against the same ground truth add).

Example::

    python benchmarks/restored_pairs.py --restorer R1.pt --pairs results/restorer-dev/pairs-train \\
        --out results/restorer-dev/s10/pairs-train-R1

A file already in ``--out`` is kept, so an interrupted run resumes; files are written to a
temporary name first.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np


def restored_copy(restorer, content: dict) -> dict:
    """The pairs arrays with every stage's degraded clip restored once (1 DDIM step, seed 0)."""
    from recondreamer.restorer.inference import restore_clip

    structure = content["structure"] if restorer.unet_config.uses_structure else None
    restored = np.stack([restore_clip(restorer, clip, structure, num_steps=1, seed=0) for clip in content["degraded"]])
    return {**content, "degraded": restored}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--restorer", required=True, help="the first pass's restorer checkpoint")
    parser.add_argument("--pairs", nargs="+", required=True, help="restoration-pairs directories or .npz files")
    parser.add_argument("--out", required=True, help="output directory of the restored pairs files (same names)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    args = parser.parse_args()

    import torch

    from recondreamer.io import atomic_path
    from recondreamer.restorer.data import find_pairs_files, load_pairs_file
    from recondreamer.restorer.inference import load_restorer

    torch.set_num_threads(args.threads)
    restorer = load_restorer(args.restorer)
    files = find_pairs_files(args.pairs)
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    for index, file in enumerate(files):
        out = out_dir / file.name
        if not out.exists():
            arrays = restored_copy(restorer, load_pairs_file(file))
            with atomic_path(out) as tmp, open(tmp, "wb") as handle:
                np.savez_compressed(handle, **arrays)
        elapsed = time.perf_counter() - start
        eta = elapsed / (index + 1) * (len(files) - index - 1)
        print(f"{index + 1}/{len(files)} {out}  ETA {eta / 60:.1f} min", file=sys.stderr, flush=True)


if __name__ == "__main__":
    main()
