"""Where the error of degraded renders sits: what a restorer would have to fix to gain on them.

For the earliest and latest stage of every restoration-pairs file given, prints the degraded
clip's PSNR against its ground truth and:

- ``edge px / edge err``: the share of pixels within one pixel of a ground-truth edge (grey-level
  step > 0.08 to the right or below neighbour) and the share of the squared error they hold;
- ``line px / line err``: the same for pixels within two pixels of a road line or road edge of the
  structure maps (what the dd2 restorers are told);
- ``coarse oracle dB``: the gain of a perfect correction of everything coarser than 8x8 pixels
  (the error minus its 8x8 block means is what remains): an upper bound for any restorer that only
  fixes colour and blur at that scale;
- with ``--autoencoder CKPT``, ``latent oracle dB``: the gain of a restorer whose restored latent is
  exactly the ground truth's, ``E(gt)``, under residual decoding (``input + D(E(gt)) - D(E(input))``,
  what ``restore_clip`` returns): the ceiling of any latent restorer with that autoencoder.

docs/generative.md cites it for the latent oracle's gain (Design decisions, the autoencoder) and for
where a render's error sits, the reason for the pixel refiner (Design decisions, Refiner). Example::

    python experiments/pairs_error.py --pairs results/restorer-dev/pairs-heldout [--autoencoder results/restorer-dev/ae8_5000.pt]
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.ndimage import binary_dilation

from recondreamer.evaluation.image_metrics import psnr

BLOCK = 8
EDGE_STEP = 0.08


def error_structure(gt: np.ndarray, degraded: np.ndarray, structure: np.ndarray, channels: list[str]) -> dict:
    """gt, degraded (T,H,W,3) uint8 with H, W multiples of BLOCK; structure (T,S,H,W) uint8."""
    truth = gt.astype(np.float64) / 255.0
    difference = truth - degraded.astype(np.float64) / 255.0
    squared = (difference**2).mean(-1)  # (T,H,W)
    grey = truth.mean(-1)
    steps = np.abs(np.diff(grey, axis=2, append=grey[:, :, -1:])) + np.abs(np.diff(grey, axis=1, append=grey[:, -1:]))
    edges = binary_dilation(steps > EDGE_STEP, structure=np.ones((1, 3, 3)))
    line_channels = [channels.index(name) for name in ("road_line", "road_edge")]
    lines = binary_dilation((structure[:, line_channels] > 0).any(1), structure=np.ones((1, 5, 5)))
    t, h, w, c = difference.shape
    blocks = difference.reshape(t, h // BLOCK, BLOCK, w // BLOCK, BLOCK, c)
    fine = (blocks - blocks.mean((2, 4), keepdims=True)).reshape(t, h, w, c)
    total = squared.sum()
    return {
        "psnr": psnr(degraded, gt),  # over the whole clip
        "edge_pixels": edges.mean(),
        "edge_error": squared[edges].sum() / total,
        "line_pixels": lines.mean(),
        "line_error": squared[lines].sum() / total,
        "coarse_oracle_db": 10.0 * np.log10(squared.mean() / (fine**2).mean()),
    }


def latent_oracle_db(autoencoder, gt: np.ndarray, degraded: np.ndarray) -> float:
    """Gain (dB) of residual-decoding the ground truth's own latents onto the degraded clip (T,H,W,3) uint8."""
    from recondreamer.generative.autoencoder import encode_frames
    from recondreamer.generative.inference import residual_decode

    oracle = residual_decode(autoencoder, degraded, encode_frames(autoencoder, gt), encode_frames(autoencoder, degraded))
    return psnr(oracle, gt) - psnr(degraded, gt)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", nargs="+", required=True, help="restoration-pairs directories or .npz files")
    parser.add_argument("--autoencoder", default=None, help="autoencoder checkpoint: adds the latent-oracle column")
    args = parser.parse_args()
    from recondreamer.generative.data import find_pairs_files, load_pairs_file

    autoencoder = None
    if args.autoencoder:
        from recondreamer.generative.models import load_autoencoder

        autoencoder = load_autoencoder(args.autoencoder)[0].eval()
    header = f"{'pairs file':44s} {'stage':>5s} {'PSNR':>6s} {'edge px':>7s} {'edge err':>8s} {'line px':>7s} {'line err':>8s} {'coarse oracle dB':>16s}"
    header += f" {'latent oracle dB':>16s}" if autoencoder is not None else ""
    print(header)
    print("-" * len(header))
    for path in find_pairs_files(args.pairs):
        content = load_pairs_file(path)
        channels = [str(name) for name in content["structure_channels"]]
        for k in sorted({0, len(content["degraded"]) - 1}):
            row = error_structure(content["gt"], content["degraded"][k], content["structure"], channels)
            print(
                f"{path.name:44s} {int(content['stages'][k]):5d} {row['psnr']:6.2f} {row['edge_pixels']:7.2f} {row['edge_error']:8.2f} "
                f"{row['line_pixels']:7.2f} {row['line_error']:8.2f} {row['coarse_oracle_db']:16.2f}"
                + (f" {latent_oracle_db(autoencoder, content['gt'], content['degraded'][k]):16.2f}" if autoencoder is not None else "")
            )


if __name__ == "__main__":
    main()
