"""ReconDreamer as a reproducible experiment system.

Sub-packages, one job each:

- ``scene``: the scene directory format, cameras, trajectories, structure maps.
- ``sources.synthetic`` / ``sources.waymo``: the two scene sources.
- ``splat``: the differentiable Gaussian rasterizer (reference, fast CPU kernel, gsplat).
- ``recon``: Gaussian scene models and their trainer.
- ``generative``: autoencoder, diffusion world models, DriveRestorer, DriveDreamer4D's generation.
- ``methods``: ReconDreamer's loop (PDUS) and DriveDreamer4D on top of a reconstruction.
- ``evaluation``: NTA-IoU, NTL-IoU, FID/KID, PSNR/SSIM against true novel views, the evaluation models.
- ``foundation``: the weight set of models trained once, its manifest and gates.
- ``report``: tables, findings, plots, clips and the study page.
"""

import os

# OpenMP threads that spin while waiting turn a busy 2-core machine into a crawl (measured: the
# rasterizer's fwd+bwd at 50k Gaussians went from 113 ms to 3 s with 2 threads when another
# process held one core). Set before torch is imported; a user's own setting wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

__version__ = "0.1.0"
