"""The common scene-model interface: Gaussians at a time, rasterised, composited over the sky.

A backbone subclasses ``GaussianSceneModel`` and says how its Gaussians look at a normalised
time (``gaussians_at``) and how it is initialised from a scene (``initial_state``). Rendering,
sky compositing, SH colour and the spec needed to rebuild a saved model live here.
"""

from __future__ import annotations

import abc
from typing import ClassVar

import numpy as np
import torch
from torch import nn

from recondreamer.recon.config import ModelConfig, ReconConfig
from recondreamer.recon.gaussians import GaussianSet, initial_rows
from recondreamer.recon.init import (
    ScenePoints,
    camera_center_and_extent,
    colored_lidar_points,
    far_shell_points,
    knn_log_scales,
    lidar_radius,
    subsample,
)
from recondreamer.recon.sky import SkyTexture, pixel_ray_directions


def as_float_tensor(value, device: torch.device | str = "cpu") -> torch.Tensor:
    if isinstance(value, torch.Tensor):
        return value.float().to(device)
    return torch.tensor(np.asarray(value, dtype=np.float32), device=device)


def rigid_inverse(matrix: torch.Tensor) -> torch.Tensor:  # (4,4) -> (4,4)
    rotation, translation = matrix[:3, :3], matrix[:3, 3]
    inverse = torch.eye(4, dtype=matrix.dtype, device=matrix.device)
    inverse[:3, :3] = rotation.T
    inverse[:3, 3] = -rotation.T @ translation
    return inverse


