"""The ground-truth renderer: boxes match instance masks, novel views move the right way, LiDAR counts."""

from __future__ import annotations

import numpy as np
import pytest

from recondreamer.scene.structure import project_box_2d
from recondreamer.scene.trajectories import lateral_offsets, trajectory_cam_to_world
from recondreamer.scene.types import SEMANTIC_CLASSES
from recondreamer.sources.synthetic import generate_segment

GROUND = [SEMANTIC_CLASSES.index(name) for name in ("road", "lane_marking", "sidewalk")]
VEHICLE, SKY = SEMANTIC_CLASSES.index("vehicle"), SEMANTIC_CLASSES.index("sky")


@pytest.fixture(scope="module")
def segment():
    return generate_segment(11, "quick", width=192, height=128, frames=11)


def _poses(data, name):
    cams = data.ego_to_world @ data.cam_to_ego
    return cams if name == "original" else trajectory_cam_to_world(cams, data.ego_to_world, name)


def _channels(data, name):
    return data.frames if name == "original" else data.novel[name]


def _unoccluded_boxes(data, name, t):
    """(instance id, projected 2D box, instance mask) of vehicles nothing can hide.

    A vehicle counts as unoccluded when its 3D box projects fully inside the image, at least
    20 px wide and high (so that pixel quantisation stays below the IoU tolerance), and no pixel of its 2D box shows anything other than itself, the ground
    or sky nearer than its farthest corner.
    """
    channels = _channels(data, name)
    cam = _poses(data, name)[t]
    instances, depth, semantics = channels.instances[t], channels.depth[t], channels.semantics[t]
    world_to_cam = np.linalg.inv(cam)
    found = []
    for index, box in enumerate(data.boxes[t]):
        box2d = project_box_2d(box, data.K, cam, data.width, data.height)
        if not box2d.fully_inside:
            continue
        x0, y0, x1, y1 = box2d.xyxy
        if x1 - x0 < 20 or y1 - y0 < 20:
            continue
        far = (box.corners() @ world_to_cam[:3, :3].T + world_to_cam[:3, 3])[:, 2].max()
        cols = slice(int(np.ceil(x0 - 0.5)), int(np.floor(x1 - 0.5)) + 1)
        rows = slice(int(np.ceil(y0 - 0.5)), int(np.floor(y1 - 0.5)) + 1)
        others = (instances[rows, cols] != index + 1) & ~np.isin(semantics[rows, cols], GROUND + [SKY])
        if np.any(others & (depth[rows, cols] < far)):
            continue
        found.append((index + 1, box2d, instances == index + 1))
    return found


def _iou(a, b) -> float:
    inter = max(0.0, min(a[2], b[2]) - max(a[0], b[0])) * max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    area = lambda r: (r[2] - r[0]) * (r[3] - r[1])
    return inter / (area(a) + area(b) - inter)


@pytest.mark.parametrize("name", ["original", "shift@3", "shift@6"])
def test_projected_boxes_match_instance_masks(segment, name):
    checked = 0
    for t in range(0, segment.num_frames, 2):
        for _, box2d, mask in _unoccluded_boxes(segment, name, t):
            rows, cols = np.nonzero(mask)
            mask_box = (cols.min() - 0.5, rows.min() - 0.5, cols.max() + 0.5, rows.max() + 0.5)  # pixel edges
            assert _iou(mask_box, box2d.xyxy) >= 0.9, (name, t, box2d.track_id, mask_box, box2d.xyxy)
            checked += 1
    assert checked >= 5, f"only {checked} unoccluded vehicles to check"


def test_channels_agree_with_each_other(segment):
    for channels in [segment.frames] + list(segment.novel.values()):
        for t in range(segment.num_frames):
            semantics, instances, depth, sky = channels.semantics[t], channels.instances[t], channels.depth[t], channels.sky_masks[t]
            assert np.array_equal(instances > 0, semantics == VEHICLE)
            assert np.array_equal(sky, semantics == SKY) and np.array_equal(sky, depth == 0)
            assert instances.max() <= len(segment.track_ids)
            assert (semantics == SEMANTIC_CLASSES.index("lane_marking")).any(), "no lane marking visible"


def _lateral_agreement(data, name, t, offset, sign):
    """Fraction of non-ground original pixels whose depth the novel view reproduces where a
    camera moved ``offset`` metres left should see them (sign -1: the wrong direction)."""
    depth = data.frames.depth[t]
    semantics = data.frames.semantics[t]
    novel_depth = data.novel[name].depth[t]
    fx = data.K[0, 0]
    rows, cols = np.nonzero((depth > 0) & (depth < 60) & ~np.isin(semantics, GROUND))
    z = depth[rows, cols].astype(np.float64)
    # Moving left by Y along the camera's -x axis (no roll): u' = u + fx * Y / z, v' = v, z' = z.
    target = np.round(cols + sign * fx * offset / z).astype(int)
    inside = (target >= 0) & (target < data.width)
    found = novel_depth[rows[inside], target[inside]]
    return float(np.mean(np.abs(found - z[inside]) < 0.02 * z[inside]))


