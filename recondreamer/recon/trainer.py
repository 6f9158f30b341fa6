"""One trainer for every backbone: weighted view sampling, losses, density control, checkpoints.

``train_scene`` is the entry point: it builds (or resumes) a model for a scene and trains it in
a run directory, writing snapshots at configured steps, an atomic checkpoint every
``checkpoint_every`` steps, the final ``model.pt`` and progress lines in ``train.log``. The steps
run in the project's one resumable loop (``recondreamer.training_loop.run_steps``); what is the
reconstruction's own is the step (the Gaussian set and the optimiser's parameters change with
densification, each parameter group has its own learning-rate schedule) and the checkpoint.

Resume is exact: the checkpoint holds the model, Adam moments, density statistics and both
random generators (view sampling and split sampling), so a resumed run takes the same steps as
an uninterrupted one. On the CPU the results are bit-identical run to run; ``run.json`` says
what the run promises (``recon.reproducibility``).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np
import torch

from recondreamer.errors import CheckpointError
from recondreamer.evaluation.image_metrics import psnr_from_mse
from recondreamer.io import OutputPathError, write_json_atomic
from recondreamer.recon.base import GaussianSceneModel
from recondreamer.recon.checkpoint import (
    CHECKPOINT_NAME,
    MODEL_NAME,
    RUN_JSON,
    TRAIN_LOG,
    model_from_record,
    model_record,
    read_record,
    save_record,
    snapshot_path,
)
from recondreamer.configs import to_dict
from recondreamer.recon.config import ReconConfig
from recondreamer.recon.data import TargetCache, TrainingSet
from recondreamer.recon.density import (
    DensityController,
    build_optimizer,
    update_learning_rates,
)
from recondreamer.recon.losses import view_loss
from recondreamer.recon.models import MODEL_CLASSES
from recondreamer.recon.reproducibility import reproducibility
from recondreamer.training_loop import ProgressLog, run_steps

logger = logging.getLogger("recondreamer.recon")

# Called before every step with the trainer (e.g. PDUS refreshes the novel views every S steps).
StepCallback = Callable[["Trainer"], None]


class Trainer:
    """Trains ``model`` on ``training_set`` for ``config.iterations`` steps."""

    def __init__(
        self,
        model: GaussianSceneModel,
        training_set: TrainingSet,
        config: ReconConfig,
        run_dir: str | Path | None = None,
        scene_path: str | None = None,
        callbacks: Iterable[StepCallback] = (),
    ) -> None:
        self.model = model.to(config.device)
        self.training_set = training_set
        self.config = config
        self.run_dir = Path(run_dir) if run_dir is not None else None
        self.scene_path = scene_path
        self.scene_fingerprint: str | None = None  # Scene.fingerprint() of a scene read from disk (compared on resume)
        self.callbacks = list(callbacks)
        self.optimizer = build_optimizer(model, config.optim)
        self.density = DensityController(
            config.densify, config.iterations, len(model.gaussians), config.device
        )
        self.rng = np.random.default_rng(config.seed)
        self.generator = torch.Generator().manual_seed(config.seed)
        self.step = 0
        self.warmup_steps = int(config.net.warmup_fraction * config.iterations)
        self.last_psnr = float("nan")
        self.targets = TargetCache(config.loss.ssim_window, config.device)

    # --- one step -------------------------------------------------------------------------
    def train_step(self) -> dict[str, float]:
        config = self.config
        data = self.training_set
        view = data.sample(self.rng)
        static = self.step < self.warmup_steps
        coarse = (
            self.step < config.coarse_fraction * config.iterations
            and config.coarse_factor > 1
        )
        targets = self.targets.get(view, data.K, config.coarse_factor if coarse else 1)
        image = targets.image.image  # (h,w,3)
        height, width = image.shape[:2]
        self.model.train()
        render = self.model.render(
            view.cam_to_world,
            view.timestamp,
            targets.K,
            width,
            height,
            backend=config.backend,
            static=static,
            ray_directions=targets.ray_directions,
        )
        render["means2d"].retain_grad()
        loss, parts = view_loss(
            render, targets.image, targets.depth, targets.sky_mask, config.loss
        )
        regularization = None if static else self.model.regularization()
        if regularization is not None:
            loss = loss + regularization
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if render["means2d"].grad is not None:
            self.density.accumulate(
                render["means2d"].grad, render["radii"], width, height
            )
        update_learning_rates(
            self.optimizer, self.model, config.optim, self.step, config.iterations
        )
        self.optimizer.step()
        self.step += 1
        self.density.step(self.step, self.model, self.optimizer, self.generator)
        gaussians = self.model.gaussians
        if (
            self.step % config.net.sh_degree_every == 0
            and int(gaussians.active_sh_degree) < config.net.sh_degree
        ):
            gaussians.active_sh_degree += 1
        return {
            "loss": float(loss.detach()),
            "psnr": psnr_from_mse(float(((render["rgb"].detach() - image) ** 2).mean())),  # on the device: one scalar leaves it
            **parts,
        }

    # --- the loop -------------------------------------------------------------------------
    def run(self) -> GaussianSceneModel:
        config = self.config
        total = config.iterations
        file_handler = self._attach_log()
        started = time.monotonic()
        try:
            if 0 < self.step < total:
                logger.info("resumed from %s at step %d/%d", CHECKPOINT_NAME, self.step, total)  # marks the resume in train.log
            if self.step >= total:
                logger.info("already trained %d/%d steps", self.step, total)
            logger.info("reproducibility: %s", reproducibility(config, self.model)["repeats"])
            progress = ProgressLog(config.model, total, self.step, config.log_every, logger, self._describe)

            def one_step(done: int) -> dict[str, float]:
                for callback in self.callbacks:
                    callback(self)
                return self.train_step()

            def after_step(done: int) -> None:
                self.last_psnr = progress.last_mean.get("psnr", self.last_psnr)
                if self.run_dir is not None and done in config.snapshot_steps:
                    save_record(snapshot_path(self.run_dir, done), self._record("snapshot"))

            def save_state(done: int) -> None:
                if self.run_dir is not None:
                    self.save_checkpoint()

            run_steps(progress, one_step, self.step, total, config.checkpoint_every, save_state, after_step)
            if self.run_dir is not None:
                self.save_checkpoint()
                save_record(self.run_dir / MODEL_NAME, self._record("model"))
                self._write_run_json("done", time.monotonic() - started)
        finally:
            if file_handler is not None:
                logger.removeHandler(file_handler)
                file_handler.close()
        return self.model

    def _describe(self, mean: dict[str, float]) -> str:
        """The progress line's reconstruction fields: PSNR, Gaussians and the loss parts."""
        parts = " ".join(f"{key} {mean[key]:.4f}" for key in ("l1", "ssim", "depth", "sky") if key in mean)
        return f"psnr {mean['psnr']:.2f} gaussians {len(self.model.gaussians)} {parts}".rstrip()

    def _attach_log(self) -> logging.Handler | None:
        if self.run_dir is None:
            return None
        self.run_dir.mkdir(parents=True, exist_ok=True)
        handler = logging.FileHandler(self.run_dir / TRAIN_LOG)
        handler.setFormatter(
            logging.Formatter("%(asctime)s %(message)s", "%Y-%m-%d %H:%M:%S")
        )
        logger.addHandler(handler)
        if logger.getEffectiveLevel() > logging.INFO:
            logger.setLevel(logging.INFO)
        return handler

    # --- persistence ----------------------------------------------------------------------
    def _record(self, kind: str) -> dict:
        record = model_record(kind, self.model, self.config, self.step, self.scene_path)
        record["scene_fingerprint"] = self.scene_fingerprint
        return record

    def save_checkpoint(self) -> None:
        record = self._record("checkpoint")
        record["optimizer"] = self.optimizer.state_dict()
        record["density"] = self.density.state_dict()
        record["rng"] = {
            "numpy": self.rng.bit_generator.state,
            "torch": self.generator.get_state(),
        }
        save_record(self.run_dir / CHECKPOINT_NAME, record)
        self._write_run_json("running", None)

    def load_checkpoint(self, record: dict) -> None:
        """Restore optimiser, density statistics, generators and step (the model comes from the record)."""
        self.optimizer.load_state_dict(record["optimizer"])
        self.density.load_state_dict(record["density"])
        self.rng.bit_generator.state = record["rng"]["numpy"]
        self.generator.set_state(record["rng"]["torch"])
        self.step = int(record["step"])

    def _write_run_json(self, status: str, wall_time: float | None) -> None:
        info = {
            "status": status,
            "model_type": self.model.model_type,
            "scene_id": self.model.spec().get("scene_id", ""),
            "scene_path": self.scene_path,
            "step": self.step,
            "iterations": self.config.iterations,
            "num_gaussians": len(self.model.gaussians),
            "training_sources": self.training_set.sources(),
            "last_logged_psnr": None
            if np.isnan(self.last_psnr)
            else round(self.last_psnr, 3),
            "wall_time_s": None if wall_time is None else round(wall_time, 2),
            "reproducibility": reproducibility(self.config, self.model),
            "config": to_dict(self.config),
        }
        write_json_atomic(self.run_dir / RUN_JSON, info)


