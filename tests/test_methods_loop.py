"""ReconDreamer's PDUS loop and the DriveDreamer4D baseline end to end on a tiny scene.

The restorer and world model are tiny randomly initialised dd2 models built with the restorer
package's API: these tests check the loop's mechanics (schedule, files, losses, resume), not
restoration quality.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch

from recondreamer.cli import main as cli_main
from recondreamer.errors import RecondreamerError
from recondreamer.methods.dd4d import (
    dd4d_training_set,
    generate_videos,
    load_generated_videos,
    train_dd4d,
)
from recondreamer.methods.loop import (
    PDUS_JSON,
    ProgressiveDataUpdate,
    train_recondreamer,
)
from recondreamer.methods.pdus import PdusSchedule
from recondreamer.recon import load_model, make_config
from recondreamer.recon import trainer as trainer_module
from recondreamer.generative.autoencoder import Autoencoder
from recondreamer.generative.checkpoint import save_checkpoint
from recondreamer.generative.config import (
    AutoencoderConfig,
    DiffusionConfig,
    RestoreConfig,
    TrainConfig,
    UNetConfig,
)
from recondreamer.generative.diffusion import NoiseSchedule
from recondreamer.generative.models import (
    GenerativeModel,
    autoencoder_payload,
    model_config_dict,
)
from recondreamer.generative.unet import LatentUNet
from recondreamer.scene import load_scene, write_scene
from recondreamer.scene.structure import STRUCTURE_CHANNELS
from recondreamer.sources.synthetic import generate_segment
from recondreamer.sources.synthetic.truth import TrueViewRenderer

# Small tensors: one torch thread each (tests/conftest.py).
pytestmark = pytest.mark.usefixtures("one_torch_thread")

ITERATIONS, EVERY = 24, 8  # updates before steps 8 and 16


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    path = tmp_path_factory.mktemp("scene") / "quick3"
    write_scene(path, generate_segment(3, preset="quick", frames=6))
    return load_scene(path)


def tiny_generative(kind: str, height: int, width: int) -> GenerativeModel:
    """A tiny dd2 world model / dd2_mask restorer with the scene's structure channels."""
    torch.manual_seed(0)
    arch = "dd2_mask" if kind == "restorer" else "dd2"
    unet = LatentUNet(UNetConfig(
        arch=arch, channels=(8, 8), attention_levels=(False, False), temporal_levels=(True, True), num_heads=2,
        time_embed_dim=8, structure_channels=len(STRUCTURE_CHANNELS), structure_hidden=4,
        degraded_condition=kind == "restorer",
    ))
    diffusion = DiffusionConfig(sample_steps=2)
    return GenerativeModel(
        kind=kind, arch=arch, unet=unet.eval(), autoencoder=Autoencoder(AutoencoderConfig(hidden_channels=(8, 8, 8))).eval(),
        schedule=NoiseSchedule(diffusion), unet_config=unet.config, diffusion_config=diffusion,
        train_config=TrainConfig(window=4, crop=(0, 0), batch_size=1), structure_channels=tuple(STRUCTURE_CHANNELS),
        frame_size=(height, width), restore_config=RestoreConfig(window=4, overlap=1, sample_steps=2, seed=0),
    )


def small_config(iterations: int = ITERATIONS, checkpoint_every: int = 4):
    config = make_config("street", "quick", iterations=iterations, backend="cpu", checkpoint_every=checkpoint_every,
                         log_every=4)
    config.snapshot_steps = ()
    config.init.max_lidar_points = 300
    config.init.num_far_points = 50
    config.init.max_object_points = 40
    config.densify.max_gaussians = 800
    return config


class Killed(Exception):
    pass


def kill_at(step: int):
    def callback(trainer):
        if trainer.step == step:
            raise Killed(step)
    return callback


def record_views(log: list):
    """Wraps the trainer's loss to record, per step, the sampled view's source and whether depth was passed."""
    original = trainer_module.view_loss

    def view_loss(render, image, depth, sky_mask, config):
        log.append(depth is not None)
        return original(render, image, depth, sky_mask, config)
    return original, view_loss


