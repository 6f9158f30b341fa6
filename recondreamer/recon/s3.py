"""S3Gaussian (Huang et al. 2024): Gaussians deformed by a HexPlane spatio-temporal field.

The field factorises 4D space-time (x, y, z, t) into six feature planes (xy, xz, yz, xt, yt, zt)
at several spatial resolutions. A point's feature is the product of its bilinear samples on the
six planes (per resolution), concatenated over resolutions; a small decoder and three heads turn
it into position, rotation and log-scale offsets. Spatial planes start random in [0.1, 0.5] and
time planes at 1 (K-Planes' initialisation: no time dependence at first); heads start at zero.
Static and dynamic parts separate on their own (no box labels): where the time planes stay
flat, Gaussians do not move. Total-variation and temporal-smoothness regularisers keep the
planes smooth, as in the paper.
"""

from __future__ import annotations

import itertools

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from recondreamer.recon.base import GaussianSceneModel
from recondreamer.recon.config import ModelConfig, ReconConfig
from recondreamer.recon.init import ScenePoints

PLANE_AXES = tuple(
    itertools.combinations(range(4), 2)
)  # (0,1) xy ... (2,3) zt; axis 3 is time
TV_WEIGHT = 2e-4
TIME_SMOOTHNESS_WEIGHT = 1e-3


class HexPlaneField(nn.Module):
    """coords (N,4) in [-1,1] (x, y, z, t) -> features (N, F * len(resolutions))."""

    def __init__(
        self, resolutions: tuple[int, ...], time_resolution: int, features: int
    ) -> None:
        super().__init__()
        planes = []
        for resolution in resolutions:
            for a, b in PLANE_AXES:
                size_a = resolution if a < 3 else time_resolution
                size_b = resolution if b < 3 else time_resolution
                if b == 3:
                    plane = torch.ones(1, features, size_b, size_a)
                else:
                    plane = torch.empty(1, features, size_b, size_a).uniform_(0.1, 0.5)
                planes.append(nn.Parameter(plane))
        self.planes = nn.ParameterList(planes)
        self.num_resolutions = len(resolutions)
        self.register_buffer(
            "pair_index", torch.tensor(PLANE_AXES), persistent=False
        )  # (6,2)

    def forward(self, coords: torch.Tensor) -> torch.Tensor:
        # One gather of the six coordinate pairs (one backward scatter instead of six), and
        # channels-first products: the samples come out of grid_sample as contiguous (F,N).
        pairs = coords[:, self.pair_index].permute(1, 0, 2).contiguous()  # (6,N,2)
        count = coords.shape[0]
        features = []
        for level in range(self.num_resolutions):
            product = None
            for k in range(len(PLANE_AXES)):
                plane = self.planes[level * len(PLANE_AXES) + k]  # (1,F,size_b,size_a)
                sample = F.grid_sample(
                    plane,
                    pairs[k].view(1, 1, count, 2),  # x indexes axis a (width), y axis b
                    mode="bilinear",
                    padding_mode="border",
                    align_corners=True,
                ).view(-1, count)  # (F,N)
                product = sample if product is None else product * sample
            features.append(product)
        return torch.cat(features).T  # (N, F * levels)

    def regularization(self) -> torch.Tensor:
        """Total variation of every plane + second differences along time of the time planes."""
        total = torch.zeros((), device=self.planes[0].device)
        for index, plane in enumerate(self.planes):
            b = PLANE_AXES[index % len(PLANE_AXES)][1]
            total = total + TV_WEIGHT * (
                (plane[..., 1:, :] - plane[..., :-1, :]).pow(2).mean()
                + (plane[..., :, 1:] - plane[..., :, :-1]).pow(2).mean()
            )
            if b == 3 and plane.shape[-2] > 2:
                second = (
                    plane[..., 2:, :] - 2 * plane[..., 1:-1, :] + plane[..., :-2, :]
                )
                total = total + TIME_SMOOTHNESS_WEIGHT * second.pow(2).mean()
        return total


class S3Model(GaussianSceneModel):
    model_type = "s3"

    def __init__(self, spec: dict, net: ModelConfig) -> None:
        super().__init__(spec, net)
        time_resolution = net.hexplane_time_resolution or max(
            2, spec["num_frames"] // 2
        )
        self.field = HexPlaneField(
            tuple(net.hexplane_resolutions), time_resolution, net.hexplane_features
        )
        width = net.s3_decoder_width
        in_dim = net.hexplane_features * len(net.hexplane_resolutions)
        self.decoder = nn.Sequential(
            nn.Linear(in_dim, width), nn.ReLU(), nn.Linear(width, width), nn.ReLU()
        )
        self.position = nn.Linear(width, 3)
        self.rotation = nn.Linear(width, 4)
        self.scale = nn.Linear(width, 3)
        for head in (self.position, self.rotation, self.scale):
            nn.init.zeros_(head.weight)
            nn.init.zeros_(head.bias)
        aabb = torch.tensor(spec["aabb"], dtype=torch.float32)  # (2,3) min, max
        self.register_buffer("aabb", aabb)

    def field_parameters(self) -> list[nn.Parameter]:
        modules = (self.decoder, self.position, self.rotation, self.scale)
        return [p for module in modules for p in module.parameters()]

    def grid_parameters(self) -> list[nn.Parameter]:
        return list(self.field.parameters())

    def gaussians_at(
        self, time: float, static: bool = False
    ) -> dict[str, torch.Tensor]:
        p = self.gaussians.params
        means, quats, log_scales = p["means"], p["quats"], p["log_scales"]
        if not static:
            xyz = (means - self.aabb[0]) / (self.aabb[1] - self.aabb[0]) * 2 - 1
            coords = torch.cat(
                (xyz.clamp(-1, 1), torch.full_like(xyz[:, :1], 2 * float(time) - 1)),
                dim=1,
            )
            h = self.decoder(self.field(coords))
            means = means + self.position(h) * self.extent
            quats = quats + self.rotation(h)
            log_scales = log_scales + self.scale(h)
        return {
            "means": means,
            "quats": quats,
            "scales": torch.exp(log_scales),
            "opacities": self.gaussians.opacities(),
        }

    def regularization(self) -> torch.Tensor:
        return self.field.regularization()

    @classmethod
    def initial_state(
        cls,
        scene,
        config: ReconConfig,
        points: ScenePoints,
        center: np.ndarray,
        rng: np.random.Generator,
    ) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor], dict]:
        points, rows, far_count = cls.background_state(config, points, center, rng)
        if len(points):
            low, high = (
                np.percentile(points.points, 1, axis=0),
                np.percentile(points.points, 99, axis=0),
            )
        else:
            low, high = center - 10.0, center + 10.0
        margin = 0.05 * (high - low) + 0.5
        aabb = [[float(x) for x in low - margin], [float(x) for x in high + margin]]
        return (
            rows,
            {},
            {
                "num_far_points": far_count,
                "aabb": aabb,
                "num_frames": int(scene.num_frames),
            },
        )
