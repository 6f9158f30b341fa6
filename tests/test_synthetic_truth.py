"""True views of a synthetic scene from arbitrary poses (the oracle restorer of the PDUS loop)."""

from __future__ import annotations


import numpy as np
import pytest

from recondreamer.errors import RecondreamerError
from recondreamer.scene import load_scene, write_scene
from recondreamer.scene.trajectories import trajectory_cam_to_world
from recondreamer.sources.synthetic import generate_segment
from recondreamer.sources.synthetic.truth import TrueViewRenderer


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    path = tmp_path_factory.mktemp("truth") / "quick5"
    write_scene(path, generate_segment(5, preset="quick", frames=4))
    return load_scene(path)


@pytest.mark.parametrize("trajectory", ["original", "shift@3", "lane_change"])
def test_true_views_equal_the_views_recorded_in_the_scene(scene, trajectory):
    poses = trajectory_cam_to_world(scene.cam_to_world, scene.ego_to_world, trajectory)
    frames = TrueViewRenderer(scene).render(poses)
    recorded = np.stack([
        scene.image(t) if trajectory == "original" else scene.novel_image(trajectory, t)
        for t in range(scene.num_frames)
    ])
    assert frames.dtype == np.uint8 and frames.shape == recorded.shape
    np.testing.assert_array_equal(frames, recorded)


def test_a_pose_the_scene_never_recorded_gives_a_different_view(scene):
    renderer = TrueViewRenderer(scene)
    at_3 = renderer.render(trajectory_cam_to_world(scene.cam_to_world, scene.ego_to_world, "shift@3"))
    at_1_5 = renderer.render(trajectory_cam_to_world(scene.cam_to_world, scene.ego_to_world, "shift@1.5"))
    assert np.abs(at_3.astype(int) - at_1_5.astype(int)).mean() > 1.0


def test_non_synthetic_scene_and_wrong_poses_are_refused(scene):
    class Recorded:  # a scene from a real dataset: no world to rebuild
        scene_id, metadata = "waymo-seg", {"generator": "recondreamer.sources.waymo"}

    with pytest.raises(RecondreamerError, match="waymo-seg: true views exist only for synthetic scenes"):
        TrueViewRenderer(Recorded())
    stale = generate_segment(5, preset="quick", frames=2)
    stale.metadata["generator_version"] = -1
    with pytest.raises(RecondreamerError, match="generator version -1"):
        TrueViewRenderer(stale)
    with pytest.raises(RecondreamerError, match=r"poses of shape \(2, 4, 4\), expected \(4, 4, 4\)"):
        TrueViewRenderer(scene).render(np.tile(np.eye(4), (2, 1, 1)))
