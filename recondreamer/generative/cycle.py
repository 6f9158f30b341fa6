"""Cycle pairs: the degradation of a reconstruction seen from a lane away, with the recorded frames as truth.

The paper's restoration pairs (``pairs.py``) render the recorded trajectory from under-trained
snapshots: their degradation is the blur of a model that has not converged, not the one DriveRestorer
meets along a novel trajectory (a converged model seen from where it was never trained). A cycle
makes the second kind without any frame of a novel trajectory (Difix3D+ builds training pairs this
way):

1. run A, a reconstruction trained on the recorded frames, renders a lateral drive (e.g. ``shift@3``);
2. run B trains on those renders alone, at the shifted cameras, with the drive's LiDAR depth
   projected into them (what the loop's PDUS updates train on);
3. B renders the recorded trajectory, a lane away from everything it saw, from a snapshot at half
   its iterations and from its final model; those clips pair with the recorded frames.

The pairs file is the ``make-pairs`` format (``pairs.py``) along the recorded trajectory, with
``cycle_from`` naming the lateral drive and ``view`` holding A's renders along it (what B was trained
on at each timestamp, the reference view of a view-conditioned restorer). docs/foundation.md measures
what such pairs are worth at the gate.
"""

from __future__ import annotations

import dataclasses
import logging
import os
from pathlib import Path

from recondreamer.errors import RecondreamerError

LOG = logging.getLogger(__name__)

CYCLE_SOURCE = "cycle"  # the training-view source tag of run B's views


def cycle_snapshot_step(iterations: int) -> int:
    """The step of run B's under-trained snapshot: half its iterations, so each cycle gives one clip of
    a half-trained and one of a converged model (as the snapshot pairs span training)."""
    return max(1, iterations // 2)


def make_cycle_pairs(
    source_run: str | os.PathLike,
    scene_dir: str | os.PathLike,
    trajectory: str,
    cycle_run: str | os.PathLike,
    out_dir: str | os.PathLike,
    config,  # ReconConfig of run B (its snapshot steps are set here)
) -> Path:
    """Run B (``cycle_run``, resumed if present) on run A's (``source_run``) renders along ``trajectory`` (a lateral drive);
    write B's renders of the recorded trajectory, paired with the recorded frames, to ``out_dir``."""
    from recondreamer.generative.pairs import _write_trajectory_pairs
    from recondreamer.recon import load_model, render_trajectory
    from recondreamer.recon.data import TrainingSet, TrainingView, lidar_depth_map
    from recondreamer.recon.trainer import train_scene
    from recondreamer.scene import load_scene
    from recondreamer.scene.trajectories import trajectory_cam_to_world

    if trajectory == "original":
        raise RecondreamerError("--trajectory original: a cycle needs a drive away from the recorded trajectory (e.g. shift@3)")
    source_model = Path(source_run) / "model.pt"
    if not source_model.is_file():
        raise RecondreamerError(f"{source_run}: cycle pairs need the run's final model {source_model}")
    scene = load_scene(scene_dir)
    try:
        cams = trajectory_cam_to_world(scene.cam_to_world, scene.ego_to_world, trajectory)  # (T,4,4)
    except ValueError as error:
        raise RecondreamerError(f"--trajectory {trajectory}: {error}") from error
    renders = render_trajectory(load_model(source_model), scene, cams)  # (T,H,W,3) uint8
    LOG.info("cycle %s %s: run A rendered the lateral drive", scene.scene_id, trajectory)
    views = [
        TrainingView(
            cam_to_world=cam, timestamp=float(scene.timestamps[t]), image=renders[t],
            depth=lidar_depth_map(scene.lidar(t), scene.K, cam, scene.width, scene.height), source=CYCLE_SOURCE, frame=t,
        )
        for t, cam in enumerate(cams)
    ]
    snapshot = cycle_snapshot_step(config.iterations)
    config = dataclasses.replace(config, snapshot_steps=(snapshot,))
    cycle_run = Path(cycle_run)
    final = train_scene(scene, config, cycle_run, training_set=TrainingSet(scene.K, scene.width, scene.height, views))
    models = {snapshot: load_model(cycle_run / "snapshots" / f"step_{snapshot:06d}.pt"), config.iterations: final}
    return _write_trajectory_pairs(cycle_run, scene, "original", models, Path(out_dir), view=renders, cycle_from=trajectory)
