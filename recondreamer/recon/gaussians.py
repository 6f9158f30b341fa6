"""The Gaussian-parameter core every backbone shares, and the maths on it.

A ``GaussianSet`` holds per-Gaussian tensors whose first dimension is the Gaussian count N:
trainable parameters (means, wxyz quaternions, log-scales, logit-opacities, SH colour
coefficients, plus backbone-specific ones such as PVG's velocity) and non-trainable buffers
(such as Street Gaussians' owner index). Density control edits all of them row-wise, so a
backbone only declares its extra fields and inherits cloning, splitting and pruning.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from recondreamer.splat.sh import SH_C0


def num_sh_rest(degree: int) -> int:
    """Number of SH coefficients above the DC term for a degree (0..3)."""
    return (degree + 1) ** 2 - 1


def rgb_to_sh_dc(rgb: torch.Tensor) -> torch.Tensor:  # (N,3) -> (N,3)
    """DC coefficient giving ``rgb`` under the rasterizer's ``SH_C0 * c + 0.5`` colour rule."""
    return (rgb - 0.5) / SH_C0


def quat_multiply(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product of wxyz quaternions (...,4) x (...,4) -> (...,4): rotation b, then a."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        (
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ),
        dim=-1,
    )


def matrix_to_quat(matrix: torch.Tensor) -> torch.Tensor:
    """Rotation matrices (...,3,3) -> unit wxyz quaternions (...,4) with w >= 0 (Shepperd's method)."""
    m = matrix
    trace = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    candidates = torch.stack(
        (
            torch.stack(
                (
                    1 + trace,
                    m[..., 2, 1] - m[..., 1, 2],
                    m[..., 0, 2] - m[..., 2, 0],
                    m[..., 1, 0] - m[..., 0, 1],
                ),
                -1,
            ),
            torch.stack(
                (
                    m[..., 2, 1] - m[..., 1, 2],
                    1 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2],
                    m[..., 0, 1] + m[..., 1, 0],
                    m[..., 0, 2] + m[..., 2, 0],
                ),
                -1,
            ),
            torch.stack(
                (
                    m[..., 0, 2] - m[..., 2, 0],
                    m[..., 0, 1] + m[..., 1, 0],
                    1 - m[..., 0, 0] + m[..., 1, 1] - m[..., 2, 2],
                    m[..., 1, 2] + m[..., 2, 1],
                ),
                -1,
            ),
            torch.stack(
                (
                    m[..., 1, 0] - m[..., 0, 1],
                    m[..., 0, 2] + m[..., 2, 0],
                    m[..., 1, 2] + m[..., 2, 1],
                    1 - m[..., 0, 0] - m[..., 1, 1] + m[..., 2, 2],
                ),
                -1,
            ),
        ),
        dim=-2,
    )  # (...,4,4): row i is 4*q*q_i, best conditioned where its diagonal entry is largest
    diagonal = torch.stack(
        (
            1 + trace,
            1 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2],
            1 - m[..., 0, 0] + m[..., 1, 1] - m[..., 2, 2],
            1 - m[..., 0, 0] - m[..., 1, 1] + m[..., 2, 2],
        ),
        -1,
    )
    best = diagonal.argmax(dim=-1, keepdim=True)
    q = torch.gather(
        candidates, -2, best.unsqueeze(-1).expand(best.shape + (4,))
    ).squeeze(-2)
    q = q / q.norm(dim=-1, keepdim=True)
    return torch.where(q[..., :1] < 0, -q, q)


