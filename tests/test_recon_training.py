"""End-to-end tests of the reconstruction trainer on a tiny synthetic scene (quick preset)."""

from __future__ import annotations

import copy
import json
import shutil

import numpy as np
import pytest
import torch
from PIL import Image

from recondreamer.cli import main as cli_main
from recondreamer.errors import CheckpointError
from recondreamer.recon import (
    TrainingSet,
    load_model,
    make_config,
    render_trajectory,
    train_scene,
)
from recondreamer.recon.checkpoint import snapshot_path
from recondreamer.recon.data import TrainingView
from recondreamer.recon.models import MODEL_CLASSES
from recondreamer.recon.trainer import Trainer
from recondreamer.scene import load_scene, write_scene
from recondreamer.sources.synthetic import generate_segment

# Small tensors: one torch thread each (tests/conftest.py).
pytestmark = pytest.mark.usefixtures("one_torch_thread")

HELD_OUT = 6  # frame never shown to the street model
ITERATIONS = 80


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    path = tmp_path_factory.mktemp("scene") / "quick0"
    write_scene(path, generate_segment(0, preset="quick"))
    return load_scene(path)


def small_config(model: str, iterations: int = ITERATIONS, **overrides):
    """Quick preset, shrunk further so every backbone trains in a few seconds."""
    config = make_config(model, "quick", iterations=iterations, **overrides)
    config.init.max_lidar_points = 500
    config.init.num_far_points = 100
    config.init.max_object_points = 60
    config.densify.max_gaussians = 1500
    return config


def training_psnr(model, scene, frames) -> float:
    renders = (
        render_trajectory(model, scene, scene.cam_to_world).astype(np.float64) / 255.0
    )
    truth = np.stack([scene.image(t) for t in frames]).astype(np.float64) / 255.0
    return float(10 * np.log10(1.0 / np.mean((renders[frames] - truth) ** 2)))


def initial_model(scene, config):
    torch.manual_seed(config.seed)
    return MODEL_CLASSES[config.model].from_scene(
        scene, config, np.random.default_rng(config.seed)
    )


@pytest.fixture(scope="module")
def street_run(scene, tmp_path_factory):
    """Street Gaussians trained on every frame but HELD_OUT, with snapshots and checkpoints."""
    run = tmp_path_factory.mktemp("runs") / "street"
    frames = [t for t in range(scene.num_frames) if t != HELD_OUT]
    config = small_config("street", snapshot_steps=(40, 80), checkpoint_every=50)
    model = train_scene(
        scene, config, run, training_set=TrainingSet.from_scene(scene, frames)
    )
    return run, model, config, frames


def test_street_learns_training_views(scene, street_run):
    _, model, config, frames = street_run
    before = training_psnr(initial_model(scene, config), scene, frames)
    after = training_psnr(model, scene, frames)
    assert after > before + 3.0, (before, after)


@pytest.mark.parametrize("backbone", ["pvg", "deformable", "s3"])
def test_backbone_learns_training_views(scene, backbone):
    config = small_config(backbone)
    frames = list(range(scene.num_frames))
    before = training_psnr(initial_model(scene, config), scene, frames)
    model = train_scene(scene, config, None)
    after = training_psnr(model, scene, frames)
    assert after > before + 3.0, (backbone, before, after)
    # Dynamics are learned without boxes: some Gaussians move between two times.
    with torch.no_grad():
        start, end = model.gaussians_at(0.3), model.gaussians_at(0.75)
    assert (end["means"] - start["means"]).norm(dim=1).max() > 0.005


def vehicle_overlap(
    model, scene, frame: int, track: str, pose_frame: int | None = None
) -> tuple[float, float]:
    """(recall, precision) of the vehicle's rendered silhouette against its true instance mask."""
    solo = copy.deepcopy(model)
    k = solo.track_ids.index(track)
    with torch.no_grad():
        others = solo.gaussians.owner != k
        solo.gaussians.params["logit_opacities"][others] = -30.0
        if (
            pose_frame is not None
        ):  # control: freeze the vehicle at another frame's box pose
            solo.track_translations[k, :] = solo.track_translations[k, pose_frame]
            solo.track_quats[k, :] = solo.track_quats[k, pose_frame]
        out = solo.render(
            scene.cam_to_world[frame],
            float(scene.timestamps[frame]),
            scene.K,
            scene.width,
            scene.height,
        )
    rendered = out["alpha"].numpy() > 0.5
    truth = scene.instances(frame) == 1 + scene.track_ids.index(track)
    overlap = (rendered & truth).sum()
    return overlap / max(truth.sum(), 1), overlap / max(rendered.sum(), 1)


def largest_moving_vehicle(scene, model, frame: int) -> str:
    """The modelled vehicle moving faster than 5 m/s with the largest visible area at ``frame``."""
    speeds = {box.track_id: box.speed for box in scene.boxes(frame)}
    areas = np.bincount(
        scene.instances(frame).ravel(), minlength=len(scene.track_ids) + 1
    )
    moving = [track for track in model.track_ids if speeds.get(track, 0.0) > 5.0]
    return max(moving, key=lambda track: areas[1 + scene.track_ids.index(track)])