def train_scene(
    scene,
    config: ReconConfig,
    run_dir: str | Path | None,
    training_set: TrainingSet | None = None,
    callbacks: Iterable[StepCallback] = (),
    resume: bool = True,
) -> GaussianSceneModel:
    """Train ``config.model`` on ``scene`` (a loaded Scene); resume from ``RUN/checkpoint.pt`` if present.

    ``training_set`` defaults to the scene's original frames. A checkpoint of a different
    model, scene or config in ``run_dir`` is an error rather than silently overwritten.
    """
    training_set = (
        training_set if training_set is not None else TrainingSet.from_scene(scene)
    )
    # Absolute, so run.json names the scene wherever the run is used from.
    scene_path = (
        str(Path(scene.path).resolve()) if getattr(scene, "path", None) else None
    )
    if run_dir is not None and Path(run_dir).exists() and not Path(run_dir).is_dir():
        raise OutputPathError(f"{run_dir}: exists and is not a directory; choose another --out directory for the run")
    fingerprint = scene.fingerprint() if scene_path is not None else None
    checkpoint = Path(run_dir) / CHECKPOINT_NAME if run_dir is not None else None
    if resume and checkpoint is not None and checkpoint.exists():
        record = read_record(checkpoint)
        mismatch = [
            what
            for what, ours, theirs in (
                ("model type", config.model, record["model_type"]),
                ("scene id", scene.scene_id, record["scene_id"]),
                ("scene content (fingerprint)", fingerprint, record.get("scene_fingerprint")),
                ("config", to_dict(config), record["config"]),
            )
            if _normalized(ours) != _normalized(theirs)
        ]
        if mismatch or record.get("kind") != "checkpoint":
            raise CheckpointError(
                f"{checkpoint}: belongs to a different run (differs in {', '.join(mismatch) or 'kind'}); "
                "choose another --out directory or delete the old one"
            )
        model = model_from_record(record)
        trainer = Trainer(model, training_set, config, run_dir, scene_path, callbacks)
        trainer.scene_fingerprint = fingerprint
        trainer.load_checkpoint(record)
        logger.info(
            "resuming %s on %s from step %d", config.model, scene.scene_id, trainer.step
        )
    else:
        torch.manual_seed(config.seed)
        model = MODEL_CLASSES[config.model].from_scene(
            scene, config, np.random.default_rng(config.seed)
        )
        trainer = Trainer(model, training_set, config, run_dir, scene_path, callbacks)
        trainer.scene_fingerprint = fingerprint
        logger.info(
            "training %s on %s: %d views %s, %d initial Gaussians, %d iterations",
            config.model,
            scene.scene_id,
            len(training_set),
            training_set.sources(),
            len(model.gaussians),
            config.iterations,
        )
        if run_dir is not None:
            Path(run_dir).mkdir(parents=True, exist_ok=True)
            trainer._write_run_json("running", None)
    return trainer.run()


def _normalized(value):
    """Tuples and lists compare equal (a config read back from a checkpoint has lists)."""
    if isinstance(value, dict):
        return {key: _normalized(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_normalized(item) for item in value]
    return value
