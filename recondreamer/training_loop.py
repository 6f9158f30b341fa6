"""The one resumable training loop of every trainer: autoencoder, world models, DriveRestorers,
pixel refiner and evaluation models.

AdamW with a per-step learning rate (``warmup_cosine``: linear warm-up, cosine decay to a floor),
optional gradient clipping and an exponential moving average of the weights. Batches are drawn by
the job's loss function from a random generator the loop owns: one persistent generator whose
state the resume file keeps, or (``per_step_batches``) a fresh one seeded by (seed, step), so
that a batch depends on its step only. Every ``checkpoint_every`` steps the loop writes
``OUT.resume.pt`` (kind ``training_state``: model, optimiser, average, step, generator states);
started again with the same job identity it continues from there, and ``finish_job`` deletes it
once the job's final file is written. Progress (loss, ms/step, ETA) every ``log_every`` steps.
"""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from recondreamer.device import use_fast_conv_layout
from recondreamer.errors import CheckpointError
from recondreamer.generative.checkpoint import load_checkpoint, save_checkpoint

LOG = logging.getLogger(__name__)


def warmup_cosine(step: int, total: int, base: float, warmup: int, floor: float = 0.1) -> float:
    """Linear warm-up over ``warmup`` steps, then cosine decay to ``floor`` x the base rate."""
    if step < warmup:
        return base * (step + 1) / warmup
    progress = (step - warmup) / max(1, total - warmup)
    return base * (floor + (1.0 - floor) * 0.5 * (1.0 + math.cos(math.pi * progress)))


def resume_path(out: str | os.PathLike) -> Path:
    out = Path(out)
    return out.with_name(out.name + ".resume.pt")


class ProgressLog:
    """Running-mean loss, ms/step (wall and process CPU) and ETA every ``every`` steps.

    CPU ms/step is what a step costs on an idle core; wall ms/step also counts the time other
    jobs on a shared machine take from this one.
    """

    def __init__(self, name: str, total: int, start: int, every: int):
        self.name, self.total, self.every = name, total, every
        self.start_step, self.start_time, self.start_cpu = start, time.perf_counter(), time.process_time()
        self.losses: list[float] = []

    def update(self, step: int, loss: float) -> None:
        self.losses.append(loss)
        done = step + 1
        if done % self.every == 0 or done == self.total:
            ms = self.ms_per_step(done)
            eta = ms * (self.total - done) / 1000.0
            LOG.info(
                "%s step %d/%d loss %.5f  %.0f ms/step (%.0f CPU ms/step)  ETA %dm%02ds",
                self.name, done, self.total, float(np.mean(self.losses)), ms, self.cpu_ms_per_step(done), eta // 60, eta % 60,
            )
            self.losses.clear()

    def ms_per_step(self, done: int) -> float:
        return 1000.0 * (time.perf_counter() - self.start_time) / max(1, done - self.start_step)

    def cpu_ms_per_step(self, done: int) -> float:
        return 1000.0 * (time.process_time() - self.start_cpu) / max(1, done - self.start_step)


def run_training_loop(
    name: str,
    module: torch.nn.Module,
    loss_fn: Callable[[np.random.Generator, torch.Generator], torch.Tensor],
    steps: int,
    learning_rate: float,
    warmup: int,
    out: str | os.PathLike,
    job_identity: dict,
    checkpoint_every: int,
    log_every: int,
    seed: int,
    weight_decay: float = 0.0,
    ema_decay: float = 0.0,
    lr_schedule: Callable[[int, int, float, int], float] = warmup_cosine,  # (step, steps, learning_rate, warmup) -> rate
    clip_grad_norm: float | None = 1.0,
    per_step_batches: bool = False,
) -> dict:
    """Optimise ``module`` with AdamW for ``steps`` steps, resuming from ``OUT.resume.pt``.

    ``job_identity`` (arch and configs) must match the resume file's for it to be used; the
    step count may differ (a job can be extended or cut short on resume: the learning-rate
    schedule then follows the new total). With ``ema_decay`` > 0 an exponential moving average
    of the weights is kept from the first step (torch's ``AveragedModel``) and ``module`` ends
    with the averaged weights. Returns {"final_loss", "ms_per_step", "steps"}.
    """
    if not 0.0 <= ema_decay < 1.0:
        raise ValueError(f"ema_decay must be in [0, 1), got {ema_decay}")
    use_fast_conv_layout(module)  # before the optimiser and the average copy its parameters' layout
    optimizer = torch.optim.AdamW(module.parameters(), lr=learning_rate, weight_decay=weight_decay)
    ema = None
    if ema_decay > 0.0:
        # The average starts from the weights the job starts from; their share left at the end is
        # ema_decay**steps, so a short job with a slow average would mostly keep its start.
        if ema_decay**steps > 0.05:
            LOG.warning(
                "%s: EMA decay %g keeps %.0f%% of the starting weights after %d steps; use a smaller decay for so short a job",
                name, ema_decay, 100.0 * ema_decay**steps, steps,
            )
        ema = torch.optim.swa_utils.AveragedModel(module, multi_avg_fn=torch.optim.swa_utils.get_ema_multi_avg_fn(ema_decay))
    rng = np.random.default_rng(seed)
    generator = torch.Generator().manual_seed(seed)
    start = 0
    state_file = resume_path(out)
    if state_file.exists():
        state = load_checkpoint(state_file, "training_state")
        if _without_steps(state["config"]) != _without_steps(job_identity):
            raise CheckpointError(f"{state_file}: resume file of a different job configuration; delete it to start afresh")
        module.load_state_dict(state["state"])
        optimizer.load_state_dict(state["optimizer"])
        if ema is not None:
            ema.load_state_dict(state["ema"])
        rng.bit_generator.state = state["numpy_rng"]
        generator.set_state(state["torch_rng"])
        start = state["step"]
        LOG.info("%s: resuming from %s at step %d", name, state_file, start)
    progress = ProgressLog(name, steps, start, log_every)
    recent: list[float] = []
    module.train()
    for step in range(start, steps):
        for group in optimizer.param_groups:
            group["lr"] = lr_schedule(step, steps, learning_rate, warmup)
        if per_step_batches:
            rng = np.random.default_rng([seed, step])
        loss = loss_fn(rng, generator)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if clip_grad_norm is not None:
            torch.nn.utils.clip_grad_norm_(module.parameters(), clip_grad_norm)
        optimizer.step()
        if ema is not None:
            ema.update_parameters(module)
        recent = (recent + [loss.item()])[-50:]
        progress.update(step, loss.item())
        if (step + 1) % checkpoint_every == 0 and step + 1 < steps:
            save_checkpoint(
                state_file, "training_state", job_identity.get("arch", ""), job_identity, module.state_dict(),
                optimizer=optimizer.state_dict(), numpy_rng=rng.bit_generator.state,
                torch_rng=generator.get_state(), step=step + 1, ema=None if ema is None else ema.state_dict(),
            )
    if ema is not None:
        module.load_state_dict(ema.module.state_dict())
    module.eval()
    return {
        "final_loss": float(np.mean(recent)) if recent else float("nan"),
        "ms_per_step": progress.ms_per_step(steps),
        "cpu_ms_per_step": progress.cpu_ms_per_step(steps),
        "steps": steps,
    }


def _without_steps(identity: dict) -> dict:
    """A job identity without its step counts (every nested ``steps`` entry removed)."""
    return {k: _without_steps(v) if isinstance(v, dict) else v for k, v in identity.items() if k != "steps"}


def finish_job(out: str | os.PathLike) -> None:
    state_file = resume_path(out)
    if state_file.exists():
        state_file.unlink()


