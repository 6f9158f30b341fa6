"""PVG: Periodic Vibration Gaussians (Chen et al. 2023), no box labels.

Every Gaussian vibrates around its mean ``mu`` along a learned direction ``v`` with a shared
period ``l`` and a learned peak time ``tau``, and is visible around ``tau`` for a learned
lifespan ``beta``:

    mu(t)      = mu + l / (2 pi) * sin(2 pi (t - tau) / l) * v
    opacity(t) = opacity * exp(-(t - tau)^2 / (2 beta^2))

so static content is Gaussians with long lifespans and small ``v``, and moving content is many
short-lived Gaussians whose vibration carries them along the motion. Time is normalised to the
segment ([0, 1]); ``v`` is stored in scene-extent units per unit time so one learning rate fits
every scene size. Peak times start at the time of the LiDAR sweep that saw the point.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from recondreamer.recon.base import GaussianSceneModel
from recondreamer.recon.config import ReconConfig
from recondreamer.recon.init import ScenePoints, normalized_times

# Far-shell points model distant static background: centred in time and practically eternal.
FAR_LIFESPAN = 10.0


class PVGModel(GaussianSceneModel):
    model_type = "pvg"

    def extra_fields(self) -> dict[str, tuple[int, ...]]:
        return {"velocity": (3,), "peak_time": (), "log_lifespan": ()}

    def gaussians_at(
        self, time: float, static: bool = False
    ) -> dict[str, torch.Tensor]:
        p = self.gaussians.params
        cycle = self.net.pvg_cycle
        offset = time - p["peak_time"]  # (N,)
        vibration = (cycle / (2 * math.pi)) * torch.sin(
            2 * math.pi * offset / cycle
        )  # (N,)
        means = p["means"] + vibration[:, None] * p["velocity"] * self.extent
        lifespan = torch.exp(p["log_lifespan"])
        decay = torch.exp(-0.5 * (offset / lifespan) ** 2)
        return {
            "means": means,
            "quats": p["quats"],
            "scales": self.gaussians.scales(),
            "opacities": self.gaussians.opacities() * decay,
        }

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
        frame_times = normalized_times(np.asarray(scene.timestamps, dtype=np.float64))
        peak = np.concatenate([frame_times[points.frames], np.full(far_count, 0.5)])
        lifespan = np.concatenate(
            [
                np.full(len(points), config.net.pvg_lifespan),
                np.full(far_count, FAR_LIFESPAN),
            ]
        )
        rows["velocity"] = torch.zeros(len(peak), 3)
        rows["peak_time"] = torch.from_numpy(peak).float()
        rows["log_lifespan"] = torch.from_numpy(np.log(lifespan)).float()
        return rows, {}, {"num_far_points": far_count}