class GaussianSceneModel(nn.Module, abc.ABC):
    """Gaussians (``self.gaussians``) + sky texture; subclasses add their dynamics.

    ``spec`` holds what is needed to rebuild the module before loading a state dict:
    ``num_gaussians``, ``time_range`` (seconds of the first and last frame), ``center`` (3,)
    and ``extent`` (metres) of the camera path, plus subclass entries.
    """

    model_type: ClassVar[str] = ""
    uses_boxes: ClassVar[bool] = False

    def __init__(self, spec: dict, net: ModelConfig) -> None:
        super().__init__()
        self.net = net
        self._spec = dict(spec)
        self.time_range = tuple(float(x) for x in spec["time_range"])
        self.extent = float(spec["extent"])
        self.register_buffer(
            "center", torch.tensor(spec["center"], dtype=torch.float32)
        )
        self.gaussians = GaussianSet(
            spec["num_gaussians"],
            net.sh_degree,
            extra=self.extra_fields(),
            buffers=self.buffer_fields(),
        )
        self.sky = SkyTexture(net.sky_height, net.sky_width)

    # --- what a subclass declares -------------------------------------------------------
    def extra_fields(self) -> dict[str, tuple[int, ...]]:
        """Backbone-specific per-Gaussian parameters: name -> trailing shape."""
        return {}

    def buffer_fields(self) -> dict[str, torch.dtype]:
        """Backbone-specific per-Gaussian non-trainable rows: name -> dtype."""
        return {}

    def field_parameters(self) -> list[nn.Parameter]:
        """Parameters shared by all Gaussians (deformation networks), trained with the field LR."""
        return []

    def grid_parameters(self) -> list[nn.Parameter]:
        """Feature grids (HexPlane planes), trained with the grid learning rate."""
        return []

    @abc.abstractmethod
    def gaussians_at(
        self, time: float, static: bool = False
    ) -> dict[str, torch.Tensor]:
        """World-space ``means`` (N,3), ``quats`` (N,4), ``scales`` (N,3), ``opacities`` (N,) at
        normalised ``time``; ``static`` skips learned dynamics (warm-up of deformation fields)."""

    def regularization(self) -> torch.Tensor | None:
        """Backbone-specific regulariser added to the loss (None = none)."""
        return None

    # --- shared behaviour ---------------------------------------------------------------
    @property
    def device(self) -> torch.device:
        return self.center.device

    def spec(self) -> dict:
        return {**self._spec, "num_gaussians": len(self.gaussians)}

    def normalized_time(self, timestamp: float) -> float:
        start, end = self.time_range
        return (float(timestamp) - start) / max(end - start, 1e-6)

    def render(
        self,
        cam_to_world,  # (4,4) array or tensor
        timestamp: float,
        K,  # (3,3)
        width: int,
        height: int,
        backend: str = "auto",
        static: bool = False,
        ray_directions: torch.Tensor | None = None,
    ) -> dict[str, torch.Tensor]:
        """Render one view: ``rgb`` (H,W,3) in [0,1] over the sky, ``depth`` (H,W) expected depth
        (accumulated depth / alpha; 0 where nothing is hit), ``alpha`` (H,W); also ``means2d`` (N,2), ``radii`` (N,) and
        ``visible`` (N,) of the rasteriser for density control.

        ``ray_directions`` (H,W,3): the pixels' world directions for the sky lookup when the
        caller has them already (the trainer caches them per view); computed here otherwise."""
        from recondreamer.splat import rasterize

        from recondreamer.scene.cameras import rasterizer_intrinsics

        cam_to_world = as_float_tensor(cam_to_world, self.device)
        # K is in the scene's convention (pixel centres at integers); the rasterizer and the sky
        # rays put pixel centres at integer + 0.5.
        K = rasterizer_intrinsics(as_float_tensor(K, self.device))
        g = self.gaussians_at(self.normalized_time(timestamp), static=static)
        out = rasterize(
            g["means"],
            g["quats"],
            g["scales"],
            g["opacities"],
            g.get("colors", self.gaussians.sh_coefficients()),
            rigid_inverse(cam_to_world),
            K,
            width,
            height,
            backend=backend,
        )
        alpha = out["alpha"]
        if ray_directions is None:
            ray_directions = pixel_ray_directions(cam_to_world, K, width, height)
        sky = self.sky(ray_directions)
        rgb = out["rgb"] + (1.0 - alpha)[..., None] * sky
        return {
            "rgb": rgb.clamp(0.0, 1.0),
            "depth": out["depth"],
            "alpha": alpha,
            "means2d": out["means2d"],
            "radii": out["radii"],
            "visible": out["visible"],
        }

    # --- construction -------------------------------------------------------------------
    @classmethod
    def from_scene(
        cls, scene, config: ReconConfig, rng: np.random.Generator
    ) -> GaussianSceneModel:
        """A model initialised from the scene's coloured LiDAR points and a far shell."""
        center, extent = camera_center_and_extent(np.asarray(scene.cam_to_world))
        points = colored_lidar_points(scene)
        spec = {
            "time_range": [float(scene.timestamps[0]), float(scene.timestamps[-1])],
            "center": [float(x) for x in center],
            "extent": extent,
            "scene_id": scene.scene_id,
        }
        rows, buffers, extra_spec = cls.initial_state(
            scene, config, points, center, rng
        )
        spec.update(extra_spec)
        spec["num_gaussians"] = int(rows["means"].shape[0])
        model = cls(spec, config.net)
        model.gaussians.set_rows({**rows, **buffers})
        return model

    @staticmethod
    def background_state(
        config: ReconConfig,
        points: ScenePoints,
        center: np.ndarray,
        rng: np.random.Generator,
    ) -> tuple[ScenePoints, dict[str, torch.Tensor], int]:
        """(subsampled LiDAR points, their rows followed by the far shell's, far point count):
        the start every backbone's ``initial_state`` builds on."""
        points = subsample(points, config.init.max_lidar_points, rng)
        rows, far_count = background_rows(
            config, points.points, points.colors, center, rng
        )
        return points, rows, far_count

    @classmethod
    def initial_state(
        cls,
        scene,
        config: ReconConfig,
        points: ScenePoints,
        center: np.ndarray,
        rng: np.random.Generator,
    ) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor], dict]:
        """(parameter rows, buffer rows, extra spec) from all coloured LiDAR ``points``.

        Default: one set of (subsampled) LiDAR points plus the far shell."""
        points, rows, far_count = cls.background_state(config, points, center, rng)
        return rows, {}, {"num_far_points": far_count}


def background_rows(
    config: ReconConfig,
    points: np.ndarray,
    colors: np.ndarray,
    center: np.ndarray,
    rng: np.random.Generator,
) -> tuple[dict[str, torch.Tensor], int]:
    """Core rows for ``points`` plus a far shell (appended last); returns (rows, shell size)."""
    radius = lidar_radius(points, center)
    far = far_shell_points(
        center, radius, config.init.far_radius, config.init.num_far_points, rng
    )
    far_colors = np.full((len(far), 3), 0.5, dtype=np.float32)
    all_points = np.concatenate([points, far]) if len(points) else far
    all_colors = np.concatenate([colors, far_colors]) if len(points) else far_colors
    rows = initial_rows(
        torch.from_numpy(all_points).float(),
        torch.from_numpy(all_colors).float(),
        torch.from_numpy(knn_log_scales(all_points)),
        config.net.sh_degree,
        config.init.initial_opacity,
    )
    return rows, len(far)