def quat_slerp(a: torch.Tensor, b: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """Spherical interpolation between unit quaternions (...,4) at ``weight`` (...,) in [0,1]."""
    dot = (a * b).sum(-1, keepdim=True)
    b = torch.where(dot < 0, -b, b)
    dot = dot.abs().clamp(max=1.0)
    w = weight.unsqueeze(-1)
    theta = torch.acos(dot)
    sin_theta = torch.sin(theta)
    small = sin_theta < 1e-6
    safe = torch.where(small, torch.ones_like(sin_theta), sin_theta)
    wa = torch.where(small, 1 - w, torch.sin((1 - w) * theta) / safe)
    wb = torch.where(small, w, torch.sin(w * theta) / safe)
    q = wa * a + wb * b
    return q / q.norm(dim=-1, keepdim=True)


def inverse_sigmoid(x: torch.Tensor) -> torch.Tensor:
    return torch.log(x / (1 - x))


class GaussianSet(nn.Module):
    """N Gaussians: named per-row trainable parameters and non-trainable buffers.

    Core parameters: ``means`` (N,3), ``quats`` (N,4) wxyz, ``log_scales`` (N,3),
    ``logit_opacities`` (N,), ``sh_dc`` (N,3), ``sh_rest`` (N,K,3). ``extra`` adds backbone
    parameters as name -> trailing shape; ``buffers`` adds non-trainable rows (name -> dtype).
    """

    CORE = ("means", "quats", "log_scales", "logit_opacities", "sh_dc", "sh_rest")

    def __init__(
        self,
        num: int,
        sh_degree: int,
        extra: dict[str, tuple[int, ...]] | None = None,
        buffers: dict[str, torch.dtype] | None = None,
    ) -> None:
        super().__init__()
        self.sh_degree = sh_degree
        shapes = {
            "means": (3,),
            "quats": (4,),
            "log_scales": (3,),
            "logit_opacities": (),
            "sh_dc": (3,),
            "sh_rest": (num_sh_rest(sh_degree), 3),
        }
        shapes.update(extra or {})
        self.params = nn.ParameterDict(
            {
                name: nn.Parameter(torch.zeros((num,) + shape))
                for name, shape in shapes.items()
            }
        )
        self.buffer_names = tuple((buffers or {}).keys())
        for name, dtype in (buffers or {}).items():
            self.register_buffer(name, torch.zeros(num, dtype=dtype))
        # Raised during training (3DGS schedule); saved so a snapshot renders as it was trained.
        self.register_buffer("active_sh_degree", torch.zeros((), dtype=torch.long))

    def __len__(self) -> int:
        return self.params["means"].shape[0]

    @property
    def row_names(self) -> tuple[str, ...]:
        return tuple(self.params.keys())

    def set_rows(self, values: dict[str, torch.Tensor]) -> None:
        """Replace every per-row tensor at once (initialisation); all must share the same N."""
        for name, value in values.items():
            if name in self.params:
                self.params[name] = nn.Parameter(value.detach().clone().float())
            else:
                setattr(self, name, value.detach().clone())

    def buffer_rows(self) -> dict[str, torch.Tensor]:
        return {name: getattr(self, name) for name in self.buffer_names}

    def scales(self) -> torch.Tensor:  # (N,3)
        return torch.exp(self.params["log_scales"])

    def opacities(self) -> torch.Tensor:  # (N,)
        return torch.sigmoid(self.params["logit_opacities"])

    def sh_coefficients(self) -> torch.Tensor:  # (N,C,3), C = (active degree + 1)^2
        """SH coefficients up to the active degree, in the layout ``rasterize`` evaluates."""
        rest = self.params["sh_rest"][:, : num_sh_rest(int(self.active_sh_degree))]
        return torch.cat((self.params["sh_dc"][:, None, :], rest), dim=1)


def initial_rows(
    points: torch.Tensor,  # (N,3)
    colors: torch.Tensor,  # (N,3) in [0,1]
    log_scales: torch.Tensor,  # (N,3)
    sh_degree: int,
    opacity: float,
) -> dict[str, torch.Tensor]:
    """Core rows for Gaussians at ``points``: identity rotation, isotropic scales, given colour."""
    num = points.shape[0]
    quats = torch.zeros(num, 4)
    quats[:, 0] = 1.0
    return {
        "means": points.float(),
        "quats": quats,
        "log_scales": log_scales.float(),
        "logit_opacities": torch.full((num,), math.log(opacity / (1 - opacity))),
        "sh_dc": rgb_to_sh_dc(colors.float()),
        "sh_rest": torch.zeros(num, num_sh_rest(sh_degree), 3),
    }
