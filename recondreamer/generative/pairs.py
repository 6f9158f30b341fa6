"""Restoration pairs (paper Fig. 3): renders of the original trajectory by under-trained
reconstructions at several training stages, paired with the ground-truth frames.

One compressed ``.npz`` per run: ``gt`` (T,H,W,3) uint8, ``degraded`` (K,T,H,W,3) uint8 (one clip
per stage), ``stages`` (K,) training steps, ``structure`` (T,C,H,W) uint8 structure maps of the
original cameras (x255), ``structure_channels`` their names, ``vanishing`` (T,2) the ego-forward
vanishing point per frame, optional ``sky`` (T,H,W) bool ground-truth sky masks, and the
``scene_id`` / ``run`` / ``scene_path`` / ``trajectory`` they came from.

Synthetic scenes also store their true novel views, so pairs can be made on novel trajectories
too (``trajectories``): renders along e.g. ``shift@3`` from every selected snapshot *and* the
final model, paired with the true novel frames. Those are the artifacts DriveRestorer meets in
the ReconDreamer loop (a fully trained reconstruction seen from a lane away), which training-view
renders of late snapshots barely show. One ``SCENE__RUN__TRAJECTORY.npz`` per novel trajectory;
``sky`` then comes from the novel views' sky masks where the scene has them, and ``view`` (T,H,W,3)
uint8 holds the recorded frames of the same timestamps: the views the reconstruction was trained
on, which a view-conditioned restorer (``UNetConfig.view_condition``, beyond the paper) takes as
a further input.

Cycle pairs (``cycle.py``) are pairs along the recorded trajectory whose renders come from a
reconstruction trained on another's renders of a lateral drive; ``cycle_from`` names that drive, and
``view`` holds the renders it was trained on.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path

import numpy as np

from recondreamer.errors import RecondreamerError
from recondreamer.io import atomic_path

LOG = logging.getLogger(__name__)


def select_stages(snapshots: list[Path], num_stages: int) -> list[Path]:
    """Up to ``num_stages`` snapshots evenly spread over training (earliest and latest included)."""
    if len(snapshots) <= num_stages:
        return snapshots
    indices = np.unique(np.linspace(0, len(snapshots) - 1, num_stages).round().astype(int))
    return [snapshots[i] for i in indices]


def run_scene_path(run_dir: Path) -> Path:
    """The scene a reconstruction run was trained on, from its ``run.json``."""
    run_json = run_dir / "run.json"
    if not run_json.is_file():
        raise RecondreamerError(f"{run_json}: run description not found (pass --scene to name the scene)")
    info = json.loads(run_json.read_text())
    for key in ("scene_path", "scene"):
        if isinstance(info.get(key), str):
            path = Path(info[key])
            return path if path.is_absolute() or path.exists() else run_dir / path
    raise RecondreamerError(f"{run_json}: has no 'scene_path' entry (pass --scene to name the scene)")


def make_pairs_for_run(
    run_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    num_stages: int,
    scene_dir: str | os.PathLike | None = None,
    trajectories: tuple[str, ...] = ("original",),
) -> list[Path]:
    """Render each trajectory from each selected snapshot of one run; write one .npz per trajectory."""
    from recondreamer.recon import load_model
    from recondreamer.scene import load_scene

    run_dir = Path(run_dir)
    snapshots = sorted((run_dir / "snapshots").glob("step_*.pt"))
    if not snapshots:
        raise RecondreamerError(f"{run_dir}: no training-stage snapshots (snapshots/step_*.pt)")
    scene = load_scene(scene_dir if scene_dir is not None else run_scene_path(run_dir))
    novel = [name for name in trajectories if name != "original"]
    missing = [name for name in novel if name not in scene.novel_trajectories]
    if missing:
        raise RecondreamerError(
            f"--trajectories {' '.join(missing)}: scene {scene.path} has no true novel views for them "
            f"(it has {', '.join(scene.novel_trajectories) or 'none'})"
        )
    final = run_dir / "model.pt"
    if novel and not final.is_file():
        raise RecondreamerError(f"{run_dir}: novel-trajectory pairs need the final model {final}")
    chosen = select_stages(snapshots, num_stages)
    models = {int(p.stem.split("_")[1]): load_model(p) for p in chosen}
    if novel:
        iterations = json.loads((run_dir / "run.json").read_text()).get("iterations") if (run_dir / "run.json").is_file() else None
        models[int(iterations) if iterations else max(models) + 1] = load_model(final)
    written = []
    for name in trajectories:
        stages = sorted(models) if name != "original" else [int(p.stem.split("_")[1]) for p in chosen]
        written.append(_write_trajectory_pairs(run_dir, scene, name, {step: models[step] for step in stages}, Path(out_dir)))
    return written


def _write_trajectory_pairs(
    run_dir: Path, scene, trajectory: str, models: dict, out_dir: Path, view: np.ndarray | None = None, cycle_from: str | None = None
) -> Path:
    """Render ``trajectory`` with each model; write the pairs file. ``view`` (T,H,W,3) uint8: the
    reference views to store (default: the recorded frames on a novel trajectory, none on the original);
    ``cycle_from``: the lateral drive a cycle run was trained on (``cycle.py``)."""
    from recondreamer.recon import render_trajectory
    from recondreamer.generative.data import (
        scene_structure,
        scene_vanishing_points,
        structure_channel_names,
    )
    from recondreamer.scene.trajectories import trajectory_cam_to_world

    cams = trajectory_cam_to_world(scene.cam_to_world, scene.ego_to_world, trajectory)
    degraded = []
    for step, model in models.items():
        degraded.append(render_trajectory(model, scene, cams))
        LOG.info("pairs %s %s: rendered step %d", run_dir.name, trajectory, step)
    if trajectory == "original":
        gt = scene.images()
        sky = [scene.sky_mask(t) for t in range(scene.num_frames)]
    else:
        gt = np.stack([scene.novel_image(trajectory, t) for t in range(scene.num_frames)])
        sky = [_novel_sky_mask(scene, trajectory, t) for t in range(scene.num_frames)]
        if view is None:
            view = scene.images()
    arrays = {
        "gt": gt,
        "degraded": np.stack(degraded),
        "stages": np.array(list(models)),
        "structure": scene_structure(scene, cams),
        "structure_channels": np.array(structure_channel_names()),
        "vanishing": scene_vanishing_points(scene, cams),
        "scene_id": np.array(scene.scene_id),
        "scene_path": np.array(str(scene.path)),
        "run": np.array(str(run_dir)),
        "trajectory": np.array(trajectory),
    }
    if all(mask is not None for mask in sky):
        arrays["sky"] = np.stack(sky).astype(bool)
    if view is not None:
        arrays["view"] = view
    if cycle_from is not None:
        arrays["cycle_from"] = np.array(cycle_from)
    suffix = "" if trajectory == "original" else f"__{trajectory}"
    out = out_dir / f"{scene.scene_id}__{run_dir.name}{suffix}.npz"
    with atomic_path(out) as tmp, open(tmp, "wb") as handle:
        np.savez_compressed(handle, **arrays)
    return out


def _novel_sky_mask(scene, trajectory: str, t: int) -> np.ndarray | None:  # (H,W) bool
    """Sky pixels of a true novel view, from its semantic labels (None without them)."""
    from recondreamer.scene.types import SEMANTIC_CLASSES

    labels = scene.novel_semantics(trajectory, t)
    return None if labels is None else labels == SEMANTIC_CLASSES.index("sky")