def test_lateral_shift_moves_the_image_right_with_consistent_depth(segment):
    for t in (0, 5, 10):
        right = _lateral_agreement(segment, "shift@3", t, 3.0, +1)
        wrong = _lateral_agreement(segment, "shift@3", t, 3.0, -1)
        assert right >= 0.85, (t, right)
        assert wrong < right - 0.3, (t, right, wrong)
    # Objects move right in the image: the centre of every vehicle seen unoccluded in both views.
    moved = 0
    for t in range(segment.num_frames):
        original = {i: m for i, _, m in _unoccluded_boxes(segment, "original", t)}
        for instance, _, mask in _unoccluded_boxes(segment, "shift@3", t):
            if instance in original:
                assert np.nonzero(mask)[1].mean() > np.nonzero(original[instance])[1].mean()
                moved += 1
    assert moved >= 3


def test_lane_change_offsets(segment):
    lane_change = segment.novel["lane_change"]
    assert np.array_equal(lane_change.images[0], segment.frames.images[0])  # offset 0 at frame 0
    assert not np.array_equal(lane_change.images[10], segment.frames.images[10])
    offset = float(lateral_offsets("lane_change", segment.num_frames)[3])
    assert _lateral_agreement(segment, "lane_change", 3, offset, +1) >= 0.85
    assert _lateral_agreement(segment, "lane_change", 3, offset / 2, +1) < 0.6


def test_lidar_points_and_visible_counts(segment):
    config = segment.metadata["config"]
    for t in range(0, segment.num_frames, 5):
        points = segment.lidar[t].astype(np.float64)
        assert points.dtype.kind == "f" and len(points) > 1000
        origin = segment.ego_to_world[t, :3, 3]
        assert np.linalg.norm(points - origin, axis=1).max() <= config["lidar_range"] + 2.5
        assert points[:, 2].min() > -0.01  # nothing below the road: no sky returns, no misses
        for box in segment.boxes[t]:
            local = (points - box.obj_to_world[:3, 3]) @ box.obj_to_world[:3, :3]
            half = np.asarray(box.size) / 2
            # Inside the box, not on the road beneath it (the box bottom lies on the road).
            inside = np.all(np.abs(local) <= half + 0.02, axis=1) & (local[:, 2] > 1e-3 - half[2])
            assert int(inside.sum()) == box.num_points, (t, box.track_id)
        assert sum(box.num_points >= 10 for box in segment.boxes[t]) >= 3


def test_map_polylines(segment):
    kinds = [p.kind for p in segment.map_polylines]
    assert kinds.count("road_edge") == 2 and kinds.count("road_line") >= 5 and kinds.count("lane_center") >= 5
    ego_lane = segment.map_polylines[1].points  # forward lanes right to left: index 1 is the ego lane
    for pose in segment.ego_to_world:
        assert np.min(np.linalg.norm(ego_lane[:, :2] - pose[:2, 3], axis=1)) < 1.5  # vertices every 2 m


def test_footprint_culling_matches_exhaustive_casting():
    from recondreamer.sources.synthetic import make_config
    from recondreamer.sources.synthetic.render import ExhaustiveRays, PinholeRays, SpinningLidarRays, cast
    from recondreamer.sources.synthetic.segment import camera_intrinsics, camera_to_ego
    from recondreamer.sources.synthetic.world import build_world

    config = make_config("quick", width=80, height=56)
    for seed, time in ((2, 0.0), (8, 2.5)):
        world = build_world(seed)
        prims = world.primitives_at(time)
        ego = world.ego_pose(time)
        bundles = [
            PinholeRays(ego @ camera_to_ego(config), camera_intrinsics(config), config.width, config.height),
            # A camera beside the parked cars, looking back-left: primitives straddle its near plane.
            PinholeRays(ego @ camera_to_ego(config) @ np.array([[0, 0, 1, 3], [0, 1, 0, 0], [-1, 0, 0, 2], [0, 0, 0, 1.0]]), camera_intrinsics(config), 40, 28),
            SpinningLidarRays(ego[:3, 3] + [0.0, 0.0, 2.0], 0.3, np.radians(np.linspace(-25, 10, 8)), 90),
        ]
        for rays in bundles:
            fast, reference = cast(world, prims, rays), cast(world, prims, ExhaustiveRays(rays))
            assert np.array_equal(fast.t, reference.t) and np.array_equal(fast.kind, reference.kind)
            assert np.array_equal(fast.index, reference.index)
