"""train-restorer --init-restorer: a fine-tuning that starts from an earlier restorer (tiny sizes)."""

from __future__ import annotations

import dataclasses

import pytest
import torch
from test_generative_models import tiny_model

from recondreamer.errors import CheckpointError
from recondreamer.generative.autoencoder import Autoencoder
from recondreamer.generative.checkpoint import load_checkpoint
from recondreamer.generative.config import AutoencoderConfig, RestoreConfig, TrainConfig
from recondreamer.generative.data import Sequence
from recondreamer.generative.training import train_restorer

# Small tensors: one torch thread each (tests/conftest.py).
pytestmark = pytest.mark.usefixtures("one_torch_thread")

TRAIN = TrainConfig(steps=2, window=3, crop=(0, 0), batch_size=1, warmup_steps=1, checkpoint_every=100, log_every=100)


def _sequences(scene_id: str) -> list[Sequence]:
    g = torch.Generator().manual_seed(len(scene_id))
    target = torch.randn(5, 4, 8, 12, generator=g)
    return [Sequence(name=scene_id, scene_id=scene_id, target=target, reference=target, structure=None,
                     degraded=target[None] + 0.3 * torch.randn(2, 5, 4, 8, 12, generator=g))]


def _train(world, out, scene_id="a", init_from=None, target_space="residual", **train_changes):
    train = dataclasses.replace(TRAIN, **train_changes)
    return train_restorer(world, "sd", _sequences(scene_id), train, None, RestoreConfig(), out, "wm.pt", target_space, "cpu", init_from)


def test_a_restorer_started_from_another_starts_from_its_weights_and_counts_both_jobs(tmp_path):
    world = tiny_model("sd")
    _train(world, tmp_path / "first.pt", steps=3)
    first = load_checkpoint(tmp_path / "first.pt", "restorer")
    # Learning rate 0: the second job leaves the weights it started from unchanged.
    _train(world, tmp_path / "second.pt", scene_id="bb", init_from=tmp_path / "first.pt", steps=2, learning_rate=0.0)
    second = load_checkpoint(tmp_path / "second.pt", "restorer")
    assert all(torch.equal(first["state"][name], second["state"][name]) for name in first["state"])
    assert second["metrics"]["steps"] == 2 and second["metrics"]["total_steps"] == 5
    assert second["metrics"]["total_cpu_minutes"] > second["metrics"]["cpu_ms_per_step"] * 2 / 60000.0
    assert second["training_scenes"] == ["a", "bb"] and second["initialised_from"] == str(tmp_path / "first.pt")
    # Without a start the restorer is the world model plus its zero-initialised degraded branch: not the first restorer.
    _train(world, tmp_path / "fresh.pt", steps=2, learning_rate=0.0)
    fresh = load_checkpoint(tmp_path / "fresh.pt", "restorer")
    assert not all(torch.equal(first["state"][name], fresh["state"][name]) for name in first["state"])
    assert fresh["initialised_from"] is None and fresh["metrics"]["total_steps"] == 2


def test_a_start_that_does_not_fit_the_job_is_refused(tmp_path):
    world = tiny_model("sd")
    _train(world, tmp_path / "first.pt")
    with pytest.raises(CheckpointError, match="target space|space"):
        _train(world, tmp_path / "clean.pt", init_from=tmp_path / "first.pt", target_space="clean")
    other_autoencoder = dataclasses.replace(world, autoencoder=Autoencoder(AutoencoderConfig(hidden_channels=(8, 8, 8))).eval())
    with pytest.raises(CheckpointError, match="another autoencoder"):
        _train(other_autoencoder, tmp_path / "other.pt", init_from=tmp_path / "first.pt")
    svd_world = dataclasses.replace(tiny_model("svd"), autoencoder=world.autoencoder)
    with pytest.raises(CheckpointError, match="cannot start"):
        train_restorer(svd_world, "svd", _sequences("a"), TRAIN, None, RestoreConfig(), tmp_path / "svd.pt", "wm.pt", "residual", "cpu",
                       tmp_path / "first.pt")
    with pytest.raises(CheckpointError, match="does not exist"):
        _train(world, tmp_path / "missing.pt", init_from=tmp_path / "nothing.pt")


def _outputs(payload: dict) -> torch.Tensor:
    """The UNet output of a restorer checkpoint on fixed random inputs."""
    from test_generative_models import random_inputs

    from recondreamer.generative.models import model_from_payload

    unet = model_from_payload(payload).unet
    inputs = random_inputs("sd")
    with torch.no_grad():
        return unet(inputs["noisy"], inputs["timesteps"], inputs["reference"], degraded=torch.ones_like(inputs["noisy"]))