def test_two_updates_write_restored_frames_a_checkpoint_and_no_depth_on_novel_views(scene, tmp_path, monkeypatch):
    run = tmp_path / "run"
    restorer = tiny_generative("restorer", scene.height, scene.width)
    schedule = PdusSchedule(stride=1.5, update_every=EVERY, iterations=ITERATIONS)
    sampled: list = []
    original_sample = trainer_module.TrainingSet.sample

    def spy_sample(self, rng):
        view = original_sample(self, rng)
        sampled.append(view)
        return view

    depth_passed: list[bool] = []
    _, spy_loss = record_views(depth_passed)
    monkeypatch.setattr(trainer_module.TrainingSet, "sample", spy_sample)
    monkeypatch.setattr(trainer_module, "view_loss", spy_loss)
    train_recondreamer(scene, small_config(), run, restorer, schedule)

    # Files: the model as train-recon writes it, two update folders the report reads.
    assert (run / "model.pt").is_file() and (run / "checkpoint.pt").is_file()
    load_model(run)
    names = sorted(p.name for p in (run / "updates").iterdir())
    assert names == ["update_01", "update_02"]
    for k, name in enumerate(names, start=1):
        info = json.loads((run / "updates" / name / "update.json").read_text())
        assert info["offset_m"] == 1.5 * k and info["step"] == EVERY * k
        rendered = sorted(p.name for p in (run / "updates" / name / "rendered").glob("*.png"))
        assert rendered == sorted(p.name for p in (run / "updates" / name / "restored").glob("*.png")) == ["000.png", "002.png", "005.png"]
    state = json.loads((run / PDUS_JSON).read_text())
    assert state["k"] == 2 and np.allclose(state["video_weights"], [1 / 3, 2 / 3])
    log = (run / "train.log").read_text()
    assert "pdus: update 1 at step 8" in log and "pdus: update 2 at step 16" in log

    # Before step 8 only original views; novel views never carry depth; the loss saw no depth for them.
    assert all(v.source == "original" for v in sampled[:EVERY])
    novel = [v for v in sampled if v.source != "original"]
    assert novel and {v.source for v in novel} <= {"pdus1@1.5m", "pdus2@3m"}
    assert all(v.depth is None and v.sky_mask is None for v in novel)
    assert depth_passed == [v.depth is not None for v in sampled]
    # Novel views are posed on the shifted trajectory: 1.5 m to the ego's left.
    view = next(v for v in novel if v.source == "pdus1@1.5m")
    left = scene.ego_to_world[view.frame][:3, 1]
    assert np.allclose(view.cam_to_world[:3, 3] - scene.cam_to_world[view.frame][:3, 3], 1.5 * left)


def test_resume_after_a_kill_between_updates_gives_the_same_state(scene, tmp_path):
    restorer = tiny_generative("restorer", scene.height, scene.width)
    schedule = PdusSchedule(stride=3.0, update_every=EVERY, iterations=ITERATIONS)
    config = small_config(checkpoint_every=5)  # checkpoints at 5, 10, 15, 20; updates before 8 and 16
    whole = tmp_path / "whole"
    train_recondreamer(scene, config, whole, restorer, schedule)

    run = tmp_path / "killed"
    # Killed between update 1 and update 2: resumes from step 10 and reloads update 1.
    with pytest.raises(Killed):
        train_recondreamer(scene, config, run, restorer, schedule, extra_callbacks=[kill_at(14)])
    assert sorted(p.name for p in (run / "updates").iterdir()) == ["update_01"]
    # Killed after update 2 (step 16) was written but before the next checkpoint (20): resumes
    # from step 15, before the update, and must reuse the folder rather than lose or redo it.
    with pytest.raises(Killed):
        train_recondreamer(scene, config, run, restorer, schedule, extra_callbacks=[kill_at(17)])
    before = (run / "updates" / "update_02" / "frames.npz").stat().st_mtime_ns
    train_recondreamer(scene, config, run, restorer, schedule)
    assert (run / "updates" / "update_02" / "frames.npz").stat().st_mtime_ns == before  # reused, not redone

    for name in ("update_01", "update_02"):
        a, b = (np.load(r / "updates" / name / "frames.npz") for r in (whole, run))
        assert np.array_equal(a["supervised"], b["supervised"])
    a, b = (json.loads((r / PDUS_JSON).read_text()) for r in (whole, run))
    assert a["updates"] == b["updates"] and a["k"] == b["k"] == 2
    model_a, model_b = load_model(whole), load_model(run)
    for (name, x), (_, y) in zip(model_a.state_dict().items(), model_b.state_dict().items()):
        assert torch.allclose(x, y, atol=1e-5), name

    # Another schedule in the same run directory is refused, not mixed in.
    with pytest.raises(RecondreamerError, match="another PDUS set-up"):
        ProgressiveDataUpdate(scene, restorer, PdusSchedule(stride=1.5, update_every=EVERY, iterations=ITERATIONS), run)


