"""ReconDreamer: reconstruction training with online DriveRestorer restoration driven by PDUS.

``ProgressiveDataUpdate`` is a trainer callback (run before every step). Before step ``k*S`` it
renders the trajectory shifted ``min(k*dy, max)`` metres to the left with the *current* model,
restores the clip with DriveRestorer (conditioned on the 3D boxes and HD map projected into
that trajectory), saves the restored video as ``RUN/updates/update_KK/`` (atomic) and adds its
frames as depth-free training views, re-weighting all videos as in Algorithm 1.

Resume: the state of the loop is a function of the training step and the update folders. After
a kill, ``train_scene`` resumes from ``RUN/checkpoint.pt`` at step s; the first callback then
reloads every update due before s from disk (folders are complete or absent), reusing an update
saved after the checkpoint too (it was made from the same model state), and only computes what
is missing. ``RUN/pdus.json`` records the schedule and refuses a resume with another one.
"""

from __future__ import annotations

import logging
import shutil
import time
from pathlib import Path

import numpy as np

from recondreamer.errors import RecondreamerError
from recondreamer.io import write_json_atomic
from recondreamer.methods.novel import NovelVideo, load_video, save_video
from recondreamer.methods.pdus import (
    PdusSchedule,
    apply_mixing,
    coverage_gap,
    video_weights,
)
from recondreamer.recon.config import ReconConfig
from recondreamer.recon.data import TrainingSet
from recondreamer.recon.render import render_frames
from recondreamer.scene.trajectories import lateral_offsets, trajectory_cam_to_world
from recondreamer.sources.synthetic.truth import TrueViewRenderer

# A child of the trainer's logger, so update lines land in RUN/train.log between progress lines.
logger = logging.getLogger("recondreamer.recon.pdus")

PDUS_JSON = "pdus.json"
UPDATES_DIR = "updates"


def update_name(k: int) -> str:
    return f"update_{k:02d}"


def shift_name(offset: float) -> str:
    return f"shift@{offset:g}"