def test_street_places_moving_vehicle_at_held_out_frame(scene, street_run):
    model = street_run[1]
    track = largest_moving_vehicle(scene, model, HELD_OUT)
    assert (scene.instances(HELD_OUT) == 1 + scene.track_ids.index(track)).sum() > 100
    recall, precision = vehicle_overlap(model, scene, HELD_OUT, track)
    assert recall > 0.7 and precision > 0.7, (track, recall, precision)
    # The same Gaussians left at the first frame's box pose miss the vehicle: the test can fail.
    recall0, precision0 = vehicle_overlap(model, scene, HELD_OUT, track, pose_frame=0)
    assert recall0 < 0.5 * recall or precision0 < 0.5 * precision, (recall0, precision0)


def test_street_interpolates_box_pose_between_frames(scene, street_run):
    model = street_run[1]
    k = model.track_ids.index(largest_moving_vehicle(scene, model, HELD_OUT))
    frame_times = model.frame_times
    mid = float(frame_times[2] + frame_times[3]) / 2
    _, translations, present = model.track_poses_at(mid)
    expected = (model.track_translations[k, 2] + model.track_translations[k, 3]) / 2
    assert bool(present[k]) and torch.allclose(translations[k], expected, atol=1e-5)


def test_checkpoint_round_trip_renders_identically(scene, street_run):
    run, model = street_run[:2]
    for path in (run, run / "model.pt"):
        loaded = load_model(path)
        assert loaded.model_type == "street" and len(loaded.gaussians) == len(
            model.gaussians
        )
        with torch.no_grad():
            a = model.render(
                scene.cam_to_world[3],
                float(scene.timestamps[3]),
                scene.K,
                scene.width,
                scene.height,
            )
            b = loaded.render(
                scene.cam_to_world[3],
                float(scene.timestamps[3]),
                scene.K,
                scene.width,
                scene.height,
            )
        assert torch.equal(a["rgb"], b["rgb"]) and torch.equal(a["depth"], b["depth"])
    snapshots = [load_model(snapshot_path(run, step)) for step in (40, 80)]
    assert all(s.model_type == "street" for s in snapshots)
    assert (run / "train.log").read_text().count("psnr") >= 2
    (run / "broken.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="broken.pt"):
        load_model(run / "broken.pt")


def test_render_command_for_every_trajectory_kind(scene, street_run, tmp_path):
    run = street_run[0]
    poses_file = tmp_path / "poses.npy"
    np.save(poses_file, np.asarray(scene.cam_to_world))
    outputs = {}
    for name in ("original", "shift@3", "lane_change", f"file:{poses_file}"):
        out = tmp_path / name.replace(":", "_").replace("/", "_").replace("@", "_")
        assert (
            cli_main(
                ["render", "--run", str(run), "--trajectory", name, "--out", str(out)]
            )
            == 0
        )
        assert sorted(p.name for p in out.glob("*.png")) == [
            f"{t:03d}.png" for t in range(scene.num_frames)
        ]
        assert np.load(out / "000_depth.npy").shape == (scene.height, scene.width)
        outputs[name] = np.stack(
            [
                np.asarray(Image.open(out / f"{t:03d}.png"))
                for t in range(scene.num_frames)
            ]
        )
    assert np.array_equal(outputs["original"], outputs[f"file:{poses_file}"])
    assert not np.array_equal(outputs["original"], outputs["shift@3"])
    # lane change starts on the original trajectory and drifts away from it.
    assert np.array_equal(outputs["original"][0], outputs["lane_change"][0])
    assert not np.array_equal(outputs["original"][-1], outputs["lane_change"][-1])
    assert (
        cli_main(
            [
                "render",
                "--run",
                str(run),
                "--trajectory",
                "sideways",
                "--out",
                str(tmp_path / "x"),
            ]
        )
        == 1
    )


def train_with_threads(scene, config, run_dir, threads: int):
    """Train with ``threads`` torch threads; the final model's tensors and the training-view renders."""
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        model = train_scene(scene, config, run_dir)
        renders = render_trajectory(model, scene, scene.cam_to_world)
    finally:
        torch.set_num_threads(previous)
    return torch.load(run_dir / "model.pt", weights_only=True)["model_state"], renders


def assert_same_runs(first, second) -> None:
    (state, renders), (other_state, other_renders) = first, second
    assert other_state.keys() == state.keys()
    for name, tensor in state.items():
        assert torch.equal(other_state[name], tensor), name
    np.testing.assert_array_equal(other_renders, renders)


def test_street_gives_the_same_model_at_any_thread_count(scene, tmp_path):
    # Densification at steps 50 and 100 would turn any drift of the gradients into other Gaussians.
    config = small_config("street", iterations=150)
    runs = [train_with_threads(scene, config, tmp_path / f"run{i}", threads) for i, threads in enumerate((2, 2, 1))]
    assert_same_runs(runs[0], runs[1])
    assert_same_runs(runs[0], runs[2])
    notes = json.loads((tmp_path / "run0" / "run.json").read_text())["reproducibility"]
    assert notes["threads"] == 2 and notes["repeats"].endswith("and at any other thread count")


def test_deformable_repeats_at_the_same_thread_count(scene, tmp_path):
    # The deformation MLP's weight gradients are MKL matrix products summed over the Gaussians,
    # split by thread count: the same count repeats, and run.json says that other counts may not.
    config = small_config("deformable", iterations=100)
    runs = [train_with_threads(scene, config, tmp_path / f"run{i}", 2) for i in range(2)]
    assert_same_runs(runs[0], runs[1])
    notes = json.loads((tmp_path / "run0" / "run.json").read_text())["reproducibility"]
    assert "at 2 thread(s)" in notes["repeats"] and "MKL" in notes["repeats"]


class Interrupt(Exception):
    pass


def test_resume_after_interruption_matches_uninterrupted_run(scene, tmp_path):
    config = small_config("pvg", iterations=30, checkpoint_every=10)
    config.densify.start, config.densify.every = 5, 5
    reference = train_scene(scene, config, tmp_path / "a")

    def kill_at_18(trainer):
        if trainer.step == 18:
            raise Interrupt

    with pytest.raises(Interrupt):
        train_scene(scene, config, tmp_path / "b", callbacks=[kill_at_18])
    assert torch.load(tmp_path / "b" / "checkpoint.pt", weights_only=True)["step"] == 10
    resumed = train_scene(scene, config, tmp_path / "b")
    assert len(resumed.gaussians) == len(reference.gaussians)
    for name, param in reference.gaussians.params.items():
        assert torch.equal(resumed.gaussians.params[name], param), name  # bit-identical
    # A checkpoint of another run is refused, not overwritten.
    with pytest.raises(CheckpointError, match="different run"):
        train_scene(scene, small_config("s3", iterations=30), tmp_path / "b")


def test_depth_free_views_never_get_depth_loss(scene):
    config = small_config("pvg", iterations=3)
    frames = [0, 4, 8]

    def train(depth_weight: float, with_depth: bool):
        data = TrainingSet.from_scene(scene, frames)
        if not with_depth:
            data = TrainingSet(
                data.K,
                data.width,
                data.height,
                [
                    TrainingView(
                        v.cam_to_world,
                        v.timestamp,
                        v.image,
                        None,
                        v.sky_mask,
                        "novel",
                        1.0,
                    )
                    for v in data
                ],
            )
        cfg = copy.deepcopy(config)
        cfg.loss.depth = depth_weight
        trainer = Trainer(initial_model(scene, cfg), data, cfg)
        for _ in range(3):
            trainer.train_step()
        return trainer.model.gaussians.params["means"].detach()

    assert torch.equal(train(0.05, with_depth=False), train(100.0, with_depth=False))
    assert not torch.allclose(
        train(0.05, with_depth=True), train(100.0, with_depth=True)
    )


def test_train_command_rejects_invalid_scene(scene, tmp_path, capsys):
    broken = tmp_path / "broken"
    shutil.copytree(scene.path, broken)
    (broken / "boxes.json").unlink()
    code = cli_main(
        [
            "train-recon",
            "--scene",
            str(broken),
            "--model",
            "street",
            "--out",
            str(tmp_path / "run"),
            "--preset",
            "quick",
        ]
    )
    assert code == 1
    assert "boxes.json" in capsys.readouterr().err
    assert not (tmp_path / "run" / "checkpoint.pt").exists()


def test_train_command_writes_run_directory(scene, tmp_path):
    run = tmp_path / "run"
    args = [
        "train-recon",
        "--scene",
        str(scene.path),
        "--model",
        "deformable",
        "--out",
        str(run),
    ]
    previous = torch.are_deterministic_algorithms_enabled(), torch.is_deterministic_algorithms_warn_only_enabled()
    try:
        code = cli_main([*args, "--preset", "quick", "--iterations", "5", "--threads", "1", "--deterministic"])
    finally:  # --deterministic switches torch's mode for the process
        torch.use_deterministic_algorithms(previous[0], warn_only=previous[1])
    assert code == 0
    assert {p.name for p in run.iterdir()} >= {
        "checkpoint.pt",
        "model.pt",
        "run.json",
        "train.log",
    }
    info = json.loads((run / "run.json").read_text())
    assert (
        info["status"] == "done"
        and info["step"] == 5
        and info["model_type"] == "deformable"
    )
    assert info["reproducibility"]["deterministic_algorithms"] and info["reproducibility"]["threads"] == 1
    assert load_model(run).model_type == "deformable"