def test_dd4d_generates_once_and_trains_half_on_generated_data(scene, tmp_path):
    world = tiny_generative("world_model", scene.height, scene.width)
    run = tmp_path / "dd4d"
    videos = generate_videos(scene, world, run, ("shift@3", "lane_change"))
    assert [v.source for v in videos] == ["dd4d:shift@3", "dd4d:lane_change"]
    assert json.loads((run / "generated" / "shift@3" / "update.json").read_text())["offset_m"] == 3.0
    training_set = dd4d_training_set(scene, videos)
    p = training_set.probabilities()
    is_original = np.array([v.source == "original" for v in training_set])
    assert p[is_original].sum() == pytest.approx(0.5)
    assert all(v.depth is None for v in training_set if v.source != "original")
    # Reused on resume: the world model is not asked again.
    again = generate_videos(scene, None, run, ("shift@3", "lane_change"))
    assert all(np.array_equal(a.frames, b.frames) for a, b in zip(videos, again))
    train_dd4d(scene, small_config(8), run, None, ("shift@3", "lane_change"))
    assert (run / "model.pt").is_file()


def test_cli_commands_run_from_checkpoint_files(scene, tmp_path):
    for kind in ("restorer", "world_model"):
        model = tiny_generative(kind, scene.height, scene.width)
        save_checkpoint(tmp_path / f"{kind}.pt", kind, model.arch, model_config_dict(model), model.unet.state_dict(),
                        autoencoder=autoencoder_payload(model.autoencoder))
    common = ["--scene", str(scene.path), "--model", "street", "--preset", "quick", "--iterations", "6",
              "--backend", "cpu", "--threads", "1"]
    assert cli_main(["train-recondreamer", *common, "--restorer", str(tmp_path / "restorer.pt"), "--stride", "6",
                     "--update-every", "3", "--out", str(tmp_path / "rd")]) == 0
    info = json.loads((tmp_path / "rd" / "updates" / "update_01" / "update.json").read_text())
    assert info["offset_m"] == 6.0 and (tmp_path / "rd" / "model.pt").is_file()
    assert cli_main(["train-dd4d", *common, "--world-model", str(tmp_path / "world_model.pt"), "--trajectories",
                     "shift@3", "--out", str(tmp_path / "dd")]) == 0
    assert (tmp_path / "dd" / "model.pt").is_file()
    # Bad input is a clear error (exit code 1): a strength outside (0, 1], a restorer as world model.
    assert cli_main(["train-recondreamer", *common, "--restorer", str(tmp_path / "restorer.pt"), "--stride", "1.5",
                     "--restore-strength", "0", "--out", str(tmp_path / "bad")]) == 1
    assert cli_main(["train-dd4d", *common, "--world-model", str(tmp_path / "restorer.pt"), "--out", str(tmp_path / "x")]) == 1


