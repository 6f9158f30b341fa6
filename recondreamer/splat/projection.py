"""Differentiable projection of 3D Gaussians to screen-space splats (EWA splatting).

Shared by every CPU backend: it is cheap, vectorised torch, and autograd carries gradients
from the 2D splat parameters back to means, quats and scales. Conventions (as in 3DGS/gsplat):

- camera axes OpenCV (x right, y down, z forward), pixel centres at integer + 0.5;
- a Gaussian is rendered only if its camera depth is above :data:`NEAR_PLANE`;
- the Jacobian of the perspective map is evaluated at the camera-space mean with x/z and y/z
  clamped to 1.3 times the half field of view (keeps splats of Gaussians far outside the view
  from exploding);
- the 2D covariance is dilated by :data:`LOW_PASS` pixels^2 on the diagonal (anti-aliasing
  low-pass filter, gsplat's ``eps2d``);
- ``radii`` are 3-sigma radii of the dilated covariance, in whole pixels; 0 means not visible.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

NEAR_PLANE = 0.01  # camera depth below which a Gaussian is culled
LOW_PASS = 0.3  # pixels^2 added to the 2D covariance diagonal


@dataclass
class ProjectedGaussians:
    """Screen-space splats of N Gaussians for one camera (all on the autograd graph)."""

    means2d: torch.Tensor  # (N,2) pixel coordinates of the projected centres
    conics: torch.Tensor  # (N,3) inverse 2D covariance (a, b, c): [[a, b], [b, c]]
    depths: torch.Tensor  # (N,) camera-space z
    in_front: torch.Tensor  # (N,) bool: depth > NEAR_PLANE (the Gaussians that get rasterised)
    radii: torch.Tensor  # (N,) int32 3-sigma radius in pixels, 0 if not visible
    visible: torch.Tensor  # (N,) bool: in front and 3-sigma box overlaps the image


def quats_to_rotmats(quats: torch.Tensor) -> torch.Tensor:
    """Rotation matrices from quaternions in (w, x, y, z) order, normalised here."""
    w, x, y, z = (quats / quats.norm(dim=-1, keepdim=True)).unbind(-1)  # (N,) each
    rows = [
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ]  # fmt: skip
    return torch.stack(rows, dim=-1).reshape(quats.shape[:-1] + (3, 3))  # (N,3,3)


def camera_axes(quats: torch.Tensor, scales: torch.Tensor, rotation: torch.Tensor) -> torch.Tensor:
    """Scaled principal axes of each Gaussian in camera coordinates: row k of (N,3,3) is
    ``scales[k] * (rotation @ R)[:, k]``, so the camera-space covariance is ``sum_k a_k a_k^T``."""
    n = quats.shape[0]
    # R(conjugate q) = R(q)^T: its rows are the world-space axes, already contiguous.
    conjugate = quats * quats.new_tensor([1.0, -1.0, -1.0, -1.0])
    world_axes = quats_to_rotmats(conjugate).reshape(n * 3, 3)  # (N*3,3)
    return (world_axes @ rotation.T).reshape(n, 3, 3) * scales[:, :, None]  # (N,3,3)


def project_gaussians(
    means: torch.Tensor,  # (N,3) world
    quats: torch.Tensor,  # (N,4) wxyz
    scales: torch.Tensor,  # (N,3) linear
    viewmat: torch.Tensor,  # (4,4) world-to-camera
    K: torch.Tensor,  # (3,3)
    width: int,
    height: int,
) -> ProjectedGaussians:
    """Project Gaussians with the EWA approximation; see the module docstring for conventions."""
    rotation, translation = viewmat[:3, :3], viewmat[:3, 3]
    means_cam = means @ rotation.T + translation  # (N,3)
    x, y, z = means_cam.unbind(-1)  # (N,) each
    in_front = z > NEAR_PLANE
    # Gaussians behind the near plane are never rasterised; a safe depth keeps their (unused)
    # values finite so that no NaN can leak into gradients through masked arithmetic.
    z_safe = torch.where(in_front, z, torch.ones_like(z))
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    means2d = torch.stack([fx * x / z_safe + cx, fy * y / z_safe + cy], dim=-1)  # (N,2)

    half_tan_x = 0.5 * width / fx
    half_tan_y = 0.5 * height / fy
    tx = z_safe * torch.clamp(x / z_safe, -(cx / fx + 0.3 * half_tan_x), (width - cx) / fx + 0.3 * half_tan_x)
    ty = z_safe * torch.clamp(y / z_safe, -(cy / fy + 0.3 * half_tan_y), (height - cy) / fy + 0.3 * half_tan_y)
    # Jacobian of (x, y, z) -> (fx x/z + cx, fy y/z + cy): [[fx/z, 0, -fx tx/z^2], [0, fy/z, -fy ty/z^2]],
    # with (tx, ty) the view-angle-clamped camera-space position.
    # cov2d = J cov_cam J^T = sum_k (J a_k)(J a_k)^T over the scaled axes a_k: elementwise
    # arithmetic on (N,3) instead of thousands of tiny 3x3 matrix products.
    axes = camera_axes(quats, scales, rotation)  # (N,3,3)
    ax, ay, az = axes[..., 0], axes[..., 1], axes[..., 2]  # (N,3) each
    jx = (fx / z_safe)[:, None] * ax - (fx * tx / z_safe**2)[:, None] * az  # (N,3) J row 0 . a_k
    jy = (fy / z_safe)[:, None] * ay - (fy * ty / z_safe**2)[:, None] * az  # (N,3) J row 1 . a_k
    a = (jx * jx).sum(-1) + LOW_PASS
    b = (jx * jy).sum(-1)
    c = (jy * jy).sum(-1) + LOW_PASS
    det = a * c - b * b  # > 0: cov2d is PSD and the dilation adds LOW_PASS^2 at least
    conics = torch.stack([c / det, -b / det, a / det], dim=-1)  # (N,3)

    with torch.no_grad():
        mid = 0.5 * (a + c)
        largest_eigenvalue = mid + torch.sqrt(torch.clamp(mid * mid - det, min=0.0))
        radii = torch.ceil(3.0 * torch.sqrt(largest_eigenvalue))  # (N,)
        u, v = means2d.unbind(-1)
        overlaps = (u + radii > 0) & (u - radii < width) & (v + radii > 0) & (v - radii < height)
        visible = in_front & overlaps & (radii > 0)
        radii = torch.where(visible, radii, torch.zeros_like(radii)).to(torch.int32)
    return ProjectedGaussians(means2d, conics, z, in_front, radii, visible)
