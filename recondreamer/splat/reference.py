"""Pure-torch reference compositing of screen-space splats: the test oracle.

Every pixel composites every Gaussian front to back in depth order (stable sort, ties by
index), with the same rules as the fast kernel:

- ``alpha = min(ALPHA_MAX, opacity * exp(-sigma))`` with
  ``sigma = 0.5 (a dx^2 + c dy^2) + b dx dy`` and ``(dx, dy) = pixel centre - mean``;
- a Gaussian is skipped at a pixel when ``sigma < 0`` or ``alpha < ALPHA_MIN`` (1/255);
- early stop: when compositing a Gaussian would bring the transmittance to
  ``T (1 - alpha) <= TRANSMITTANCE_MIN`` (1e-4), that Gaussian is NOT composited and the pixel
  takes no further Gaussians (the 3DGS / gsplat rule);
- outputs are accumulated colour ``sum_i w_i c_i``, accumulated depth ``sum_i w_i z_i`` and
  ``alpha = 1 - T_final`` with ``w_i = alpha_i T_i``.

There is no per-tile truncation. For large problems the image is cut into pixel blocks and each
block only sees the Gaussians whose support can reach it: outside the box
``|dx| <= sqrt(2 ln(255 opacity) cov_xx)`` (same for y) ``alpha < 1/255`` holds exactly, so the
cull changes nothing but memory and time. Blocks are gradient-checkpointed.
"""

from __future__ import annotations

import torch
from torch.utils.checkpoint import checkpoint

ALPHA_MAX = 0.99
ALPHA_MIN = 1.0 / 255.0
TRANSMITTANCE_MIN = 1e-4
# Above this many (Gaussian, pixel) pairs the reference works block by block.
FULL_PAIRS_LIMIT = 1 << 24
BLOCK_SIZE = 16
SUPPORT_MARGIN = 1.0  # pixels added to the support box against rounding at its edge