def test_dd4d_reads_videos_generated_once_by_the_dd4d_generate_command(scene, tmp_path):
    """The workflow's split (one 'dd4d-generate' per trajectory, then 'train-dd4d --generated') trains on
    exactly the frames train-dd4d would have generated itself (same seeds: run seed + trajectory index)."""
    world = tiny_generative("world_model", scene.height, scene.width)
    save_checkpoint(tmp_path / "world_model.pt", "world_model", world.arch, model_config_dict(world), world.unet.state_dict(),
                    autoencoder=autoencoder_payload(world.autoencoder))
    generated = tmp_path / "generated"
    for index, name in enumerate(("shift@3", "lane_change")):
        assert cli_main(["dd4d-generate", "--world-model", str(tmp_path / "world_model.pt"), "--scene", str(scene.path),
                         "--trajectory", name, "--seed", str(index), "--out", str(generated / name)]) == 0
    read = load_generated_videos(scene, generated, ("shift@3", "lane_change"))
    made = generate_videos(scene, world, None, ("shift@3", "lane_change"))
    for a, b in zip(read, made):
        assert a.source == b.source and a.info["offset_m"] == b.info["offset_m"]
        assert np.array_equal(a.poses, b.poses) and np.array_equal(a.frames, b.frames)

    common = ["--scene", str(scene.path), "--model", "street", "--preset", "quick", "--iterations", "4",
              "--backend", "cpu", "--threads", "1", "--trajectories", "shift@3,lane_change"]
    assert cli_main(["train-dd4d", *common, "--generated", str(generated), "--out", str(tmp_path / "dd")]) == 0
    assert (tmp_path / "dd" / "model.pt").is_file() and not (tmp_path / "dd" / "generated").exists()
    # A missing trajectory folder, or both/neither of the two sources, is a clear error.
    assert cli_main(["train-dd4d", *common[:-1], "shift@6", "--generated", str(generated), "--out", str(tmp_path / "x")]) == 1
    assert cli_main(["train-dd4d", *common, "--out", str(tmp_path / "y")]) == 1
    other = tmp_path / "other" / "shift@3"
    other.mkdir(parents=True)
    for frame in sorted((generated / "shift@3").glob("*.png")):
        (other / frame.name).write_bytes(frame.read_bytes())
    (other / "info.json").write_text(json.dumps({"scene_id": "another-scene", "trajectory": "shift@3"}))
    with pytest.raises(RecondreamerError, match="another-scene"):
        load_generated_videos(scene, other.parent, ("shift@3",))


def test_truth_oracle_trains_on_the_true_views_of_each_shifted_trajectory(scene, tmp_path):
    from recondreamer.methods.novel import load_video
    from recondreamer.scene.trajectories import trajectory_cam_to_world

    run = tmp_path / "oracle"
    schedule = PdusSchedule(stride=1.5, update_every=EVERY, iterations=ITERATIONS)
    train_recondreamer(scene, small_config(), run, TrueViewRenderer(scene), schedule, restorer_path="truth")
    assert json.loads((run / PDUS_JSON).read_text())["restorer"] == "truth"
    for k, offset in ((1, 1.5), (2, 3.0)):
        video = load_video(run / "updates" / f"update_{k:02d}", (scene.num_frames, scene.height, scene.width, 3))
        poses = trajectory_cam_to_world(scene.cam_to_world, scene.ego_to_world, f"shift@{offset:g}")
        np.testing.assert_array_equal(video.frames, TrueViewRenderer(scene).render(poses))
    expected = np.stack([scene.novel_image("shift@3", t) for t in range(scene.num_frames)])
    np.testing.assert_array_equal(video.frames, expected)  # shift@3 was also recorded by the generator


def test_a_view_conditioned_restorer_sees_the_recorded_frames(scene, tmp_path, monkeypatch):
    from recondreamer.generative import inference

    plain = tiny_generative("restorer", scene.height, scene.width)
    unet = LatentUNet(dataclasses.replace(plain.unet_config, view_condition=True)).eval()
    restorer = dataclasses.replace(plain, unet=unet, unet_config=unet.config)
    views = []
    original_restore = inference.restore_clip

    def spy_restore(*args, view=None, **kwargs):
        views.append(view)
        return original_restore(*args, view=view, **kwargs)

    monkeypatch.setattr(inference, "restore_clip", spy_restore)
    train_recondreamer(scene, small_config(iterations=EVERY + 1), tmp_path / "run", restorer,
                       PdusSchedule(stride=1.5, update_every=EVERY, iterations=EVERY + 1))
    assert len(views) == 1
    assert np.array_equal(views[0], np.stack([scene.image(t) for t in range(scene.num_frames)]))
