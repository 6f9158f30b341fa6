"""Exponential moving average of the weights in the training loop (``TrainConfig.ema_decay``)."""

import numpy as np
import pytest
import torch

from recondreamer.cli import main
from recondreamer.generative.checkpoint import load_checkpoint
from recondreamer.training_loop import resume_path, run_training_loop

pytestmark = pytest.mark.usefixtures("one_torch_thread")

TARGET = torch.tensor([[1.0], [2.0], [3.0]])


class Interrupted(Exception):
    """Stands in for a kill in the middle of a job."""


def make_module() -> torch.nn.Linear:
    torch.manual_seed(0)
    return torch.nn.Linear(3, 1)


def loss_fn_for(module, seen=None, fail_at=None):
    """A noisy regression loss; ``seen`` collects the weights each step starts from."""
    calls = {"n": 0}

    def loss_fn(rng, generator):
        calls["n"] += 1
        if fail_at is not None and calls["n"] == fail_at:
            raise Interrupted
        if seen is not None:
            seen.append(torch.cat([p.detach().flatten() for p in module.parameters()]).clone())
        x = torch.from_numpy(rng.normal(size=(3, 3)).astype(np.float32)) + torch.randn(3, 3, generator=generator)
        return torch.mean((module(x) - TARGET) ** 2)

    return loss_fn


def flat(module) -> torch.Tensor:
    return torch.cat([p.detach().flatten() for p in module.parameters()])


def train(module, out, steps, ema_decay, seen=None, fail_at=None):
    return run_training_loop(
        "toy", module, loss_fn_for(module, seen, fail_at), steps, 0.05, 1, out, {"arch": "toy", "ema": ema_decay}, 2, 100,
        seed=1, ema_decay=ema_decay,
    )


def test_the_saved_weights_are_the_moving_average_of_the_trained_weights(tmp_path):
    steps, decay = 7, 0.6
    plain, seen = make_module(), []
    train(plain, tmp_path / "plain.pt", steps, 0.0, seen)
    after_each_step = seen[1:] + [flat(plain)]  # the weights that step k+1 starts from are step k's result

    # Reference: the average starts at the first step's weights, then mixes in each later step's.
    expected = after_each_step[0]
    for weights in after_each_step[1:]:
        expected = decay * expected + (1.0 - decay) * weights

    averaged = make_module()
    train(averaged, tmp_path / "ema.pt", steps, decay)
    assert torch.allclose(flat(averaged), expected, atol=1e-6)
    assert not torch.allclose(flat(averaged), flat(plain))  # the average is not the last weights


def test_an_interrupted_job_with_a_moving_average_resumes_to_the_same_weights(tmp_path):
    straight = make_module()
    train(straight, tmp_path / "a.pt", 6, 0.5)
    interrupted = make_module()
    with pytest.raises(Interrupted):
        train(interrupted, tmp_path / "b.pt", 6, 0.5, fail_at=5)
    assert load_checkpoint(resume_path(tmp_path / "b.pt"), "training_state")["ema"] is not None
    resumed = make_module()
    train(resumed, tmp_path / "b.pt", 6, 0.5)
    assert torch.allclose(flat(resumed), flat(straight))


@pytest.mark.parametrize("decay", [-0.1, 1.0])
def test_a_decay_outside_zero_to_one_is_refused(tmp_path, decay):
    with pytest.raises(ValueError, match="ema_decay"):
        train(make_module(), tmp_path / "x.pt", 2, decay)


def test_a_slow_average_on_a_short_job_is_warned_about(tmp_path, caplog):
    with caplog.at_level("WARNING"):
        train(make_module(), tmp_path / "x.pt", 3, 0.99)
    assert "keeps 97% of the starting weights" in caplog.text


@pytest.mark.parametrize("command", ["train-restorer", "pretrain-world-model"])
def test_the_cli_refuses_a_bad_ema_decay_before_any_work(tmp_path, capsys, command):
    args = ["--arch", "dd2", "--out", str(tmp_path / "m.pt"), "--ema-decay", "1.5"]
    if command == "train-restorer":
        args += ["--world-model", str(tmp_path / "missing.pt"), "--pairs", str(tmp_path)]
    else:
        args += ["--corpus", str(tmp_path), "--autoencoder", str(tmp_path / "missing.pt")]
    assert main([command, *args]) == 1
    assert "--ema-decay must be in [0, 1), got 1.5" in capsys.readouterr().err
