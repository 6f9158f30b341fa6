"""How far a DriveRestorer moves a clip's latents, against how far the truth lies.

    python experiments/restorer_latent_gap.py --restorer weights/restorer_dd2.pt \
        --pairs results/foundation/pairs/corpus/corpus-000/corpus-000__street.npz [--stage 0]

For one stage of one pairs file: the mean squared distance of the degraded clip's latents to the
true latents, of the restored latents to the truth, and of the restored to the degraded ones (the
change the restorer makes); PSNR of the render, of the restored clip, and of the true latents
decoded the same way (residual decoding: the most a restorer in this latent space could give).
docs/foundation.md cites it for why the shipped restorers stay near identity.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from recondreamer.generative.autoencoder import encode_frames
from recondreamer.generative.data import load_pairs_file
from recondreamer.generative.inference import _encode_conditions, _sample_clip, clip_noise, load_restorer, residual_decode
from recondreamer.generative.scoring import mean_psnr


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--restorer", type=Path, required=True)
    parser.add_argument("--pairs", type=Path, required=True, help="one pairs .npz file")
    parser.add_argument("--stage", type=int, default=0, help="degraded stage of the file (default 0, the earliest)")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    restorer = load_restorer(args.restorer)
    config = restorer.restore_config
    content = load_pairs_file(args.pairs)
    render, truth = content["degraded"][args.stage], content["gt"]
    structure = content["structure"] if restorer.unet_config.uses_structure else None
    degraded, structure_tensor = _encode_conditions(restorer, render, structure, "degraded frames")
    true_latents = encode_frames(restorer.autoencoder, truth)
    restored = _sample_clip(
        restorer, degraded, structure_tensor, degraded, config.sample_steps, config.window, config.overlap, config.strength,
        clip_noise(degraded, config.samples, config.seed),
    )
    print(f"{args.restorer} on {args.pairs.name} stage {args.stage} ({config.sample_steps} step(s), {config.samples} draws)")
    print(f"latent mean square: degraded-truth {float(((degraded - true_latents) ** 2).mean()):.3f}, "
          f"restored-truth {float(((restored - true_latents) ** 2).mean()):.3f}, restored-degraded {float(((restored - degraded) ** 2).mean()):.3f}")
    print(f"PSNR: render {mean_psnr(render, truth):.2f} dB, restored {mean_psnr(residual_decode(restorer.autoencoder, render, restored, degraded), truth):.2f} dB, "
          f"true latents decoded residually {mean_psnr(residual_decode(restorer.autoencoder, render, true_latents, degraded), truth):.2f} dB")


if __name__ == "__main__":
    main()
