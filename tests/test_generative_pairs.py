"""make-pairs on a real (tiny, briefly trained) reconstruction run: original and novel trajectories."""

from __future__ import annotations

import numpy as np
import pytest

from recondreamer.errors import RecondreamerError
from recondreamer.recon import load_model, render_trajectory
from recondreamer.recon.config import make_config
from recondreamer.recon.trainer import train_scene
from recondreamer.generative.data import load_pairs_file, scene_structure
from recondreamer.generative.pairs import make_pairs_for_run
from recondreamer.scene import load_scene, write_scene
from recondreamer.scene.trajectories import trajectory_cam_to_world
from recondreamer.sources.synthetic import generate_segment

# Small tensors: one torch thread each (tests/conftest.py).
pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    root = tmp_path_factory.mktemp("pairs")
    write_scene(root / "scene", generate_segment(0, preset="quick"))
    scene = load_scene(root / "scene")
    config = make_config("street", "quick", iterations=6, snapshot_steps=(2, 4), checkpoint_every=100)
    config.init.max_lidar_points = 300
    config.init.num_far_points = 50
    config.init.max_object_points = 30
    train_scene(scene, config, root / "street")
    return root / "street", scene


def test_pairs_of_original_and_novel_trajectories(run, tmp_path):
    run_dir, scene = run
    novel = scene.novel_trajectories[0]
    written = make_pairs_for_run(run_dir, tmp_path, num_stages=4, trajectories=("original", novel))
    assert [p.name for p in written] == [f"{scene.scene_id}__street.npz", f"{scene.scene_id}__street__{novel}.npz"]
    original, shifted = (load_pairs_file(p) for p in written)

    # Original trajectory: one clip per snapshot, against the recorded frames.
    assert original["stages"].tolist() == [2, 4] and original["degraded"].shape[0] == 2
    assert np.array_equal(original["gt"], np.stack([scene.image(t) for t in range(scene.num_frames)]))
    assert str(original["trajectory"]) == "original"
    assert "view" not in original  # the recorded frames are its truth: no reference view

    # Novel trajectory: the snapshots and the final model, rendered in the shifted cameras,
    # against the true novel views, with structure maps drawn in those cameras.
    cams = trajectory_cam_to_world(scene.cam_to_world, scene.ego_to_world, novel)
    assert shifted["stages"].tolist() == [2, 4, 6]
    assert np.array_equal(shifted["degraded"][-1], render_trajectory(load_model(run_dir / "model.pt"), scene, cams))
    assert np.array_equal(shifted["degraded"][0], render_trajectory(load_model(run_dir / "snapshots" / "step_000002.pt"), scene, cams))
    assert np.array_equal(shifted["gt"], np.stack([scene.novel_image(novel, t) for t in range(scene.num_frames)]))
    assert np.array_equal(shifted["structure"], scene_structure(scene, cams))
    assert not np.array_equal(shifted["structure"], original["structure"])
    assert str(shifted["trajectory"]) == novel and str(shifted["scene_id"]) == scene.scene_id
    # Reference views (view-conditioned restorers): the recorded frames the reconstruction trained on.
    assert np.array_equal(shifted["view"], original["gt"])


def test_novel_trajectory_without_true_views_is_refused(run, tmp_path):
    run_dir, _ = run
    with pytest.raises(RecondreamerError, match="no true novel views"):
        make_pairs_for_run(run_dir, tmp_path, num_stages=2, trajectories=("shift@9.5",))


class TestDamagedPairsFile:
    def test_a_cut_short_npz_is_named(self, tmp_path):
        whole = tmp_path / "whole.npz"
        np.savez_compressed(whole, gt=np.zeros((3, 8, 8, 3), np.uint8), degraded=np.ones((1, 3, 8, 8, 3), np.uint8))
        data = whole.read_bytes()
        (tmp_path / "cut.npz").write_bytes(data[: len(data) // 2])  # a copy or download that stopped
        with pytest.raises(RecondreamerError, match=r"cut.npz: not a readable restoration-pairs file"):
            load_pairs_file(tmp_path / "cut.npz")