class ProgressiveDataUpdate:
    """Trainer callback running Algorithm 1 with a DriveRestorer (``generative.inference.load_restorer``).

    ``restorer`` may instead be a ``TrueViewRenderer`` (synthetic scenes only): each update then
    trains on the true views of the shifted trajectory, the upper bound of any restorer.
    """

    def __init__(self, scene, restorer, schedule: PdusSchedule, run_dir: str | Path | None,
                 backend: str = "auto", restore_steps: int | None = None, seed: int = 0,
                 preview_frames: int = 3, restorer_path: str | None = None,
                 restore_strength: float | None = None) -> None:
        self.scene = scene
        self.restorer = restorer
        self.schedule = schedule
        self.run_dir = Path(run_dir) if run_dir is not None else None
        self.backend = backend
        self.restore_steps = restore_steps
        self.restore_strength = restore_strength  # None: the restorer checkpoint's (1 = from pure noise)
        self.seed = seed
        self.preview_frames = preview_frames
        self.restorer_path = restorer_path
        self.videos: list[NovelVideo] = []
        if self.run_dir is not None:
            self._check_or_write_state()

    @property
    def k(self) -> int:
        return len(self.videos)

    # --- the callback -------------------------------------------------------------------
    def __call__(self, trainer) -> None:
        due = self.schedule.updates_due(trainer.step)
        if due == self.k:
            return
        for k in range(self.k + 1, due + 1):
            video = self._load(k)
            if video is None:
                if self.schedule.update_step(k) < trainer.step:
                    logger.warning("pdus: update %d (step %d) missing on disk; recomputing it with the model of step %d",
                                   k, self.schedule.update_step(k), trainer.step)
                video = self._make_update(trainer, k)
            else:
                logger.info("pdus: update %d (%s m) reloaded from %s", k, video.info["offset_m"], self._folder(k))
            trainer.training_set.extend(video.views())
            self.videos.append(video)
        apply_mixing(trainer.training_set, [v.source for v in self.videos], self.schedule.novel_fraction)
        if self.run_dir is not None:
            self._write_state(trainer.step)

    def _make_update(self, trainer, k: int) -> NovelVideo:
        from recondreamer.generative.data import scene_structure
        from recondreamer.generative.inference import restore_clip

        scene, offset = self.scene, self.schedule.offset(k)
        started = time.monotonic()
        poses = trajectory_cam_to_world(scene.cam_to_world, scene.ego_to_world, shift_name(offset))
        rendered, _ = render_frames(trainer.model, scene, poses, backend=self.backend)  # (T,H,W,3)
        if isinstance(self.restorer, TrueViewRenderer):  # the oracle: what a perfect restorer would return
            restored = self.restorer.render(poses)
        else:
            structure = scene_structure(scene, poses)  # (T,C,H,W) uint8, boxes + map in the shifted cameras
            # A view-conditioned restorer (beyond the paper) also sees the recorded frames of the same timestamps.
            view = scene.images() if self.restorer.unet_config.view_condition else None
            restored = restore_clip(self.restorer, rendered, structure, num_steps=self.restore_steps,
                                    strength=self.restore_strength, seed=self.seed + k, view=view)
        weights = video_weights(k)
        video = NovelVideo(
            source=f"pdus{k}@{offset:g}m",
            poses=poses,
            timestamps=np.asarray(scene.timestamps, dtype=np.float64),
            frames=restored,
            info={
                "k": k, "step": trainer.step, "offset_m": offset, "trajectory": shift_name(offset),
                "stride_m": self.schedule.stride, "weight": float(weights[-1]),
                "change_vs_render": float(np.abs(restored.astype(np.float32) - rendered.astype(np.float32)).mean()),
                "seconds": round(time.monotonic() - started, 2),
            },
        )
        if self.run_dir is not None:
            save_video(self._folder(k), video, rendered, self.preview_frames)
        logger.info(
            "pdus: update %d at step %d: %s rendered and restored (%d frames, %.1f s, mean |restored - render| %.1f); "
            "video weights %s", k, trainer.step, shift_name(offset), len(restored), video.info["seconds"],
            video.info["change_vs_render"], np.round(weights, 3).tolist(),
        )
        return video

    # --- persistence --------------------------------------------------------------------
    def _folder(self, k: int) -> Path:
        return self.run_dir / UPDATES_DIR / update_name(k)

    def _load(self, k: int) -> NovelVideo | None:
        if self.run_dir is None or not self._folder(k).is_dir():
            return None
        scene = self.scene
        video = load_video(self._folder(k), (scene.num_frames, scene.height, scene.width, 3))
        if abs(float(video.info.get("offset_m", np.nan)) - self.schedule.offset(k)) > 1e-9:
            raise RecondreamerError(f"{self._folder(k)}: offset {video.info.get('offset_m')} m does not match this "
                                    f"schedule's {self.schedule.offset(k)} m; choose another --out directory")
        return video

    def _identity(self) -> dict:
        return {"schedule": self.schedule.to_dict(), "restorer": self.restorer_path, "seed": self.seed,
                "restore_steps": self.restore_steps, "restore_strength": self.restore_strength}

    def _check_or_write_state(self) -> None:
        path = self.run_dir / PDUS_JSON
        if path.is_file():
            import json

            recorded = json.loads(path.read_text())
            mine = self._identity()
            differs = [key for key in mine if recorded.get(key) != mine[key]]
            if differs:
                raise RecondreamerError(f"{path}: this run used another PDUS set-up (differs in {', '.join(differs)}); "
                                        "choose another --out directory or delete the old one")
        # Temporary folders of an update interrupted by a kill (atomic_directory leaves them behind).
        updates = self.run_dir / UPDATES_DIR
        for stale in updates.glob(".*.tmp") if updates.is_dir() else ():
            shutil.rmtree(stale, ignore_errors=True)
        self._write_state(None)

    def _write_state(self, step: int | None) -> None:
        num_frames = self.scene.num_frames
        write_json_atomic(self.run_dir / PDUS_JSON, {
            **self._identity(),
            "k": self.k,
            "at_step": step,
            "updates": [{"name": update_name(i + 1), "source": v.source, "offset_m": v.info["offset_m"],
                         "step": v.info["step"]} for i, v in enumerate(self.videos)],
            "video_weights": video_weights(self.k).tolist(),
            "planned_offsets_m": self.schedule.offsets(),
            "lane_change_gap_m": coverage_gap(self.schedule.offsets(), lateral_offsets("lane_change", num_frames)),
        })


def train_recondreamer(scene, config: ReconConfig, run_dir: str | Path | None, restorer,
                       schedule: PdusSchedule, restore_steps: int | None = None,
                       restorer_path: str | None = None, restore_strength: float | None = None,
                       extra_callbacks=()):
    """Train ``config.model`` on the scene with PDUS updates; returns the trained model."""
    from recondreamer.recon.trainer import train_scene

    if schedule.iterations != config.iterations:
        raise RecondreamerError(f"PDUS schedule is for {schedule.iterations} iterations, the run has {config.iterations}")
    gap = coverage_gap(schedule.offsets(), lateral_offsets("lane_change", scene.num_frames))
    logger.info("pdus: stride %g m, update every %d steps, offsets %s m; lane change (0..%.1f m) within %.2f m of a "
                "trained offset", schedule.stride, schedule.update_every, schedule.offsets(),
                float(lateral_offsets("lane_change", scene.num_frames).max()), gap)
    update = ProgressiveDataUpdate(scene, restorer, schedule, run_dir, backend=config.backend,
                                   restore_steps=restore_steps, seed=config.seed, restorer_path=restorer_path,
                                   restore_strength=restore_strength)
    return train_scene(scene, config, run_dir, training_set=TrainingSet.from_scene(scene),
                       callbacks=[update, *extra_callbacks])
