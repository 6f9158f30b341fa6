"""Training views and the weighted training set every backbone trains on.

A ``TrainingView`` is one supervised image: camera pose, timestamp, RGB, and optional LiDAR
depth and sky mask, with a source tag ("original", "pdus:k", "dd4d", ...) and a sampling
weight. Views without depth (generated novel-trajectory frames) never get a depth loss: the
paper's depth-free loss for generated data. Sampling picks a view with probability
proportional to its weight, so later stages mix novel data in by weight (PDUS: 50/50 between
original and novel, newest novel video with probability w).
"""

from __future__ import annotations

from collections import Counter, OrderedDict
from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from recondreamer.errors import RecondreamerError
from recondreamer.recon.losses import image_tensor
from recondreamer.recon.sky import pixel_ray_directions
from recondreamer.recon.ssim import SSIMTarget
from recondreamer.scene.cameras import (
    pixel_indices,
    project_points,
    rasterizer_intrinsics,
    world_to_camera,
)

ORIGINAL = "original"


@dataclass
class TrainingView:
    """One supervised view.

    Its image, depth and sky mask are read once, the first time the trainer draws it (see
    ``TargetCache``): to change them, add a new view (PDUS adds a new video at each update).
    """

    cam_to_world: np.ndarray  # (4,4)
    timestamp: float  # seconds, on the scene's clock
    image: np.ndarray  # (H,W,3) uint8
    depth: np.ndarray | None = (
        None  # (H,W) float32 metres along camera z, 0 = no target
    )
    sky_mask: np.ndarray | None = None  # (H,W) bool
    source: str = ORIGINAL
    weight: float = 1.0
    frame: int | None = None  # frame index in the scene, when the view belongs to one


def lidar_depth_map(
    points_world: np.ndarray,
    K: np.ndarray,
    cam_to_world: np.ndarray,
    width: int,
    height: int,
) -> np.ndarray:
    """Sparse depth target (H,W) float32: nearest LiDAR z per pixel, 0 where no point lands."""
    depth = np.full((height, width), np.inf, dtype=np.float64)
    if len(points_world):
        uv, z = project_points(
            np.asarray(points_world, dtype=np.float64), K, world_to_camera(cam_to_world)
        )
        front = z > 0.1
        u, v = pixel_indices(np.where(front[:, None], uv, -1.0))
        keep = front & (u >= 0) & (u < width) & (v >= 0) & (v < height)
        np.minimum.at(depth, (v[keep], u[keep]), z[keep])
    depth[~np.isfinite(depth)] = 0.0
    return depth.astype(np.float32)


def downsample_targets(
    image: torch.Tensor,  # (H,W,3)
    depth: np.ndarray | None,  # (H,W)
    sky_mask: np.ndarray | None,  # (H,W)
    K: np.ndarray,  # (3,3)
    factor: int,
) -> tuple[torch.Tensor, np.ndarray | None, np.ndarray | None, np.ndarray]:
    """Targets at 1/factor resolution for coarse-to-fine training, and the matching intrinsics.

    RGB is box-filtered; sky masks take the majority; sparse LiDAR depth keeps the nearest
    return of each block (0 = none stays none).
    """
    height, width = image.shape[0] // factor, image.shape[1] // factor
    crop = (slice(0, height * factor), slice(0, width * factor))
    small = F.avg_pool2d(image[crop].permute(2, 0, 1)[None], factor)[0].permute(1, 2, 0)
    small_depth = small_sky = None
    if depth is not None:
        blocks = (
            np.where(depth > 0, depth, np.inf)[crop]
            .reshape(height, factor, width, factor)
            .min(axis=(1, 3))
        )
        small_depth = np.where(np.isfinite(blocks), blocks, 0.0).astype(np.float32)
    if sky_mask is not None:
        small_sky = (
            np.asarray(sky_mask)[crop]
            .reshape(height, factor, width, factor)
            .mean(axis=(1, 3))
            > 0.5
        )
    scale = np.diag([width / image.shape[1], height / image.shape[0], 1.0])
    return small, small_depth, small_sky, scale @ np.asarray(K, dtype=np.float64)


@dataclass
class ViewTargets:
    """One view's supervision at one resolution, as tensors ready for a training step."""

    image: SSIMTarget  # RGB (h,w,3) in [0,1] with its SSIM statistics
    depth: (
        torch.Tensor | None
    )  # (h,w) LiDAR depth, 0 = no target; None = depth-free view
    sky_mask: torch.Tensor | None  # (h,w) bool
    K: np.ndarray  # (3,3) intrinsics at this resolution (scene convention)
    ray_directions: (
        torch.Tensor
    )  # (h,w,3) unit world directions of the pixels (sky lookup)

    def nbytes(self) -> int:
        tensors = (
            self.image.image,
            self.image.channels,
            self.image.mean,
            self.image.variance,
            self.depth,
            self.sky_mask,
            self.ray_directions,
        )
        return sum(t.numel() * t.element_size() for t in tensors if t is not None)


