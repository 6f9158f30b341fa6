"""Deformable-GS (Yang et al. 2024): canonical Gaussians + a deformation MLP over (x, t).

An MLP reads the positional encodings of a canonical mean (normalised by the camera-path
extent, detached as in the paper) and of time, and predicts offsets of position, rotation
(added to the quaternion) and log-scale. The output layers start at zero so training begins
from the static scene; the paper's static warm-up is the trainer's ``static`` flag for the first
``warmup_fraction`` of the iterations. No box labels.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from recondreamer.recon.base import GaussianSceneModel
from recondreamer.recon.config import ModelConfig


def positional_encoding(
    x: torch.Tensor, octaves: int
) -> torch.Tensor:  # (N,D) -> (N, D*(1+2*octaves))
    """NeRF encoding [x, sin(2^k pi x), cos(2^k pi x)] for k < octaves."""
    freqs = (
        2.0 ** torch.arange(octaves, dtype=x.dtype, device=x.device)
    ) * math.pi  # (F,)
    angles = x[:, :, None] * freqs  # (N,D,F)
    return torch.cat(
        (x, torch.sin(angles).flatten(1), torch.cos(angles).flatten(1)), dim=1
    )


class DeformationMLP(nn.Module):
    """(PE(x), PE(t)) -> (d_position (N,3), d_rotation (N,4), d_log_scale (N,3))."""

    def __init__(self, octaves_x: int, octaves_t: int, width: int, depth: int) -> None:
        super().__init__()
        self.octaves_x, self.octaves_t = octaves_x, octaves_t
        in_dim = 3 * (1 + 2 * octaves_x) + (1 + 2 * octaves_t)
        self.skip_at = (
            depth // 2
        )  # the encoded input is fed again half-way (NeRF-style skip)
        layers = []
        for i in range(depth):
            layers.append(
                nn.Linear(
                    in_dim
                    if i == 0
                    else width + (in_dim if i == self.skip_at and i > 0 else 0),
                    width,
                )
            )
        self.hidden = nn.ModuleList(layers)
        self.position = nn.Linear(width, 3)
        self.rotation = nn.Linear(width, 4)
        self.scale = nn.Linear(width, 3)
        for head in (self.position, self.rotation, self.scale):
            nn.init.zeros_(head.weight)
            nn.init.zeros_(head.bias)

    def forward(
        self, x: torch.Tensor, time: float
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        t = torch.full((x.shape[0], 1), float(time), dtype=x.dtype, device=x.device)
        encoded = torch.cat(
            (
                positional_encoding(x, self.octaves_x),
                positional_encoding(t, self.octaves_t),
            ),
            dim=1,
        )
        h = encoded
        for i, layer in enumerate(self.hidden):
            if i == self.skip_at and i > 0:
                h = torch.cat((h, encoded), dim=1)
            h = torch.relu(layer(h))
        return self.position(h), self.rotation(h), self.scale(h)


class DeformableModel(GaussianSceneModel):
    model_type = "deformable"

    def __init__(self, spec: dict, net: ModelConfig) -> None:
        super().__init__(spec, net)
        self.deform = DeformationMLP(
            net.deform_freqs_x, net.deform_freqs_t, net.deform_width, net.deform_depth
        )

    def field_parameters(self) -> list[nn.Parameter]:
        return list(self.deform.parameters())

    def gaussians_at(
        self, time: float, static: bool = False
    ) -> dict[str, torch.Tensor]:
        p = self.gaussians.params
        means, quats, log_scales = p["means"], p["quats"], p["log_scales"]
        if not static:
            canonical = (means.detach() - self.center) / self.extent
            d_means, d_quats, d_scales = self.deform(canonical, time)
            means = means + d_means * self.extent
            quats = quats + d_quats
            log_scales = log_scales + d_scales
        return {
            "means": means,
            "quats": quats,
            "scales": torch.exp(log_scales),
            "opacities": self.gaussians.opacities(),
        }
