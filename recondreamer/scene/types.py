"""Plain data types shared by every scene source and consumer.

Shapes are given in trailing comments; every array is numpy. Conventions:

- world frame = ego frame of frame 0 (x forward, y left, z up), metres;
- cameras use OpenCV axes (x right, y down, z forward);
- ``obj_to_world`` of a box puts the box centre at the origin, x along its length
  (heading), y along its width (left), z up.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

BOX_LABELS = ("vehicle", "pedestrian", "cyclist", "sign")
POLYLINE_KINDS = ("lane_center", "road_line", "road_edge", "crosswalk")
# Semantic label ids written to ``semantics/{t:03d}.png`` (synthetic scenes) and their names.
SEMANTIC_CLASSES = (
    "void",
    "road",
    "lane_marking",
    "sidewalk",
    "building",
    "vegetation",
    "pole",
    "vehicle",
    "sky",
)


@dataclass(frozen=True)
class Box:
    """One tracked 3D box at one frame."""

    track_id: str
    label: str  # one of BOX_LABELS
    size: np.ndarray  # (3,) length, width, height in metres
    obj_to_world: np.ndarray  # (4,4)
    num_points: int  # LiDAR points inside the box (visibility filter of NTA-IoU)
    speed: float = 0.0  # m/s, 0 where the source does not know it

    def corners(self) -> np.ndarray:  # (8,3) world
        """The 8 box corners in world coordinates (signs of x, y, z in binary order)."""
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
        local = signs * (np.asarray(self.size, dtype=np.float64) / 2.0)
        return local @ self.obj_to_world[:3, :3].T + self.obj_to_world[:3, 3]


@dataclass(frozen=True)
class Polyline:
    """One HD-map polyline in world coordinates."""

    kind: str  # one of POLYLINE_KINDS
    points: np.ndarray  # (M,3) world, M >= 2


@dataclass
class FrameChannels:
    """Per-frame image-like channels of one camera trajectory (original or novel).

    ``images`` holds (H,W,3) uint8 arrays, or already-encoded JPEG/PNG bytes (Waymo JPEGs are
    kept as they are). The optional channels are None when the source does not have them.
    """

    images: list  # T x ((H,W,3) uint8 | bytes)
    depth: list[np.ndarray] | None = None  # T x (H,W) float32 metres along the camera z axis, 0 = no hit (sky)
    semantics: list[np.ndarray] | None = None  # T x (H,W) uint8 ids into SEMANTIC_CLASSES
    instances: list[np.ndarray] | None = None  # T x (H,W) int32, 0 = none, else 1 + index into track_ids
    sky_masks: list[np.ndarray] | None = None  # T x (H,W) bool


@dataclass
class SceneData:
    """Everything a scene directory holds, in memory: what sources build and ``write_scene`` writes."""

    scene_id: str
    source: str  # "synthetic" | "waymo" | ...
    width: int
    height: int
    K: np.ndarray  # (3,3)
    distortion: np.ndarray  # (5,) k1 k2 p1 p2 k3
    cam_to_ego: np.ndarray  # (4,4) camera (OpenCV axes) to ego, constant over the segment
    ego_to_world: np.ndarray  # (T,4,4)
    timestamps: np.ndarray  # (T,) seconds
    frames: FrameChannels  # original trajectory
    lidar: list[np.ndarray]  # T x (N,3) float32 world
    boxes: list[list[Box]]  # T x boxes
    map_polylines: list[Polyline] = field(default_factory=list)
    track_ids: list[str] = field(default_factory=list)  # instance id i+1 <-> track_ids[i]
    novel: dict[str, FrameChannels] = field(default_factory=dict)  # true novel views, trajectory name -> channels
    metadata: dict = field(default_factory=dict)  # free-form provenance (seed, preset, source file, frame range)

    @property
    def num_frames(self) -> int:
        return len(self.timestamps)
