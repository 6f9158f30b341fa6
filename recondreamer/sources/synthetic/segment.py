"""One synthetic segment: render the world from the ego camera, its LiDAR and the novel cameras."""

from __future__ import annotations

import dataclasses
import logging
import time as clock

import numpy as np

from recondreamer.errors import RecondreamerError
from recondreamer.scene.trajectories import EVAL_TRAJECTORIES, trajectory_cam_to_world
from recondreamer.scene.types import Box, FrameChannels, Polyline, SceneData
from recondreamer.sources.synthetic.config import SyntheticConfig, make_config
from recondreamer.sources.synthetic.render import BOX, SpinningLidarRays, cast, render_view
from recondreamer.sources.synthetic.world import World, build_world

GENERATOR = "recondreamer.sources.synthetic"  # metadata["generator"] of every synthetic scene
GENERATOR_VERSION = 1  # bump when the same seed would give different bytes
LIDAR_MOUNT = np.array([1.2, 0.0, 2.0])  # ego frame: LiDAR on the roof
LIDAR_ELEVATIONS_DEG = (-22.0, 6.0)  # lowest and highest ring
POLYLINE_STEP = 2.0  # metres between map polyline vertices

log = logging.getLogger(__name__)


def camera_intrinsics(config: SyntheticConfig) -> np.ndarray:  # (3,3)
    """Pinhole with the configured horizontal field of view; principal point at the image centre."""
    focal = 0.5 * config.width / np.tan(np.radians(config.hfov_deg) / 2.0)
    return np.array([[focal, 0.0, (config.width - 1) / 2.0], [0.0, focal, (config.height - 1) / 2.0], [0.0, 0.0, 1.0]])


def camera_to_ego(config: SyntheticConfig) -> np.ndarray:  # (4,4), OpenCV camera axes
    """Front camera looking along ego +x, tilted down by the configured pitch."""
    pitch = np.radians(config.camera_pitch_deg)
    forward = np.array([np.cos(pitch), 0.0, -np.sin(pitch)])  # camera z
    right = np.array([0.0, -1.0, 0.0])  # camera x
    down = np.cross(forward, right)  # camera y
    pose = np.eye(4)
    pose[:3, :3] = np.stack([right, down, forward], axis=1)
    pose[:3, 3] = [config.camera_forward, 0.0, config.camera_height]
    return pose


def box_pose(center: np.ndarray, yaw: float) -> np.ndarray:  # (4,4) object-to-world
    pose = np.eye(4)
    pose[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]]
    pose[:3, 3] = center
    return pose


def lidar_scan(world: World, time: float, config: SyntheticConfig) -> tuple[np.ndarray, np.ndarray]:
    """Points (N,3) float32 world of one LiDAR sweep, and visible points per track (V,) int."""
    ego = world.ego_pose(time)
    rays = SpinningLidarRays(
        origin=ego[:3, :3] @ LIDAR_MOUNT + ego[:3, 3],
        yaw=float(np.arctan2(ego[1, 0], ego[0, 0])),
        elevations=np.radians(np.linspace(*LIDAR_ELEVATIONS_DEG, config.lidar_beams)),
        num_azimuths=config.lidar_azimuths,
    )
    prims = world.primitives_at(time)
    hits = cast(world, prims, rays)
    returned = np.isfinite(hits.t) & (hits.t <= config.lidar_range)
    points = rays.origin + hits.t[returned, None] * rays.dirs[returned]
    on_box = hits.index[returned & (hits.kind == BOX)]
    instance = prims.box_instance[on_box]
    counts = np.bincount(instance[instance > 0] - 1, minlength=len(world.tracks))
    return points.astype(np.float32), counts


def map_polylines(world: World) -> list[Polyline]:
    """Lane centres (in driving direction), painted lines and both kerbs as world polylines."""
    layout = world.layout
    s = np.arange(world.s_extent[0], world.s_extent[1] + POLYLINE_STEP, POLYLINE_STEP)

    def line(kind: str, d: float, reverse: bool = False) -> Polyline:
        x, y, _ = layout.frame.to_world(s, np.full_like(s, d))
        points = np.stack([x, y, np.zeros_like(x)], axis=1)
        return Polyline(kind, points[::-1].copy() if reverse else points)

    polylines = [line("lane_center", d) for d in layout.forward_lane_centers]
    polylines += [line("lane_center", d, reverse=True) for d in layout.oncoming_lane_centers]
    polylines += [line("road_line", marking.d) for marking in layout.markings()]
    polylines += [line("road_edge", layout.curb_right), line("road_edge", layout.curb_left)]
    return polylines


