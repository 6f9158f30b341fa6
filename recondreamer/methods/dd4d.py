"""DriveDreamer4D baseline: novel-trajectory videos generated once by a pretrained world model.

The dd2 world model (not fine-tuned on restoration pairs) generates each novel trajectory from
the original frames (reference) and the 3D boxes and HD map projected into the novel cameras
(``generate_clip``), as DriveDreamer4D does, once before training. The reconstruction then trains
on original + generated data, 50/50, depth-free on the generated frames, with no updates.
Generated videos are saved as ``RUN/generated/<trajectory>/`` (atomic) and reused on resume.

The workflow generates each segment's videos once with ``recondreamer dd4d-generate`` (one folder
of frames per trajectory) and every backbone's run reads them (``load_generated_videos``): the
generation depends on the segment and the world model only, not on the reconstruction backbone.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import numpy as np

from recondreamer.errors import RecondreamerError
from recondreamer.methods.novel import NovelVideo, load_video, save_video
from recondreamer.recon.config import ReconConfig
from recondreamer.recon.data import ORIGINAL, TrainingSet
from recondreamer.scene.trajectories import lateral_offsets, trajectory_cam_to_world

logger = logging.getLogger("recondreamer.recon.dd4d")

GENERATED_DIR = "generated"
# DriveDreamer4D's novel trajectories: lane shifts of one and two lanes and a lane change.
DD4D_TRAJECTORIES = ("shift@3", "shift@6", "lane_change")


def generate_videos(scene, world_model, run_dir: str | Path | None,
                    trajectories: tuple[str, ...] = DD4D_TRAJECTORIES, num_steps: int | None = None,
                    seed: int = 0) -> list[NovelVideo]:
    """One generated video per trajectory (reused from ``RUN/generated/`` when already there)."""
    from recondreamer.generative.data import scene_structure
    from recondreamer.generative.inference import generate_clip

    reference = np.stack([np.asarray(scene.image(t)) for t in range(scene.num_frames)])  # (T,H,W,3)
    videos = []
    for index, name in enumerate(trajectories):
        folder = Path(run_dir) / GENERATED_DIR / name if run_dir is not None else None
        if folder is not None and folder.is_dir():
            videos.append(load_video(folder, reference.shape))
            logger.info("dd4d: %s reloaded from %s", name, folder)
            continue
        try:
            poses = trajectory_cam_to_world(scene.cam_to_world, scene.ego_to_world, name)
        except ValueError as error:
            raise RecondreamerError(f"--trajectories: {error}") from None
        started = time.monotonic()
        structure = scene_structure(scene, poses)  # (T,C,H,W) uint8 in the novel cameras
        generated = generate_clip(world_model, reference, structure, num_steps=num_steps, seed=seed + index)
        offsets = lateral_offsets(name, scene.num_frames) if not name.startswith("file:") else None
        video = NovelVideo(
            source=f"dd4d:{name}", poses=poses, timestamps=np.asarray(scene.timestamps, dtype=np.float64),
            frames=generated,
            info={"trajectory": name, "offset_m": None if offsets is None else float(np.max(np.abs(offsets))),
                  "seconds": round(time.monotonic() - started, 2)},
        )
        if folder is not None:
            save_video(folder, video, reference)
        logger.info("dd4d: generated %s (%d frames) in %.1f s", name, len(generated), video.info["seconds"])
        videos.append(video)
    return videos


def load_generated_videos(scene, generated_dir: str | Path, trajectories: tuple[str, ...]) -> list[NovelVideo]:
    """Videos written by ``recondreamer dd4d-generate`` as ``generated_dir/<trajectory>/NNN.png``.

    Poses follow from the trajectory name, as in ``generate_videos``; the folder's ``info.json``
    must name this scene, so that a video of another segment is refused rather than trained on.
    """
    from recondreamer.frames_io import read_frame_folder

    videos = []
    for name in trajectories:
        folder = Path(generated_dir) / name
        if not folder.is_dir():
            raise RecondreamerError(f"--generated: {folder} is missing; generate it with "
                                    f"'recondreamer dd4d-generate --trajectory {name} --out {folder} ...'")
        info_path = folder / "info.json"
        info = json.loads(info_path.read_text()) if info_path.is_file() else {}
        if info.get("scene_id", scene.scene_id) != scene.scene_id or info.get("trajectory", name) != name:
            raise RecondreamerError(f"{info_path}: generated for scene {info.get('scene_id')!r} along "
                                    f"{info.get('trajectory')!r}, not scene {scene.scene_id!r} along {name!r}")
        frames = read_frame_folder(folder)  # (T,H,W,3) uint8
        expected = (scene.num_frames, scene.height, scene.width, 3)
        if frames.shape != expected:
            raise RecondreamerError(f"{folder}: frames {frames.shape} do not fit the scene's {expected} (T,H,W,3)")
        try:
            poses = trajectory_cam_to_world(scene.cam_to_world, scene.ego_to_world, name)
        except ValueError as error:
            raise RecondreamerError(f"--trajectories: {error}") from None
        offsets = lateral_offsets(name, scene.num_frames) if not name.startswith("file:") else None
        videos.append(NovelVideo(
            source=f"dd4d:{name}", poses=poses, timestamps=np.asarray(scene.timestamps, dtype=np.float64), frames=frames,
            info={"trajectory": name, "offset_m": None if offsets is None else float(np.max(np.abs(offsets))),
                  "generated": str(folder)},
        ))
        logger.info("dd4d: %s read from %s", name, folder)
    return videos


def dd4d_training_set(scene, videos: list[NovelVideo], novel_fraction: float = 0.5) -> TrainingSet:
    """Original views (with depth) + generated views (depth-free), mixed 50/50, videos equally weighted."""
    training_set = TrainingSet.from_scene(scene)
    for video in videos:
        training_set.extend(video.views())
    if not videos:
        raise RecondreamerError("DriveDreamer4D needs at least one generated trajectory")
    training_set.set_source_weight(ORIGINAL, 1.0 - novel_fraction)
    for video in videos:
        training_set.set_source_weight(video.source, novel_fraction / len(videos))
    return training_set


def train_dd4d(scene, config: ReconConfig, run_dir: str | Path | None, world_model,
               trajectories: tuple[str, ...] = DD4D_TRAJECTORIES, num_steps: int | None = None,
               generated_dir: str | Path | None = None):
    """Generate once (or read ``generated_dir``), then train on original + generated data; returns the model."""
    from recondreamer.recon.trainer import train_scene

    if generated_dir is not None:
        videos = load_generated_videos(scene, generated_dir, trajectories)
    else:
        videos = generate_videos(scene, world_model, run_dir, trajectories, num_steps, config.seed)
    return train_scene(scene, config, run_dir, training_set=dd4d_training_set(scene, videos))
