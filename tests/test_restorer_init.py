"""train-restorer --init-restorer: a fine-tuning that starts from an earlier restorer (tiny sizes)."""

from __future__ import annotations

import dataclasses

import pytest
import torch
from test_restorer_models import tiny_model

from recondreamer.errors import CheckpointError
from recondreamer.restorer.autoencoder import Autoencoder
from recondreamer.restorer.checkpoint import load_checkpoint
from recondreamer.restorer.config import AutoencoderConfig, RestoreConfig, TrainConfig
from recondreamer.restorer.data import Sequence
from recondreamer.restorer.training import train_restorer

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
