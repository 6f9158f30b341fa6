"""The procedural world: determinism, road layout, vehicle mix and the evaluation-camera corridor."""

from __future__ import annotations

import numpy as np
import pytest

from recondreamer.errors import RecondreamerError
from recondreamer.scene.trajectories import EVAL_TRAJECTORIES, lateral_offsets, trajectory_cam_to_world
from recondreamer.sources.synthetic import generate_segment, make_config
from recondreamer.sources.synthetic.road import RoadFrame
from recondreamer.sources.synthetic.segment import camera_to_ego
from recondreamer.sources.synthetic.world import build_world

SEEDS = range(25)


def _channels_bytes(channels) -> list[bytes]:
    arrays = channels.images + channels.depth + channels.semantics + channels.instances + channels.sky_masks
    return [np.ascontiguousarray(a).tobytes() for a in arrays]


def test_same_seed_same_bytes_and_different_seeds_differ():
    first = generate_segment(3, "quick", frames=3)
    again = generate_segment(3, "quick", frames=3)
    other = generate_segment(4, "quick", frames=3)
    assert _channels_bytes(first.frames) == _channels_bytes(again.frames)
    for name in EVAL_TRAJECTORIES:
        assert _channels_bytes(first.novel[name]) == _channels_bytes(again.novel[name])
    assert all(a.tobytes() == b.tobytes() for a, b in zip(first.lidar, again.lidar))
    assert [[b.obj_to_world.tobytes() for b in f] for f in first.boxes] == [[b.obj_to_world.tobytes() for b in f] for f in again.boxes]
    assert first.metadata == again.metadata
    assert not np.array_equal(first.frames.images[0], other.frames.images[0])
    assert first.track_ids != other.track_ids or not np.array_equal(first.ego_to_world, other.ego_to_world)


def test_presets_and_overrides():
    quick = generate_segment(1, "quick", frames=2, width=64, height=40, novel_views=False)
    assert (quick.width, quick.height, quick.num_frames) == (64, 40, 2)
    assert quick.frames.images[0].shape == (40, 64, 3) and quick.novel == {}
    assert np.allclose(np.diff(quick.timestamps), 0.1)
    assert np.allclose(quick.ego_to_world[0], np.eye(4))  # world = ego frame of frame 0
    cam = quick.ego_to_world[0] @ quick.cam_to_ego
    assert np.isclose(cam[2, 3], 1.6) and cam[:3, 2] @ [1.0, 0.0, 0.0] > 0.99  # 1.6 m high, optical axis forward
    assert np.allclose(cam[:3, 0], [0.0, -1.0, 0.0]) and cam[2, 1] < -0.99  # OpenCV: x right, y down
    hfov = 2 * np.degrees(np.arctan(quick.width / 2 / quick.K[0, 0]))
    assert abs(hfov - 50.0) < 0.01
    default = make_config("default")
    assert (default.width, default.height, default.frames) == (240, 160, 40)
    with pytest.raises(RecondreamerError, match="preset"):
        make_config("huge")
    with pytest.raises(RecondreamerError, match="colour"):
        make_config("quick", colour=3)
    with pytest.raises(RecondreamerError, match="width"):
        make_config("quick", width=0)
    with pytest.raises(RecondreamerError, match="seed"):
        generate_segment(-1, "quick")


def test_road_frame_round_trip_and_normal_shift():
    rng = np.random.default_rng(0)
    s, d = rng.uniform(-50, 200, 100), rng.uniform(-20, 20, 100)
    for kappa in (0.0, 1 / 300, -1 / 260):
        frame = RoadFrame(kappa)
        x, y, _ = frame.to_world(s, d)
        s2, d2 = frame.to_road(x, y)
        assert np.allclose(s2, s, atol=1e-9) and np.allclose(d2, d, atol=1e-9)
        # Moving a centre-line point along its left normal keeps s and changes d by the distance.
        x0, y0, h0 = frame.to_world(s, 0.0 * s)
        s3, d3 = frame.to_road(x0 - 6.0 * np.sin(h0), y0 + 6.0 * np.cos(h0))
        assert np.allclose(s3, s, atol=1e-9) and np.allclose(d3, 6.0, atol=1e-9)


def test_world_content_per_seed():
    for seed in SEEDS:
        world = build_world(seed)
        layout = world.layout
        moving = [t for t in world.tracks if t.speed != 0]
        kinds = {t.kind for t in moving}
        assert layout.num_lanes >= 4 and len(layout.forward_lane_centers[layout.forward_lane_centers > 0]) >= 2
        assert len(moving) >= 8, seed
        assert {"car", "van"} <= kinds and kinds & {"bus", "truck"}, (seed, kinds)
        assert any(t.speed < 0 for t in moving), "no oncoming vehicle"
        assert any(t.speed > world.ego_speed for t in moving), "no vehicle faster than the ego"
        assert len(set(world.track_ids)) == len(world.tracks)
        assert 8.0 <= world.ego_speed <= 12.0
        assert any(not m.dashed for m in layout.markings()) and any(m.dashed for m in layout.markings())


def _footprint_distance(point: np.ndarray, center: np.ndarray, yaw: float, size: np.ndarray) -> float:
    """Horizontal distance from a point to a vehicle's footprint rectangle (0 inside)."""
    rel = point[:2] - center[:2]
    local = np.array([np.cos(yaw) * rel[0] + np.sin(yaw) * rel[1], -np.sin(yaw) * rel[0] + np.cos(yaw) * rel[1]])
    outside = np.maximum(np.abs(local) - size[:2] / 2.0, 0.0)
    return float(np.hypot(*outside))


def test_novel_cameras_stay_on_the_road_and_clear_of_vehicles():
    config = make_config("default")
    times = np.arange(config.frames) / config.frame_rate
    for seed in SEEDS:
        world = build_world(seed)
        layout = world.layout
        ego = np.stack([world.ego_pose(t) for t in times])
        cams = ego @ camera_to_ego(config)
        sizes = [t.size for t in world.tracks]
        for name in ("original",) + EVAL_TRAJECTORIES:
            positions = trajectory_cam_to_world(cams, ego, name)[:, :3, 3]  # (T,3)
            _, d = layout.frame.to_road(positions[:, 0], positions[:, 1])
            # The camera sits 1.5 m ahead of the ego on the tangent of a (possibly) curved lane:
            # its d differs from the offset by kappa * 1.5^2 / 2 < 3 mm.
            assert np.allclose(d, lateral_offsets(name, config.frames), atol=0.005), (seed, name)
            # On the forward driving lanes, at least 1.5 m inside the edge line and the divider.
            assert np.all(d > -1.5 * layout.lane_width + 1.5) and np.all(d < layout.divider - 1.5), (seed, name, d.max())
            for t, time in enumerate(times):
                centers, yaws = world.vehicle_poses(time)
                clearance = min(_footprint_distance(positions[t], c, y, s) for c, y, s in zip(centers, yaws, sizes))
                assert clearance >= 2.0, (seed, name, t, clearance)
