"""A tiny hand-built scene for the scene tests: 3 frames 32x24, 2 boxes, 2 polylines, one novel trajectory."""

from __future__ import annotations

import numpy as np

from recondreamer.scene.types import Box, FrameChannels, Polyline, SceneData

WIDTH, HEIGHT, FRAMES = 32, 24, 3

# OpenCV camera (x right, y down, z forward) looking along ego +x (forward), 1.5 m above the ego origin.
CAM_TO_EGO = np.array(
    [
        [0.0, 0.0, 1.0, 1.0],
        [-1.0, 0.0, 0.0, 0.0],
        [0.0, -1.0, 0.0, 1.5],
        [0.0, 0.0, 0.0, 1.0],
    ]
)


def yaw_pose(x: float, y: float, z: float, yaw: float) -> np.ndarray:  # (4,4)
    c, s = np.cos(yaw), np.sin(yaw)
    pose = np.eye(4)
    pose[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    pose[:3, 3] = [x, y, z]
    return pose


def make_channels(rng: np.random.Generator, with_sky: bool) -> FrameChannels:
    return FrameChannels(
        images=[rng.integers(0, 256, (HEIGHT, WIDTH, 3), dtype=np.uint8) for _ in range(FRAMES)],
        depth=[rng.uniform(0.0, 80.0, (HEIGHT, WIDTH)).astype(np.float32) for _ in range(FRAMES)],
        semantics=[rng.integers(0, 9, (HEIGHT, WIDTH), dtype=np.uint8) for _ in range(FRAMES)],
        instances=[rng.integers(0, 3, (HEIGHT, WIDTH)).astype(np.int32) for _ in range(FRAMES)],
        sky_masks=[rng.random((HEIGHT, WIDTH)) > 0.5 for _ in range(FRAMES)] if with_sky else None,
    )


def make_scene_data(seed: int = 0) -> SceneData:
    rng = np.random.default_rng(seed)
    ego = np.stack([yaw_pose(1.2 * t, 0.0, 0.0, 0.01 * t) for t in range(FRAMES)])
    boxes = [
        [
            Box(
                "car-1",
                "vehicle",
                np.array([4.5, 1.9, 1.6]),
                yaw_pose(12.0 + t, 0.0, 0.8, 0.0),
                num_points=40 + t,
                speed=10.0,
            ),
            Box("ped-7", "pedestrian", np.array([0.6, 0.6, 1.8]), yaw_pose(9.0, 3.0, 0.9, 1.2), num_points=5),
        ]
        for t in range(FRAMES)
    ]
    polylines = [
        Polyline("road_line", np.array([[0.0, 1.75, 0.0], [20.0, 1.75, 0.0], [40.0, 1.8, 0.0]])),
        Polyline("road_edge", np.array([[-5.0, -5.0, 0.0], [50.0, -5.0, 0.0]])),
    ]
    return SceneData(
        scene_id="tiny",
        source="test",
        width=WIDTH,
        height=HEIGHT,
        K=np.array([[20.0, 0.0, 16.0], [0.0, 20.0, 12.0], [0.0, 0.0, 1.0]]),
        distortion=np.array([0.01, -0.002, 0.0005, -0.0003, 0.0001]),
        cam_to_ego=CAM_TO_EGO,
        ego_to_world=ego,
        timestamps=np.array([0.0, 0.1, 0.2]),
        frames=make_channels(rng, with_sky=True),
        lidar=[rng.normal(size=(10 + t, 3)).astype(np.float32) for t in range(FRAMES)],
        boxes=boxes,
        map_polylines=polylines,
        track_ids=["car-1", "ped-7"],
        novel={"shift@3": make_channels(rng, with_sky=False)},
        metadata={"seed": seed, "note": "hand-built"},
    )