def test_a_deeper_restorer_grown_from_another_starts_with_its_output_and_keeps_growing(tmp_path):
    world = tiny_model("sd")
    _train(world, tmp_path / "first.pt", steps=3)
    first = load_checkpoint(tmp_path / "first.pt", "restorer")
    assert first["config"]["unet"]["blocks_per_level"] == 1
    # Learning rate 0: what the grown restorer computes is what the blocks it started with compute.
    train = dataclasses.replace(TRAIN, steps=2, learning_rate=0.0)
    train_restorer(world, "sd", _sequences("bb"), train, None, RestoreConfig(), tmp_path / "grown.pt", "wm.pt", "residual", "cpu",
                   tmp_path / "first.pt", blocks_per_level=3)
    grown = load_checkpoint(tmp_path / "grown.pt", "restorer")
    assert grown["config"]["unet"]["blocks_per_level"] == 3
    assert any(name.startswith("down_extra.0.1.") for name in grown["state"]) and any(name.startswith("up_extra.") for name in grown["state"])
    assert all(torch.equal(first["state"][name], grown["state"][name]) for name in first["state"])
    torch.testing.assert_close(_outputs(grown), _outputs(first), rtol=0, atol=1e-6)
    # Trained on, the extra blocks change the output; without --blocks-per-level a job keeps its start's depth.
    _train(world, tmp_path / "on.pt", init_from=tmp_path / "grown.pt", steps=3)
    on = load_checkpoint(tmp_path / "on.pt", "restorer")
    assert on["config"]["unet"]["blocks_per_level"] == 3
    assert not torch.allclose(_outputs(on), _outputs(grown), atol=1e-4)
    # A restorer cannot shrink.
    with pytest.raises(CheckpointError, match="cannot start"):
        train_restorer(world, "sd", _sequences("a"), TRAIN, None, RestoreConfig(), tmp_path / "shrunk.pt", "wm.pt", "residual", "cpu",
                       tmp_path / "grown.pt", blocks_per_level=2)


def test_a_world_model_grows_into_a_deeper_restorer_that_starts_as_the_world_model(tmp_path):
    from recondreamer.generative.models import restorer_unet_from_world_model

    world = tiny_model("sd")
    shallow, deep = restorer_unet_from_world_model(world, "sd"), restorer_unet_from_world_model(world, "sd", blocks_per_level=2)
    assert deep.config.blocks_per_level == 2 and len(deep.down_extra[0]) == 1 and len(shallow.down_extra[0]) == 0
    from test_generative_models import random_inputs

    inputs = random_inputs("sd")
    degraded = torch.randn_like(inputs["noisy"])
    with torch.no_grad():
        torch.testing.assert_close(
            deep(inputs["noisy"], inputs["timesteps"], inputs["reference"], degraded=degraded),
            world.unet(inputs["noisy"], inputs["timesteps"], inputs["reference"]),
            rtol=0, atol=1e-6,
        )
    with pytest.raises(CheckpointError, match="cannot start from a world model"):
        restorer_unet_from_world_model(dataclasses.replace(world, unet_config=dataclasses.replace(world.unet_config, blocks_per_level=2)), "sd", 1)


def test_train_restorer_refuses_a_block_count_below_one(tmp_path, capsys):
    from recondreamer.cli import main

    code = main(["train-restorer", "--arch", "sd", "--world-model", str(tmp_path / "wm.pt"), "--pairs", str(tmp_path),
                 "--out", str(tmp_path / "r.pt"), "--blocks-per-level", "0"])
    assert code != 0 and "--blocks-per-level must be >= 1" in capsys.readouterr().err


def test_a_resume_file_resumes_only_the_same_job_configuration(tmp_path, monkeypatch, caplog):
    import recondreamer.generative.training as training
    from recondreamer.generative.checkpoint import save_checkpoint
    from recondreamer.training_loop import resume_path

    world = tiny_model("sd")
    # A job stopped after its first checkpoint (step 1): its resume file stays behind.
    monkeypatch.setattr(training, "finish_job", lambda out: None)
    _train(world, tmp_path / "r.pt", checkpoint_every=1)
    monkeypatch.undo()
    state_file = resume_path(tmp_path / "r.pt")
    state = load_checkpoint(state_file, "training_state")
    assert state["step"] == 1

    def rewrite(unet_config: dict) -> None:
        extra = {key: value for key, value in state.items() if key not in ("format", "format_version", "kind", "arch", "config", "state")}
        save_checkpoint(state_file, "training_state", state["arch"], {**state["config"], "unet": unet_config}, state["state"], **extra)

    with caplog.at_level("INFO", logger="recondreamer"):
        _train(world, tmp_path / "r.pt", checkpoint_every=1)
    assert "resuming from" in caplog.text and "at step 1" in caplog.text
    assert not state_file.exists()
    # A resume file written before UNetConfig.blocks_per_level existed is another job's: never
    # silently completed with today's default.
    monkeypatch.setattr(training, "finish_job", lambda out: None)
    _train(world, tmp_path / "r.pt", checkpoint_every=1)
    monkeypatch.undo()
    state = load_checkpoint(state_file, "training_state")
    rewrite({key: value for key, value in state["config"]["unet"].items() if key != "blocks_per_level"})
    with pytest.raises(CheckpointError, match="different job configuration"):
        _train(world, tmp_path / "r.pt", checkpoint_every=1)
    state_file.unlink()
    # A resume file of another depth is still another job.
    monkeypatch.setattr(training, "finish_job", lambda out: None)
    _train(world, tmp_path / "r.pt", checkpoint_every=1)
    monkeypatch.undo()
    state = load_checkpoint(state_file, "training_state")
    rewrite({**state["config"]["unet"], "blocks_per_level": 2})
    with pytest.raises(CheckpointError, match="different job configuration"):
        _train(world, tmp_path / "r.pt", checkpoint_every=1)
