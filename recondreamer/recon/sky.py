"""Sky: a learned equirectangular environment texture looked up by world viewing direction.

Composited behind the Gaussians with their accumulated alpha, so the sky-opacity loss can push
alpha to zero on sky pixels while the texture explains their colour (Street Gaussians uses a
cube map; an equirect texture is the same idea with one ``grid_sample`` call).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn


def pixel_ray_directions(
    cam_to_world: torch.Tensor, K: torch.Tensor, width: int, height: int
) -> torch.Tensor:
    """Unit world directions through every pixel centre: (H,W,3)."""
    v, u = torch.meshgrid(
        torch.arange(height, dtype=torch.float32, device=K.device) + 0.5,
        torch.arange(width, dtype=torch.float32, device=K.device) + 0.5,
        indexing="ij",
    )
    x = (u - K[0, 2]) / K[0, 0]
    y = (v - K[1, 2]) / K[1, 1]
    dirs_cam = torch.stack(
        (x, y, torch.ones_like(x)), dim=-1
    )  # (H,W,3) OpenCV camera axes
    dirs = dirs_cam @ cam_to_world[:3, :3].T
    return dirs / dirs.norm(dim=-1, keepdim=True)


class SkyTexture(nn.Module):
    """Equirectangular RGB texture over (azimuth, elevation) of the world frame (z up)."""

    def __init__(self, height: int, width: int) -> None:
        super().__init__()
        self.logits = nn.Parameter(
            torch.zeros(1, 3, height, width)
        )  # sigmoid -> RGB, starts mid-grey

    def forward(
        self, dirs: torch.Tensor
    ) -> torch.Tensor:  # (H,W,3) unit world dirs -> (H,W,3) RGB
        azimuth = torch.atan2(dirs[..., 1], dirs[..., 0]) / math.pi  # [-1,1]
        elevation = torch.asin(dirs[..., 2].clamp(-1.0, 1.0)) / (
            math.pi / 2
        )  # [-1,1], up = +1
        grid = torch.stack((azimuth, -elevation), dim=-1).unsqueeze(
            0
        )  # (1,H,W,2); top row = zenith
        colors = F.grid_sample(
            torch.sigmoid(self.logits),
            grid,
            mode="bilinear",
            padding_mode="border",
            align_corners=False,
        )
        return colors[0].permute(1, 2, 0)
