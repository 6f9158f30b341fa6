"""View-dependent colour from real spherical-harmonics coefficients (degree 0..3).

The basis and constants are the standard real SH used by 3DGS and gsplat; the colour is
``max(sum_k c_k Y_k(d) + 0.5, 0)`` with ``d`` the unit direction from the camera centre to the
Gaussian mean, so that zero coefficients give mid-grey and degree 0 stores
``(rgb - 0.5) / Y_0``.
"""

from __future__ import annotations

import math

import torch

SH_C0 = 0.28209479177387814  # 1 / (2 sqrt(pi))
SH_C1 = 0.4886025119029199  # sqrt(3 / (4 pi))
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)


def sh_basis(directions: torch.Tensor, num_coefficients: int) -> torch.Tensor:
    """Real SH basis values (N, C) at unit ``directions`` (N,3), C in {1, 4, 9, 16}."""
    x, y, z = directions.unbind(-1)  # (N,) each
    basis = [torch.full_like(x, SH_C0)]
    if num_coefficients > 1:
        basis += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if num_coefficients > 4:
        xx, yy, zz = x * x, y * y, z * z
        basis += [
            SH_C2[0] * x * y,
            SH_C2[1] * y * z,
            SH_C2[2] * (2 * zz - xx - yy),
            SH_C2[3] * x * z,
            SH_C2[4] * (xx - yy),
        ]
    if num_coefficients > 9:
        basis += [
            SH_C3[0] * y * (3 * xx - yy),
            SH_C3[1] * x * y * z,
            SH_C3[2] * y * (4 * zz - xx - yy),
            SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy),
            SH_C3[4] * x * (4 * zz - xx - yy),
            SH_C3[5] * z * (xx - yy),
            SH_C3[6] * x * (xx - 3 * yy),
        ]
    return torch.stack(basis, dim=-1)  # (N,C)


def sh_degree(num_coefficients: int) -> int:
    """SH degree from the number of coefficients per channel (1, 4, 9, 16 -> 0..3)."""
    return math.isqrt(num_coefficients) - 1


def evaluate_colors(colors: torch.Tensor, means: torch.Tensor, viewmat: torch.Tensor) -> torch.Tensor:
    """Per-Gaussian RGB (N,3): ``colors`` (N,3) pass through; (N,C,3) SH are evaluated."""
    if colors.dim() == 2:
        return colors
    rotation, translation = viewmat[:3, :3], viewmat[:3, 3]
    camera_centre = -rotation.T @ translation  # (3,) world
    directions = torch.nn.functional.normalize(means - camera_centre, dim=-1)  # (N,3)
    basis = sh_basis(directions, colors.shape[1])  # (N,C)
    return torch.clamp_min((basis[:, :, None] * colors).sum(dim=1) + 0.5, 0.0)  # (N,3)