class TargetCache:
    """Targets of training views as tensors, built the first time a view is drawn at a resolution.

    Converting, downsampling and (for SSIM) blurring a target costs as much as a good part of
    a CPU training step, and every view is drawn many times. Entries are keyed by view identity
    (the entry holds the view, so the identity cannot be reused while cached) and evicted least
    recently used beyond ``max_bytes``.
    """

    def __init__(
        self,
        ssim_window: int,
        device: torch.device | str = "cpu",
        max_bytes: int = 2 * 1024**3,
    ) -> None:
        self.ssim_window = ssim_window
        self.device = torch.device(device)
        self.max_bytes = max_bytes
        self.entries: OrderedDict[tuple[int, int], tuple[TrainingView, ViewTargets]] = (
            OrderedDict()
        )
        self.bytes = 0

    def get(self, view: TrainingView, K: np.ndarray, factor: int = 1) -> ViewTargets:
        """``view``'s targets at 1/``factor`` resolution; ``K`` are its full-resolution intrinsics."""
        key = (id(view), factor)
        entry = self.entries.get(key)
        if entry is not None and entry[0] is view:
            self.entries.move_to_end(key)
            return entry[1]
        targets = self.build(view, K, factor)
        self.entries[key] = (view, targets)
        self.bytes += targets.nbytes()
        while self.bytes > self.max_bytes and len(self.entries) > 1:
            _, (_, evicted) = self.entries.popitem(last=False)
            self.bytes -= evicted.nbytes()
        return targets

    def build(self, view: TrainingView, K: np.ndarray, factor: int) -> ViewTargets:
        image = image_tensor(view.image).to(self.device)  # (H,W,3)
        depth, sky_mask = view.depth, view.sky_mask
        if factor > 1:
            image, depth, sky_mask, K = downsample_targets(
                image, depth, sky_mask, K, factor
            )
        height, width = image.shape[:2]
        # Copies (np.array): scene arrays can be read-only, which torch.from_numpy warns about.
        cam_to_world = torch.from_numpy(
            np.array(view.cam_to_world, dtype=np.float32)
        ).to(self.device)
        K_raster = rasterizer_intrinsics(
            torch.from_numpy(np.array(K, dtype=np.float32)).to(self.device)
        )
        return ViewTargets(
            image=SSIMTarget.from_image(image, self.ssim_window),
            depth=None
            if depth is None
            else torch.from_numpy(np.array(depth, dtype=np.float32)).to(self.device),
            sky_mask=None
            if sky_mask is None
            else torch.from_numpy(np.array(sky_mask, dtype=bool)).to(self.device),
            K=np.asarray(K, dtype=np.float64),
            ray_directions=pixel_ray_directions(cam_to_world, K_raster, width, height),
        )


class TrainingSet:
    """Views of one camera model (K, width, height), sampled by weight."""

    def __init__(
        self, K: np.ndarray, width: int, height: int, views: Iterable[TrainingView] = ()
    ) -> None:
        self.K = np.asarray(K, dtype=np.float64)
        self.width, self.height = int(width), int(height)
        self.views: list[TrainingView] = []
        self.extend(views)

    @classmethod
    def from_scene(
        cls, scene, frames: Iterable[int] | None = None, weight: float = 1.0
    ) -> TrainingSet:
        """Original frames (all, or ``frames``) with LiDAR depth targets and sky masks."""
        frames = range(scene.num_frames) if frames is None else frames
        views = []
        for t in frames:
            views.append(
                TrainingView(
                    cam_to_world=np.asarray(scene.cam_to_world[t], dtype=np.float64),
                    timestamp=float(scene.timestamps[t]),
                    image=np.asarray(scene.image(t)),
                    depth=lidar_depth_map(
                        scene.lidar(t),
                        scene.K,
                        scene.cam_to_world[t],
                        scene.width,
                        scene.height,
                    ),
                    sky_mask=scene.sky_mask(t),
                    source=ORIGINAL,
                    weight=weight,
                    frame=int(t),
                )
            )
        return cls(scene.K, scene.width, scene.height, views)

    def add(self, view: TrainingView) -> None:
        image = np.asarray(view.image)
        if image.shape != (self.height, self.width, 3) or image.dtype != np.uint8:
            raise RecondreamerError(
                f"training view from {view.source!r}: image must be ({self.height},{self.width},3) uint8, "
                f"got {image.shape} {image.dtype}"
            )
        for name in ("depth", "sky_mask"):
            value = getattr(view, name)
            if value is not None and np.asarray(value).shape != (
                self.height,
                self.width,
            ):
                raise RecondreamerError(
                    f"training view from {view.source!r}: {name} must be ({self.height},{self.width}), got {np.asarray(value).shape}"
                )
        if not (view.weight >= 0 and np.isfinite(view.weight)):
            raise RecondreamerError(
                f"training view from {view.source!r}: weight must be >= 0, got {view.weight}"
            )
        self.views.append(view)

    def extend(self, views: Iterable[TrainingView]) -> None:
        for view in views:
            self.add(view)

    def remove_source(self, source: str) -> int:
        """Drop every view with this tag; returns how many were dropped."""
        before = len(self.views)
        self.views = [view for view in self.views if view.source != source]
        return before - len(self.views)

    def set_source_weight(self, source: str, total: float) -> None:
        """Spread a total sampling weight evenly over the views of one source."""
        members = [view for view in self.views if view.source == source]
        if not members:
            raise RecondreamerError(f"training set has no views from source {source!r}")
        for view in members:
            view.weight = total / len(members)

    def sources(self) -> dict[str, int]:
        return dict(Counter(view.source for view in self.views))

    def probabilities(self) -> np.ndarray:  # (V,)
        weights = np.array([view.weight for view in self.views], dtype=np.float64)
        if len(weights) == 0 or weights.sum() <= 0:
            raise RecondreamerError(
                "training set is empty or all sampling weights are 0"
            )
        return weights / weights.sum()

    def sample(self, rng: np.random.Generator) -> TrainingView:
        return self.views[int(rng.choice(len(self.views), p=self.probabilities()))]

    def __len__(self) -> int:
        return len(self.views)

    def __iter__(self) -> Iterator[TrainingView]:
        return iter(self.views)

    def __getitem__(self, index: int) -> TrainingView:
        return self.views[index]
