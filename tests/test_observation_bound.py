"""experiments/observation_bound.py: observed pixels of a novel view and LiDAR points splatted into a camera."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SPEC = importlib.util.spec_from_file_location("observation_bound", REPO / "experiments" / "observation_bound.py")
observation_bound = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(observation_bound)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    from recondreamer.scene import load_scene, write_scene
    from recondreamer.sources.synthetic import generate_segment

    path = tmp_path_factory.mktemp("observation") / "scene"
    write_scene(path, generate_segment(3, "quick", frames=6))
    return load_scene(path)


class RecordedAsNovel:
    """A scene whose 'novel' depth of any trajectory is the recorded depth: the recorded cameras as a novel trajectory."""

    def __init__(self, scene):
        self._scene = scene

    def __getattr__(self, name):
        return getattr(self._scene, name)

    def novel_depth(self, trajectory, frame):
        return self._scene.depth(frame)


def test_a_recorded_frame_observes_all_of_itself_and_less_of_a_later_one(scene):
    recorded = RecordedAsNovel(scene)
    assert observation_bound.observed_pixels(recorded, "original", 2, [2]).all()
    other = observation_bound.observed_pixels(recorded, "original", 5, [0]).mean()
    assert 0.2 < other < 1.0  # the car moved on: some surfaces are new, many were seen


def test_a_lateral_camera_observes_less_the_further_it_moves(scene):
    fractions = [observation_bound.observed_pixels(scene, name, 2, [2]).mean() for name in ("shift@3", "shift@6")]
    assert 0.0 < fractions[1] < fractions[0] < 1.0
    whole_clip = observation_bound.observed_pixels(scene, "shift@6", 2, list(range(scene.num_frames))).mean()
    assert whole_clip >= fractions[1]


def test_coloured_lidar_splatted_into_its_own_camera_gives_the_recorded_colours(scene):
    points, colours = observation_bound.coloured_lidar(scene, 1)
    assert len(points) > 0 and colours.dtype == np.uint8
    image, covered = observation_bound.splat_points(scene, points, colours, scene.cam_to_world[1])
    assert 0.0 < covered.mean() < 1.0
    np.testing.assert_array_equal(image[covered], scene.image(1)[covered])
    assert not image[~covered].any()


def test_points_behind_the_camera_or_outside_the_image_cover_nothing(scene):
    pose = scene.cam_to_world[0]
    behind = pose[:3, 3] - 5.0 * pose[:3, 2]  # 5 m behind the camera along its optical axis
    beside = pose[:3, 3] + 10.0 * pose[:3, 2] + 1000.0 * pose[:3, 0]  # far outside the field of view
    image, covered = observation_bound.splat_points(scene, np.stack([behind, beside]), np.full((2, 3), 200, np.uint8), pose)
    assert not covered.any() and not image.any()
