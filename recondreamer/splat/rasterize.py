"""The public entry point: ``rasterize(...)`` with a choice of backend.

Pipeline for the CPU backends: validate inputs -> projection (EWA) and SH colours -> compositing
of the in-front splats -> background and depth normalisation in torch. ``"torch"`` runs the
readable torch projection and the reference compositor; ``"cpu"`` runs both stages as C++
kernels (one fused projection + SH pass, then the tile compositor), except that it keeps the
torch projection when viewmat or K need gradients, which the fused pass does not compute. The
gsplat backend hands the whole job to gsplat's CUDA rasterizer with the same conventions.
"""

from __future__ import annotations

import torch

from recondreamer.splat.projection import project_gaussians
from recondreamer.splat.reference import composite_reference
from recondreamer.splat.sh import evaluate_colors
from recondreamer.splat.validation import RasterizeInputError, validate_inputs

DEPTH_ALPHA_EPS = 1e-10  # expected depth = accumulated depth / max(alpha, eps) (gsplat "ED")


def rasterize(
    means: torch.Tensor,  # (N,3) world
    quats: torch.Tensor,  # (N,4) wxyz, normalised inside
    scales: torch.Tensor,  # (N,3) linear standard deviations
    opacities: torch.Tensor,  # (N,) in [0,1]
    colors: torch.Tensor,  # (N,3) RGB or (N,C,3) SH coefficients, C in {1,4,9,16}
    viewmat: torch.Tensor,  # (4,4) world-to-camera, OpenCV axes
    K: torch.Tensor,  # (3,3) pinhole intrinsics
    width: int,
    height: int,
    background: torch.Tensor | None = None,  # (3,) or None (black)
    backend: str = "auto",
) -> dict[str, torch.Tensor]:
    """Render N 3D Gaussians into one camera, differentiably.

    Returns a dict with
    ``rgb`` (H,W,3) composited colour over ``background``;
    ``depth`` (H,W) expected depth ``sum_i w_i z_i / alpha`` (0 where nothing was hit);
    ``alpha`` (H,W) accumulated opacity ``1 - T_final``;
    ``means2d`` (N,2) screen-space means on the autograd graph (call ``retain_grad()`` before
    backward to read the densification signal from ``.grad``);
    ``radii`` (N,) int32 3-sigma pixel radii, 0 when not visible; ``visible`` (N,) bool.

    ``backend``: ``"torch"`` (exact reference), ``"cpu"`` (C++ tile kernel), ``"gsplat"``
    (CUDA), ``"auto"`` (gsplat for CUDA tensors, else ``"cpu"``). Bad arguments raise
    :class:`RasterizeInputError` (a ``ValueError``) before any work is done.
    """
    validate_inputs(means, quats, scales, opacities, colors, viewmat, K, width, height, background, backend)
    if backend == "auto":
        backend = "gsplat" if means.is_cuda else "cpu"
    if backend == "gsplat":
        from recondreamer.splat.gsplat_backend import rasterize_gsplat

        return rasterize_gsplat(means, quats, scales, opacities, colors, viewmat, K, width, height, background)
    if means.device.type != "cpu":
        raise RasterizeInputError(f"backend={backend!r} needs CPU tensors, got tensors on {means.device}")

    camera_needs_grad = torch.is_grad_enabled() and (viewmat.requires_grad or K.requires_grad)
    if backend == "cpu" and not camera_needs_grad:
        from recondreamer.splat.cpu_kernel import project_cpu

        projected, rgb_per_gaussian = project_cpu(means, quats, scales, colors, viewmat, K, width, height)
    else:
        projected = project_gaussians(means, quats, scales, viewmat, K, width, height)
        rgb_per_gaussian = evaluate_colors(colors, means, viewmat)  # (N,3)
    if backend == "torch":
        ids = torch.nonzero(projected.in_front).squeeze(1)
        rgb, depth_sum, alpha = composite_reference(
            projected.means2d[ids],
            projected.conics[ids],
            rgb_per_gaussian[ids],
            opacities[ids],
            projected.depths[ids],
            width,
            height,
        )
    else:
        from recondreamer.splat.cpu_kernel import composite_cpu

        # The kernel gives the splats behind the near plane zero opacity: no gather and scatter.
        rgb, depth_sum, alpha = composite_cpu(
            projected.means2d,
            projected.conics,
            rgb_per_gaussian,
            opacities,
            projected.depths,
            width,
            height,
            keep=projected.in_front,
        )

    if background is not None:
        rgb = rgb + (1.0 - alpha)[..., None] * background
    depth = depth_sum / torch.clamp_min(alpha, DEPTH_ALPHA_EPS)
    return {
        "rgb": rgb,
        "depth": depth,
        "alpha": alpha,
        "means2d": projected.means2d,
        "radii": projected.radii,
        "visible": projected.visible,
    }
