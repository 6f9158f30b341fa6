"""Restoration pairs (paper Fig. 3): renders of the original trajectory by under-trained
reconstructions at several training stages, paired with the ground-truth frames.

One compressed ``.npz`` per run: ``gt`` (T,H,W,3) uint8, ``degraded`` (K,T,H,W,3) uint8 (one clip
per stage), ``stages`` (K,) training steps, ``structure`` (T,C,H,W) uint8 structure maps of the
original cameras (x255), ``structure_channels`` their names, ``vanishing`` (T,2) the ego-forward
vanishing point per frame, optional ``sky`` (T,H,W) bool ground-truth sky masks, and the
``scene_id`` / ``run`` / ``scene_path`` they came from.
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


def make_pairs_for_run(run_dir: str | os.PathLike, out_dir: str | os.PathLike, num_stages: int, scene_dir: str | os.PathLike | None = None) -> Path:
    """Render the original trajectory from each selected snapshot of one run; write one .npz."""
    from recondreamer.recon import load_model, render_trajectory
    from recondreamer.restorer.data import scene_sky_masks, scene_structure, scene_vanishing_points, structure_channel_names
    from recondreamer.scene import load_scene

    run_dir = Path(run_dir)
    snapshots = sorted((run_dir / "snapshots").glob("step_*.pt"))
    if not snapshots:
        raise RecondreamerError(f"{run_dir}: no training-stage snapshots (snapshots/step_*.pt)")
    scene = load_scene(scene_dir if scene_dir is not None else run_scene_path(run_dir))
    chosen = select_stages(snapshots, num_stages)
    degraded = []
    for snapshot in chosen:
        model = load_model(snapshot)
        degraded.append(render_trajectory(model, scene, scene.cam_to_world))
        LOG.info("pairs %s: rendered %s", run_dir.name, snapshot.name)
    arrays = {
        "gt": np.stack([scene.image(t) for t in range(scene.num_frames)]),
        "degraded": np.stack(degraded),
        "stages": np.array([int(p.stem.split("_")[1]) for p in chosen]),
        "structure": scene_structure(scene, scene.cam_to_world),
        "structure_channels": np.array(structure_channel_names()),
        "vanishing": scene_vanishing_points(scene, scene.cam_to_world),
        "scene_id": np.array(scene.scene_id),
        "scene_path": np.array(str(scene.path)),
        "run": np.array(str(run_dir)),
    }
    sky = scene_sky_masks(scene)
    if sky is not None:
        arrays["sky"] = sky
    out = Path(out_dir) / f"{scene.scene_id}__{run_dir.name}.npz"
    with atomic_path(out) as tmp, open(tmp, "wb") as handle:
        np.savez_compressed(handle, **arrays)
    return out