def _empty_channels() -> FrameChannels:
    return FrameChannels(images=[], depth=[], semantics=[], instances=[], sky_masks=[])


def _append(channels: FrameChannels, view) -> None:
    channels.images.append(view.rgb)
    channels.depth.append(view.depth)
    channels.semantics.append(view.semantics)
    channels.instances.append(view.instances)
    channels.sky_masks.append(view.sky)


def generate_segment(seed: int, preset: str = "default", scene_id: str | None = None, **overrides) -> SceneData:
    """Build and render the segment of ``seed`` (deterministic: same seed and settings, same bytes).

    ``overrides`` are ``SyntheticConfig`` fields (width, height, frames, ...) replacing the
    preset's values. With ``novel_views`` (the default) the true views of every evaluation
    trajectory (shift@3, shift@6, lane_change) are rendered into ``SceneData.novel``.
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise RecondreamerError(f"synthetic seed {seed!r}: must be a non-negative integer")
    config = make_config(preset, **overrides)
    started = clock.perf_counter()
    times = np.arange(config.frames) / config.frame_rate  # (T,)
    world = build_world(int(seed), horizon=float(times[-1]), camera_forward=config.camera_forward)
    K = camera_intrinsics(config)
    cam_to_ego = camera_to_ego(config)
    ego_to_world = np.stack([world.ego_pose(t) for t in times])  # (T,4,4)
    cam_to_world = ego_to_world @ cam_to_ego  # (T,4,4)
    novel_names = EVAL_TRAJECTORIES if config.novel_views else ()
    novel_poses = {name: trajectory_cam_to_world(cam_to_world, ego_to_world, name) for name in novel_names}

    frames = _empty_channels()
    novel = {name: _empty_channels() for name in novel_names}
    lidar: list[np.ndarray] = []
    boxes: list[list[Box]] = []
    for index, time in enumerate(times):
        prims = world.primitives_at(float(time))
        _append(frames, render_view(world, prims, cam_to_world[index], K, config.width, config.height))
        for name in novel_names:
            _append(novel[name], render_view(world, prims, novel_poses[name][index], K, config.width, config.height))
        points, counts = lidar_scan(world, float(time), config)
        lidar.append(points)
        centers, yaws = world.vehicle_poses(float(time))
        boxes.append(
            [
                Box(track.track_id, "vehicle", track.size.copy(), box_pose(centers[i], yaws[i]), int(counts[i]), abs(track.speed))
                for i, track in enumerate(world.tracks)
            ]
        )
        if (index + 1) % 10 == 0 or index + 1 == len(times):
            elapsed = clock.perf_counter() - started
            log.info("seed %d: frame %d/%d rendered (%.1f s, ETA %.1f s)", seed, index + 1, len(times), elapsed, elapsed / (index + 1) * (len(times) - index - 1))

    layout = world.layout
    return SceneData(
        scene_id=scene_id or f"synth-seed{seed}",
        source="synthetic",
        width=config.width,
        height=config.height,
        K=K,
        distortion=np.zeros(5),
        cam_to_ego=cam_to_ego,
        ego_to_world=ego_to_world,
        timestamps=times,
        frames=frames,
        lidar=lidar,
        boxes=boxes,
        map_polylines=map_polylines(world),
        track_ids=world.track_ids,
        novel=novel,
        metadata={
            "generator": GENERATOR,
            "generator_version": GENERATOR_VERSION,
            "seed": int(seed),
            "preset": preset,
            "config": dataclasses.asdict(config),
            "world": {
                "curvature": layout.frame.kappa,
                "lane_width": layout.lane_width,
                "num_lanes": layout.num_lanes,
                "ego_lane": "second driving lane from the right: one forward lane to its right, two to its left",
                "oncoming_lanes": layout.oncoming_lanes,
                "ego_speed": world.ego_speed,
                "moving_vehicles": sum(track.speed != 0 for track in world.tracks),
                "parked_vehicles": sum(track.speed == 0 for track in world.tracks),
            },
        },
    )