def pixel_centres(width: int, height: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """Pixel centres (H*W, 2) as (x, y), row-major, at integer + 0.5."""
    ys, xs = torch.meshgrid(
        torch.arange(height, dtype=dtype, device=device) + 0.5,
        torch.arange(width, dtype=dtype, device=device) + 0.5,
        indexing="ij",
    )
    return torch.stack([xs.reshape(-1), ys.reshape(-1)], dim=-1)


def composite_pixels(
    pixels: torch.Tensor,  # (P,2)
    means2d: torch.Tensor,  # (M,2) sorted front to back
    conics: torch.Tensor,  # (M,3)
    colors: torch.Tensor,  # (M,3)
    opacities: torch.Tensor,  # (M,)
    depths: torch.Tensor,  # (M,)
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Composite the depth-sorted splats at ``pixels``; returns rgb (P,3), depth (P,), alpha (P,)."""
    delta = pixels[None, :, :] - means2d[:, None, :]  # (M,P,2)
    dx, dy = delta[..., 0], delta[..., 1]
    a, b, c = conics[:, 0:1], conics[:, 1:2], conics[:, 2:3]  # (M,1) each
    sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy  # (M,P)
    alpha = torch.clamp(opacities[:, None] * torch.exp(-sigma), max=ALPHA_MAX)  # (M,P)
    valid = (sigma >= 0) & (alpha >= ALPHA_MIN)
    alpha = torch.where(valid, alpha, torch.zeros_like(alpha))
    one_minus_alpha = 1.0 - alpha
    # Transmittance in front of each Gaussian (exclusive cumulative product).
    transmittance = torch.cat([torch.ones_like(alpha[:1]), torch.cumprod(one_minus_alpha, dim=0)[:-1]])
    stops = valid & (transmittance * one_minus_alpha <= TRANSMITTANCE_MIN)
    # A Gaussian contributes if it is valid and comes strictly before the first stop.
    contributing = valid & (torch.cumsum(stops.to(torch.int32), dim=0) == 0)
    weights = torch.where(contributing, alpha * transmittance, torch.zeros_like(alpha))  # (M,P)
    rgb = weights.T @ colors  # (P,3)
    depth = weights.T @ depths  # (P,)
    final_transmittance = torch.where(contributing, one_minus_alpha, torch.ones_like(alpha)).prod(dim=0)
    return rgb, depth, 1.0 - final_transmittance


def support_half_extents(conics: torch.Tensor, opacities: torch.Tensor) -> torch.Tensor:
    """Half-sizes (M,2) of the box outside which alpha < 1/255; -1 where alpha never reaches it."""
    a, b, c = conics.unbind(-1)
    det = a * c - b * b
    level = torch.log(torch.clamp_min(opacities * 255.0, 1e-30))  # sigma bound; <0: never visible
    reach = torch.sqrt(torch.clamp_min(2.0 * level, 0.0))
    extents = torch.stack([reach * torch.sqrt(c / det), reach * torch.sqrt(a / det)], dim=-1)
    return torch.where((level >= 0)[:, None], extents + SUPPORT_MARGIN, torch.full_like(extents, -1.0))


def composite_reference(
    means2d: torch.Tensor,  # (M,2)
    conics: torch.Tensor,  # (M,3)
    colors: torch.Tensor,  # (M,3)
    opacities: torch.Tensor,  # (M,)
    depths: torch.Tensor,  # (M,)
    width: int,
    height: int,
    block_size: int | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Exact compositing of M splats; returns rgb (H,W,3), depth (H,W) accumulated, alpha (H,W).

    ``block_size=None`` picks the whole image at once when M*H*W is small, else 16x16 blocks;
    ``block_size=0`` forces the whole image (no cull at all).
    """
    order = torch.sort(depths.detach(), stable=True).indices
    means2d, conics, colors = means2d[order], conics[order], colors[order]
    opacities, depths = opacities[order], depths[order]
    dtype, device = means2d.dtype, means2d.device
    if block_size is None:
        block_size = 0 if means2d.shape[0] * width * height <= FULL_PAIRS_LIMIT else BLOCK_SIZE
    if block_size == 0:
        rgb, depth, alpha = composite_pixels(
            pixel_centres(width, height, dtype, device), means2d, conics, colors, opacities, depths
        )
        return rgb.reshape(height, width, 3), depth.reshape(height, width), alpha.reshape(height, width)

    extents = support_half_extents(conics.detach(), opacities.detach())  # (M,2)
    centres = means2d.detach()
    rows = []
    for y0 in range(0, height, block_size):
        row = []
        for x0 in range(0, width, block_size):
            y1, x1 = min(y0 + block_size, height), min(x0 + block_size, width)
            reaches = (
                (extents[:, 0] >= 0)
                & (centres[:, 0] + extents[:, 0] >= x0 + 0.5)
                & (centres[:, 0] - extents[:, 0] <= x1 - 0.5)
                & (centres[:, 1] + extents[:, 1] >= y0 + 0.5)
                & (centres[:, 1] - extents[:, 1] <= y1 - 0.5)
            )
            ids = torch.nonzero(reaches).squeeze(1)  # keeps the depth order
            pixels = pixel_centres(x1 - x0, y1 - y0, dtype, device)
            pixels = pixels + torch.tensor([x0, y0], dtype=dtype, device=device)
            block_inputs = (pixels, means2d[ids], conics[ids], colors[ids], opacities[ids], depths[ids])
            if torch.is_grad_enabled():
                block = checkpoint(composite_pixels, *block_inputs, use_reentrant=False)
            else:
                block = composite_pixels(*block_inputs)
            row.append(torch.cat([block[0], block[1][:, None], block[2][:, None]], dim=-1).reshape(y1 - y0, x1 - x0, 5))
        rows.append(torch.cat(row, dim=1))
    image = torch.cat(rows, dim=0)  # (H,W,5): rgb, depth, alpha
    return image[..., :3], image[..., 3], image[..., 4]


__all__ = [
    "ALPHA_MAX",
    "ALPHA_MIN",
    "TRANSMITTANCE_MIN",
    "composite_pixels",
    "composite_reference",
    "pixel_centres",
    "support_half_extents",
]
