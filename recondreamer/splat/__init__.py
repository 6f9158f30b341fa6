"""Differentiable Gaussian rasterizer: C++ CPU tile kernel, pure-torch reference twin, gsplat on CUDA.

``from recondreamer.splat import rasterize``; conventions in ``docs/rasterizer.md``.
"""

from recondreamer.splat.rasterize import rasterize
from recondreamer.splat.validation import RasterizeInputError

__all__ = ["RasterizeInputError", "rasterize"]
