"""CUDA backend: gsplat's ``rasterization`` with this package's conventions.

gsplat (optional extra ``[cuda]``) does projection, SH and compositing on the GPU. Settings
that make it follow the CPU backends: quats wxyz and linear scales (gsplat's own convention),
``eps2d=0.3``, ``near_plane=0.01``, ``packed=False``, ``render_mode="RGB+ED"`` (expected depth
normalised by alpha), background applied here as ``rgb + (1 - alpha) * background``, radii and
visibility from :func:`recondreamer.splat.projection.project_gaussians` (3-sigma, as on CPU).
Known differences: gsplat clamps alpha at 0.999 (not 0.99) and its support radius is its own;
it computes in float32 (float64 inputs are cast and the outputs cast back).

The screen-space means gsplat differentiates are a (1,N,2) tensor inside its graph; the
``means2d`` returned here is its (N,2) view, and a gradient hook copies the gradient that
reaches the (1,N,2) tensor into ``means2d.grad`` so that ``retain_grad()`` + ``.grad`` works
as on the CPU backends. An empty scene (no Gaussians) is rendered here without gsplat, whose
extension kills the process on one. This path needs a CUDA device: CI has none; it passed the
backend tests (tests/test_splat_backends.py) on an H100 with gsplat 1.5.3 (docs/gpu.md).
"""

from __future__ import annotations

import torch

from recondreamer.splat.projection import project_gaussians
from recondreamer.splat.sh import sh_degree
from recondreamer.splat.validation import RasterizeInputError


def rasterize_gsplat(
    means: torch.Tensor,  # (N,3)
    quats: torch.Tensor,  # (N,4) wxyz
    scales: torch.Tensor,  # (N,3) linear
    opacities: torch.Tensor,  # (N,)
    colors: torch.Tensor,  # (N,3) or (N,C,3)
    viewmat: torch.Tensor,  # (4,4)
    K: torch.Tensor,  # (3,3)
    width: int,
    height: int,
    background: torch.Tensor | None,  # (3,) or None
) -> dict[str, torch.Tensor]:
    """Same contract as :func:`recondreamer.splat.rasterize`, rendered by gsplat on CUDA."""
    if not means.is_cuda:
        raise RasterizeInputError(f"backend='gsplat' needs CUDA tensors, got means on {means.device}")
    try:
        from gsplat import rasterization
    except ImportError as error:
        raise RasterizeInputError(
            "backend='gsplat' needs the gsplat package: pip install 'recondreamer[cuda]'"
        ) from error

    if means.shape[0] == 0:
        return _empty_scene(means, quats, scales, viewmat, K, width, height, background)
    dtype = means.dtype
    f32 = [t.float() for t in (means, quats, scales, opacities, colors, viewmat, K)]
    means_f, quats_f, scales_f, opacities_f, colors_f, viewmat_f, K_f = f32
    renders, alphas, meta = rasterization(
        means_f,
        quats_f,
        scales_f,
        opacities_f,
        colors_f,
        viewmat_f[None],
        K_f[None],
        width,
        height,
        near_plane=0.01,
        eps2d=0.3,
        sh_degree=sh_degree(colors.shape[1]) if colors.dim() == 3 else None,
        packed=False,
        render_mode="RGB+ED",
        rasterize_mode="classic",
    )
    rgb = renders[0, ..., :3].to(dtype)  # (H,W,3)
    depth = renders[0, ..., 3].to(dtype)  # (H,W)
    alpha = alphas[0, ..., 0].to(dtype)  # (H,W)
    if background is not None:
        rgb = rgb + (1.0 - alpha)[..., None] * background

    screen_means = meta["means2d"]  # (1,N,2), what gsplat differentiates
    means2d = screen_means[0]

    def copy_gradient(grad: torch.Tensor) -> None:
        means2d.grad = grad[0].clone() if means2d.grad is None else means2d.grad + grad[0]

    if screen_means.requires_grad:
        screen_means.register_hook(copy_gradient)
    with torch.no_grad():
        projected = project_gaussians(means, quats, scales, viewmat, K, width, height)
    return {
        "rgb": rgb,
        "depth": depth,
        "alpha": alpha,
        "means2d": means2d,
        "radii": projected.radii,
        "visible": projected.visible,
    }


def _empty_scene(means, quats, scales, viewmat, K, width: int, height: int, background) -> dict[str, torch.Tensor]:
    """The render of zero Gaussians (the background, nothing else), without gsplat: its CUDA
    extension kills the process with a floating-point exception on an empty scene (seen with
    gsplat 1.5.3 on an H100, docs/gpu.md)."""
    projected = project_gaussians(means, quats, scales, viewmat, K, width, height)
    # The sum over no Gaussians (0) ties the outputs to the inputs' graph, as on the other
    # backends: backward() runs and gives zero (or no) gradients.
    nothing = means.sum() * 0.0
    zeros = means.new_zeros((height, width)) + nothing
    rgb = means.new_zeros((height, width, 3)) if background is None else background.expand(height, width, 3)
    return {"rgb": rgb + nothing, "depth": zeros, "alpha": zeros.clone(), "means2d": projected.means2d,
            "radii": projected.radii, "visible": projected.visible}
