"""ReconDreamer as a reproducible experiment system.

Sub-packages, one job each:

- ``scene``: the scene directory format, cameras, trajectories, structure maps.
- ``sources.synthetic`` / ``sources.waymo``: the two scene sources.
- ``splat``: the differentiable Gaussian rasterizer (reference, fast CPU kernel, gsplat).
- ``recon``: Gaussian scene models and their trainer.
- ``restorer``: autoencoder, diffusion world models, DriveRestorer.
- ``evaluation``: NTA-IoU, NTL-IoU, FID, PSNR/SSIM against true novel views, preference study.
- ``report``: tables, plots and the study page.
"""

__version__ = "0.1.0"
