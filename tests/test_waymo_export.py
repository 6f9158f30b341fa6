"""A synthetic scene written as a Waymo segment converts back to itself.

``export-waymo`` writes the FRONT camera, calibration, poses, laser labels, a TOP range image and
the map; ``convert-waymo`` reads them back with the world frame at the first frame's vehicle
frame. Everything but the JPEG-coded images must come back to rounding (the synthetic LiDAR lies
on the range image's grid).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from recondreamer.cli import main
from recondreamer.scene import load_scene
from recondreamer.sources.waymo.tfrecord import iter_records

POSE_TOLERANCE = 1e-6  # metres / unit rotation entries: float64 round trip through the global frame
LIDAR_TOLERANCE = 1e-4  # metres: float32 ranges of points up to ~80 m away
IMAGE_PSNR_MIN = 35.0  # dB: JPEG quality 95, 4:4:4


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """(synthetic scene, its Waymo file, the converted scene)."""
    folder = tmp_path_factory.mktemp("export")
    original = folder / "synthetic"
    assert main(["synth", "--seed", "7", "--preset", "quick", "--frames", "4", "--no-novel", "--out", str(original)]) == 0
    segment = folder / "segment.tfrecord"
    assert main(["export-waymo", str(original), "--out", str(segment)]) == 0
    converted = folder / "converted"
    assert main(["convert-waymo", str(segment), "--out", str(converted)]) == 0
    return load_scene(original), segment, load_scene(converted)


def to_first_vehicle_frame(scene):
    """The synthetic scene's world-to-(first frame's vehicle frame) transform (4,4)."""
    return np.linalg.inv(scene.ego_to_world[0])


class TestRoundTrip:
    def test_one_record_per_frame(self, scenes):
        original, segment, _ = scenes
        assert sum(1 for _ in iter_records(segment)) == original.num_frames

    def test_camera_and_poses(self, scenes):
        original, _, converted = scenes
        assert (converted.width, converted.height, converted.source) == (original.width, original.height, "waymo")
        np.testing.assert_allclose(converted.K, original.K, atol=1e-9)
        np.testing.assert_allclose(converted.distortion, original.distortion, atol=1e-12)
        np.testing.assert_allclose(converted.cam_to_ego, original.cam_to_ego, atol=1e-9)
        np.testing.assert_allclose(converted.timestamps, original.timestamps, atol=1e-6)
        expected = to_first_vehicle_frame(original) @ original.ego_to_world
        np.testing.assert_allclose(converted.ego_to_world, expected, atol=POSE_TOLERANCE)

    def test_boxes(self, scenes):
        original, _, converted = scenes
        world = to_first_vehicle_frame(original)
        assert converted.track_ids == original.track_ids
        for t in range(original.num_frames):
            before = {box.track_id: box for box in original.boxes(t)}
            after = {box.track_id: box for box in converted.boxes(t)}
            assert after.keys() == before.keys()
            for track, box in before.items():
                assert (after[track].label, after[track].num_points) == (box.label, box.num_points)
                np.testing.assert_allclose(after[track].size, box.size, atol=1e-6)
                np.testing.assert_allclose(after[track].obj_to_world, world @ box.obj_to_world, atol=POSE_TOLERANCE)
                assert after[track].speed == pytest.approx(box.speed, abs=1e-6)

    def test_lidar_point_for_point(self, scenes):
        original, _, converted = scenes
        world = to_first_vehicle_frame(original)
        for t in range(original.num_frames):
            expected = original.lidar(t).astype(np.float64) @ world[:3, :3].T + world[:3, 3]
            points = converted.lidar(t)
            assert len(points) == len(expected)
            distance, _ = cKDTree(points).query(expected)
            assert distance.max() < LIDAR_TOLERANCE

    def test_map(self, scenes):
        original, _, converted = scenes
        world = to_first_vehicle_frame(original)
        assert [p.kind for p in converted.map_polylines] == [p.kind for p in original.map_polylines]
        for before, after in zip(original.map_polylines, converted.map_polylines, strict=True):
            np.testing.assert_allclose(after.points, before.points @ world[:3, :3].T + world[:3, 3], atol=POSE_TOLERANCE)

    def test_images_survive_jpeg(self, scenes):
        original, _, converted = scenes
        for t in range(original.num_frames):
            error = np.mean((original.image(t).astype(np.float64) - converted.image(t).astype(np.float64)) ** 2)
            assert 10 * np.log10(255.0**2 / error) > IMAGE_PSNR_MIN


class TestBadInput:
    def test_a_scene_that_is_not_synthetic_is_refused(self, scenes, tmp_path, capsys):
        _, segment, _ = scenes
        converted = tmp_path / "converted"
        assert main(["convert-waymo", str(segment), "--out", str(converted)]) == 0
        assert main(["export-waymo", str(converted), "--out", str(tmp_path / "again.tfrecord")]) != 0
        assert "not a synthetic scene" in capsys.readouterr().err
        assert not (tmp_path / "again.tfrecord").exists()

    def test_out_must_name_a_tfrecord_file(self, scenes, tmp_path, capsys):
        original, _, _ = scenes
        assert main(["export-waymo", str(original.path), "--out", str(tmp_path / "segment.bin")]) != 0
        assert "ends in .tfrecord" in capsys.readouterr().err
