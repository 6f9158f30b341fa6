"""Novel trajectories: names, lateral offsets, moved cameras, pose files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from recondreamer.scene import load_scene, write_scene
from recondreamer.scene.cameras import project_points, world_to_camera
from recondreamer.scene.trajectories import (
    EVAL_TRAJECTORIES,
    lateral_offsets,
    parse_trajectory,
    trajectory_cam_to_world,
)
from scene_fixtures import CAM_TO_EGO, make_scene_data, yaw_pose

NUM_FRAMES = 40


def curved_ego(num_frames: int = NUM_FRAMES) -> np.ndarray:  # (T,4,4) ego turning left
    return np.stack([yaw_pose(1.0 * t, 0.02 * t * t, 0.0, 0.05 * t) for t in range(num_frames)])


def test_eval_trajectories_are_the_papers():
    assert EVAL_TRAJECTORIES == ("shift@3", "shift@6", "lane_change")


def test_lateral_offsets():
    np.testing.assert_array_equal(lateral_offsets("original", NUM_FRAMES), np.zeros(NUM_FRAMES))
    np.testing.assert_array_equal(lateral_offsets("shift@3", NUM_FRAMES), np.full(NUM_FRAMES, 3.0))
    np.testing.assert_array_equal(lateral_offsets("shift@6", 5), np.full(5, 6.0))
    np.testing.assert_array_equal(lateral_offsets("shift@-1.5", 4), np.full(4, -1.5))
    lane_change = lateral_offsets("lane_change", NUM_FRAMES)
    assert lane_change.dtype == np.float64 and lane_change.shape == (NUM_FRAMES,)
    assert lane_change[0] == 0.0
    assert lane_change[1] == pytest.approx(0.1)
    assert lane_change[39] == pytest.approx(3.9)
    np.testing.assert_allclose(np.diff(lane_change), 0.1)
    # Shorter clips still reach the neighbouring lane by their last frame.
    compact = lateral_offsets("lane_change", 24)
    assert compact[0] == 0.0 and compact[-1] == pytest.approx(3.9)
    np.testing.assert_allclose(np.diff(compact), 3.9 / 23)


@pytest.mark.parametrize(
    "name",
    [
        "",
        "shift",
        "shift@",
        "shift@abc",
        "shift@nan",
        "shift@inf",
        "lanechange",
        "lane_change@2",
        "file:",
        "Original",
        3,
    ],
)
def test_unknown_names_raise_a_clear_value_error(name):
    with pytest.raises(ValueError, match="trajector"):
        parse_trajectory(name)
    with pytest.raises(ValueError):
        lateral_offsets(name, 3)


def test_file_trajectory_has_no_lateral_offsets():
    assert parse_trajectory("file:/tmp/poses.npy").kind == "file"
    with pytest.raises(ValueError, match="file"):
        lateral_offsets("file:/tmp/poses.npy", 3)


@pytest.mark.parametrize("name", ["shift@3", "shift@-2", "lane_change"])
def test_cameras_move_along_the_ego_left_axis_with_orientation_unchanged(name):
    ego = curved_ego()
    cameras = ego @ CAM_TO_EGO
    moved = trajectory_cam_to_world(cameras, ego, name)
    offsets = {
        "shift@3": np.full(NUM_FRAMES, 3.0),
        "shift@-2": np.full(NUM_FRAMES, -2.0),
        "lane_change": 0.1 * np.arange(NUM_FRAMES),  # 40 frames: 0.1 m per frame
    }[name]
    yaw = 0.05 * np.arange(NUM_FRAMES)
    left = np.stack([-np.sin(yaw), np.cos(yaw), np.zeros(NUM_FRAMES)], axis=1)  # ego +y in the world
    np.testing.assert_allclose(moved[:, :3, 3] - cameras[:, :3, 3], offsets[:, None] * left, atol=1e-12)
    np.testing.assert_array_equal(moved[:, :3, :3], cameras[:, :3, :3])
    np.testing.assert_array_equal(moved[:, 3], cameras[:, 3])


def test_left_shift_moves_the_image_content_right():
    """Moving the camera left makes a point ahead move right in the image (and the original is untouched)."""
    ego = curved_ego(3)
    cameras = ego @ CAM_TO_EGO
    K = np.array([[100.0, 0.0, 50.0], [0.0, 100.0, 40.0], [0.0, 0.0, 1.0]])
    point = (ego[1] @ np.array([15.0, 0.0, 1.5, 1.0]))[:3][None]  # straight ahead of frame 1
    shifted = trajectory_cam_to_world(cameras, ego, "shift@3")
    u_original = project_points(point, K, world_to_camera(cameras[1]))[0][0, 0]
    u_shifted = project_points(point, K, world_to_camera(shifted[1]))[0][0, 0]
    assert u_original == pytest.approx(50.0)
    assert u_shifted == pytest.approx(50.0 + 100.0 * 3.0 / (15.0 - 1.0))  # CAM_TO_EGO sits 1 m ahead
    np.testing.assert_array_equal(trajectory_cam_to_world(cameras, ego, "original"), cameras)


def test_pose_files(tmp_path):
    ego = curved_ego(4)
    cameras = ego @ CAM_TO_EGO
    poses = trajectory_cam_to_world(cameras, ego, "lane_change")
    np.save(tmp_path / "poses.npy", poses)
    (tmp_path / "poses.json").write_text(json.dumps(poses.tolist()))
    (tmp_path / "wrapped.json").write_text(json.dumps({"cam_to_world": poses.tolist()}))
    for file in ("poses.npy", "poses.json", "wrapped.json"):
        np.testing.assert_array_equal(trajectory_cam_to_world(cameras, ego, f"file:{tmp_path / file}"), poses)

    np.save(tmp_path / "short.npy", poses[:3])
    with pytest.raises(ValueError, match=r"short.npy.*\(4, 4, 4\)"):
        trajectory_cam_to_world(cameras, ego, f"file:{tmp_path / 'short.npy'}")
    skewed = poses.copy()
    skewed[2, :3, :3] *= 2.0
    np.save(tmp_path / "skewed.npy", skewed)
    with pytest.raises(ValueError, match="pose 2.*orthonormal"):
        trajectory_cam_to_world(cameras, ego, f"file:{tmp_path / 'skewed.npy'}")
    broken = poses.copy()
    broken[1, 0, 3] = np.nan
    np.save(tmp_path / "nan.npy", broken)
    with pytest.raises(ValueError, match="non-finite"):
        trajectory_cam_to_world(cameras, ego, f"file:{tmp_path / 'nan.npy'}")
    (tmp_path / "poses.txt").write_text("1 2 3")
    with pytest.raises(ValueError, match=r"\.npy or \.json"):
        trajectory_cam_to_world(cameras, ego, f"file:{tmp_path / 'poses.txt'}")
    with pytest.raises(ValueError, match="does not exist"):
        trajectory_cam_to_world(cameras, ego, f"file:{tmp_path / 'missing.npy'}")


def test_scene_trajectory_uses_its_ego_poses(tmp_path):
    data = make_scene_data()
    write_scene(tmp_path / "scene", data)
    scene = load_scene(tmp_path / "scene")
    np.testing.assert_array_equal(scene.trajectory("original"), scene.cam_to_world)
    lane_change = scene.trajectory("lane_change")
    expected = data.ego_to_world @ data.cam_to_ego
    expected[:, :3, 3] += 3.9 * np.arange(3)[:, None] / 2 * data.ego_to_world[:, :3, 1]
    np.testing.assert_allclose(lane_change, expected, atol=1e-12)
    with pytest.raises(ValueError, match="unknown trajectory"):
        scene.trajectory("shift@x")


class TestDamagedPoseFiles:
    """A pose file that is not a whole .npy array is named with what is wrong with it."""

    def test_random_bytes_are_not_an_npy_file(self, tmp_path):
        ego = curved_ego(4)
        (tmp_path / "noise.npy").write_bytes(np.random.default_rng(0).bytes(3000))
        with pytest.raises(ValueError, match=r"noise.npy: not a .npy file"):
            trajectory_cam_to_world(ego @ CAM_TO_EGO, ego, f"file:{tmp_path / 'noise.npy'}")

    def test_a_file_cut_short(self, tmp_path):
        ego = curved_ego(4)
        np.save(tmp_path / "poses.npy", ego @ CAM_TO_EGO)
        data = (tmp_path / "poses.npy").read_bytes()
        (tmp_path / "cut.npy").write_bytes(data[: len(data) - 40])
        with pytest.raises(ValueError, match=r"cut.npy: cannot be read \(Failed to read all data"):
            trajectory_cam_to_world(ego @ CAM_TO_EGO, ego, f"file:{tmp_path / 'cut.npy'}")
