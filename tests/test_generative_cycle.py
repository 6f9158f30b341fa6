"""Cycle pairs (make-cycle-pairs) on a real, tiny reconstruction run: what run B trains on, what the
pairs file holds, resumption, the command line and its errors."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import recondreamer.recon.trainer as trainer
from recondreamer.cli import main
from recondreamer.errors import RecondreamerError
from recondreamer.generative.cycle import CYCLE_SOURCE, cycle_snapshot_step, make_cycle_pairs
from recondreamer.generative.data import load_pairs_file, pair_kind, scene_structure
from recondreamer.generative.pairs import make_pairs_for_run
from recondreamer.recon import load_model, render_trajectory
from recondreamer.recon.config import make_config
from recondreamer.recon.trainer import train_scene
from recondreamer.scene import load_scene, write_scene
from recondreamer.scene.trajectories import trajectory_cam_to_world
from recondreamer.sources.synthetic import generate_segment

# Small tensors: one torch thread each (tests/conftest.py).
pytestmark = pytest.mark.usefixtures("one_torch_thread")

DRIVE = "shift@3"


def tiny_config(iterations: int):
    config = make_config("street", "quick", iterations=iterations, checkpoint_every=100)
    config.init.max_lidar_points = 300
    config.init.num_far_points = 50
    config.init.max_object_points = 30
    return config


@pytest.fixture(scope="module")
def run_a(tmp_path_factory):
    """Run A: Street Gaussians on the recorded frames of a quick scene, with snapshots for make-pairs."""
    root = tmp_path_factory.mktemp("cycle")
    write_scene(root / "scene", generate_segment(0, preset="quick"))
    scene = load_scene(root / "scene")
    train_scene(scene, dataclasses.replace(tiny_config(6), snapshot_steps=(2, 4)), root / "street")
    return root / "street", scene


@pytest.fixture(scope="module")
def cycle(run_a, tmp_path_factory):
    """make_cycle_pairs along DRIVE, with the training set run B received."""
    run_dir, scene = run_a
    root = tmp_path_factory.mktemp("cycle_b")
    received = []
    original_train_scene = trainer.train_scene

    def recording_train_scene(scene, config, run_dir, training_set=None, **kwargs):
        received.append((config, training_set))
        return original_train_scene(scene, config, run_dir, training_set=training_set, **kwargs)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(trainer, "train_scene", recording_train_scene)
        written = make_cycle_pairs(run_dir, scene.path, DRIVE, root / "runs" / DRIVE, root / "pairs", tiny_config(6))
    return written, received, root


class TestRunB:
    def test_trains_on_run_a_renders_of_the_lateral_drive_only(self, run_a, cycle):
        run_dir, scene = run_a
        _, received, _ = cycle
        (config, training_set), = received
        cams = trajectory_cam_to_world(scene.cam_to_world, scene.ego_to_world, DRIVE)
        renders = render_trajectory(load_model(run_dir / "model.pt"), scene, cams)
        assert len(training_set.views) == scene.num_frames
        for t, view in enumerate(training_set.views):
            assert view.source == CYCLE_SOURCE and view.frame == t
            np.testing.assert_array_equal(view.cam_to_world, cams[t])
            np.testing.assert_array_equal(view.image, renders[t])  # never a recorded frame nor a true novel view
            assert view.depth is not None and (view.depth > 0).any()  # the drive's LiDAR, projected into the shifted camera
        assert config.snapshot_steps == (cycle_snapshot_step(6),) == (3,)

    def test_snapshot_is_half_the_iterations(self):
        assert [cycle_snapshot_step(n) for n in (1, 2, 7, 700)] == [1, 1, 3, 350]


class TestPairsFile:
    def test_renders_of_the_recorded_trajectory_against_the_recorded_frames(self, run_a, cycle):
        _, scene = run_a
        written, _, root = cycle
        assert written == root / "pairs" / f"{scene.scene_id}__{DRIVE}.npz"
        content = load_pairs_file(written)
        run_b = root / "runs" / DRIVE
        assert content["stages"].tolist() == [3, 6]
        np.testing.assert_array_equal(content["degraded"][0], render_trajectory(load_model(run_b / "snapshots" / "step_000003.pt"), scene, scene.cam_to_world))
        np.testing.assert_array_equal(content["degraded"][1], render_trajectory(load_model(run_b / "model.pt"), scene, scene.cam_to_world))
        np.testing.assert_array_equal(content["gt"], scene.images())
        np.testing.assert_array_equal(content["structure"], scene_structure(scene, scene.cam_to_world))
        assert str(content["trajectory"]) == "original" and str(content["cycle_from"]) == DRIVE

    def test_reference_views_are_what_run_b_trained_on(self, cycle):
        written, received, _ = cycle
        (_, training_set), = received
        np.testing.assert_array_equal(load_pairs_file(written)["view"], np.stack([view.image for view in training_set.views]))

    def test_pair_kinds(self, run_a, cycle, tmp_path):
        run_dir, scene = run_a
        written, _, _ = cycle
        assert pair_kind(load_pairs_file(written)) == f"cycle:{DRIVE}"
        original, novel = make_pairs_for_run(run_dir, tmp_path, 2, trajectories=("original", DRIVE))
        assert pair_kind(load_pairs_file(original)) == "snapshot"
        assert pair_kind(load_pairs_file(novel)) == f"truth:{DRIVE}"

    def test_a_second_call_resumes_run_b_and_writes_the_same_pairs(self, run_a, cycle):
        run_dir, scene = run_a
        written, _, root = cycle
        first = load_pairs_file(written)
        again = make_cycle_pairs(run_dir, scene.path, DRIVE, root / "runs" / DRIVE, root / "pairs_again", tiny_config(6))
        np.testing.assert_array_equal(load_pairs_file(again)["degraded"], first["degraded"])


class TestErrors:
    def test_the_recorded_trajectory_is_no_cycle(self, run_a, tmp_path):
        run_dir, scene = run_a
        with pytest.raises(RecondreamerError, match="--trajectory original"):
            make_cycle_pairs(run_dir, scene.path, "original", tmp_path / "b", tmp_path / "pairs", tiny_config(4))

    def test_unknown_drive(self, run_a, tmp_path):
        run_dir, scene = run_a
        with pytest.raises(RecondreamerError, match="--trajectory sideways: unknown trajectory"):
            make_cycle_pairs(run_dir, scene.path, "sideways", tmp_path / "b", tmp_path / "pairs", tiny_config(4))

    def test_run_without_final_model(self, run_a, tmp_path):
        _, scene = run_a
        with pytest.raises(RecondreamerError, match="cycle pairs need the run's final model"):
            make_cycle_pairs(tmp_path / "nothing", scene.path, DRIVE, tmp_path / "b", tmp_path / "pairs", tiny_config(4))
        assert not (tmp_path / "pairs").exists() and not (tmp_path / "b").exists()


class TestCommandLine:
    def test_writes_pairs_with_run_a_backbone_and_the_scene_of_its_run_json(self, run_a, tmp_path):
        run_dir, scene = run_a
        assert main(["make-cycle-pairs", "--run", str(run_dir), "--trajectory", "shift@6", "--cycle-run", str(tmp_path / "b"),
                     "--out", str(tmp_path / "pairs"), "--preset", "quick", "--iterations", "2", "--threads", "1"]) == 0
        content = load_pairs_file(tmp_path / "pairs" / f"{scene.scene_id}__b.npz")
        assert content["stages"].tolist() == [1, 2] and str(content["cycle_from"]) == "shift@6"
        assert load_model(tmp_path / "b" / "model.pt").__class__ is load_model(run_dir / "model.pt").__class__

    def test_missing_run_is_a_one_line_error(self, tmp_path, capsys):
        assert main(["make-cycle-pairs", "--run", str(tmp_path / "absent"), "--trajectory", DRIVE, "--cycle-run", str(tmp_path / "b"),
                     "--out", str(tmp_path / "pairs")]) == 1
        assert f"--run {tmp_path / 'absent'}: no final model" in capsys.readouterr().err
