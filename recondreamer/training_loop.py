"""The one resumable training loop of every trainer: Gaussian reconstructions, autoencoder, world
models, DriveRestorers, pixel refiner and evaluation models.

``run_steps`` is the loop itself (steps, progress with ETA, resume state every
``checkpoint_every`` steps); the reconstruction trainer (``recon.trainer``) drives it with its
own step (view sampling, densification, per-parameter learning rates) and checkpoint, and
``run_training_loop`` with the step of every network trainer:

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


def format_duration(seconds: float) -> str:
    seconds = round(seconds)
    return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m{seconds % 60:02d}s" if seconds >= 3600 else f"{seconds // 60}m{seconds % 60:02d}s"


class ProgressLog:
    """Running means of a job's step metrics, ms/step (wall and process CPU) and ETA every ``every`` steps.

    CPU ms/step is what a step costs on an idle core; wall ms/step also counts the time other
    jobs on a shared machine take from this one. ``describe(mean)`` adds a job's own fields to the
    line (the reconstruction trainer: PSNR, Gaussians, loss parts).
    """

    def __init__(
        self,
        name: str,
        total: int,
        start: int,
        every: int,
        logger: logging.Logger = LOG,
        describe: Callable[[dict[str, float]], str] | None = None,
    ):
        self.name, self.total, self.every, self.logger, self.describe = name, total, every, logger, describe
        self.start_step, self.start_time, self.start_cpu = start, time.perf_counter(), time.process_time()
        self.window: list[dict[str, float]] = []
        self.last_mean: dict[str, float] = {}  # the metrics of the last logged window

    def update(self, done: int, metrics: dict[str, float]) -> None:
        """Record the metrics of step ``done`` (1-based; they include "loss") and log every ``every`` steps."""
        self.window.append(metrics)
        if done % self.every != 0 and done != self.total:
            return
        mean = {key: float(np.mean([m[key] for m in self.window if key in m])) for key in self.window[-1]}
        ms = self.ms_per_step(done)
        extras = self.describe(mean) if self.describe is not None else ""
        self.logger.info(
            "%s step %d/%d loss %.5f%s  %.0f ms/step (%.0f CPU ms/step)  ETA %s",
            self.name, done, self.total, mean["loss"], f" {extras}" if extras else "", ms, self.cpu_ms_per_step(done),
            format_duration(ms * (self.total - done) / 1000.0),
        )
        self.window, self.last_mean = [], mean

    def ms_per_step(self, done: int) -> float:
        return 1000.0 * (time.perf_counter() - self.start_time) / max(1, done - self.start_step)

    def cpu_ms_per_step(self, done: int) -> float:
        return 1000.0 * (time.process_time() - self.start_cpu) / max(1, done - self.start_step)


def run_steps(
    progress: ProgressLog,
    step: Callable[[int], dict[str, float]],  # (steps done before it) -> its metrics, "loss" among them
    start: int,
    total: int,
    checkpoint_every: int,
    save_state: Callable[[int], None],  # (steps done) -> writes the job's resume state
    after_step: Callable[[int], None] | None = None,  # (steps done) -> e.g. a snapshot
) -> None:
    """Steps ``start``..``total`` - 1 of a resumable job, the one loop every trainer runs.

    After each step: its metrics go to ``progress``, ``after_step`` runs, and every
    ``checkpoint_every`` steps short of the last the job's resume state is written (the job
    writes its final state itself).
    """
    for done in range(start + 1, total + 1):
        metrics = step(done - 1)
        progress.update(done, metrics)
        if after_step is not None:
            after_step(done)
        if done % checkpoint_every == 0 and done < total:
            save_state(done)


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
    recent: list[float] = []

    def one_step(step: int) -> dict[str, float]:
        nonlocal rng
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
        recent.append(loss.item())
        del recent[:-50]
        return {"loss": recent[-1]}

    def save_state(done: int) -> None:
        save_checkpoint(
            state_file, "training_state", job_identity.get("arch", ""), job_identity, module.state_dict(),
            optimizer=optimizer.state_dict(), numpy_rng=rng.bit_generator.state,
            torch_rng=generator.get_state(), step=done, ema=None if ema is None else ema.state_dict(),
        )

    progress = ProgressLog(name, steps, start, log_every)
    module.train()
    run_steps(progress, one_step, start, steps, checkpoint_every, save_state)
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


