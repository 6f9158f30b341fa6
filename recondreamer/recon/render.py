"""Rendering a trained model along a camera trajectory, in memory or to a directory of frames."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from recondreamer.errors import RecondreamerError
from recondreamer.io import atomic_directory
from recondreamer.recon.base import GaussianSceneModel
from recondreamer.scene.trajectories import trajectory_cam_to_world

log = logging.getLogger(__name__)


def render_frames(
    model: GaussianSceneModel, scene, cam_to_world: np.ndarray, backend: str = "auto"
) -> tuple[np.ndarray, np.ndarray]:
    """RGB (T,H,W,3) uint8 and expected depth (T,H,W) float32 of frame t's camera at frame t's time."""
    cam_to_world = np.asarray(cam_to_world, dtype=np.float64)
    if cam_to_world.shape != (scene.num_frames, 4, 4):
        raise ValueError(
            f"cam_to_world must have shape ({scene.num_frames},4,4), got {cam_to_world.shape}"
        )
    images = np.zeros((scene.num_frames, scene.height, scene.width, 3), dtype=np.uint8)
    depths = np.zeros((scene.num_frames, scene.height, scene.width), dtype=np.float32)
    model.eval()
    with torch.no_grad():
        for t in range(scene.num_frames):
            out = model.render(
                cam_to_world[t],
                float(scene.timestamps[t]),
                scene.K,
                scene.width,
                scene.height,
                backend=backend,
            )
            images[t] = (
                np.round(out["rgb"].cpu().numpy() * 255.0).clip(0, 255).astype(np.uint8)
            )
            depths[t] = out["depth"].cpu().numpy()
    return images, depths


def render_trajectory(
    model: GaussianSceneModel, scene, cam_to_world: np.ndarray, backend: str = "auto"
) -> np.ndarray:
    """RGB renders (T,H,W,3) uint8 of a (T,4,4) camera-to-world trajectory over the scene's frames."""
    return render_frames(model, scene, cam_to_world, backend)[0]


def write_frames(
    out_dir: str | Path, images: np.ndarray, depths: np.ndarray | None = None
) -> Path:
    """Write ``{t:03d}.png`` (and ``{t:03d}_depth.npy``) into ``out_dir`` as one atomic directory."""
    with atomic_directory(out_dir, "renders") as tmp:
        for t, image in enumerate(images):
            Image.fromarray(image).save(tmp / f"{t:03d}.png")
            if depths is not None:
                np.save(tmp / f"{t:03d}_depth.npy", depths[t].astype(np.float32))
    return Path(out_dir)


def render_to_directories(
    model: GaussianSceneModel, scene, outputs: Sequence[tuple[str, str | Path]], backend: str = "auto"
) -> None:
    """Render each (trajectory name, directory) pair: original, shift@Y, lane_change or file:PATH.

    Every trajectory is resolved before the first frame is rendered, so a bad name leaves no
    directory written.
    """
    poses = []
    for trajectory, _ in outputs:
        try:
            poses.append(trajectory_cam_to_world(scene.cam_to_world, scene.ego_to_world, trajectory))
        except ValueError as error:
            raise RecondreamerError(f"--trajectory {trajectory}: {error}") from None
    for (trajectory, out_dir), cam_to_world in zip(outputs, poses):
        images, depths = render_frames(model, scene, cam_to_world, backend)
        write_frames(out_dir, images, depths)
        log.info("rendered %d frames of %s to %s", len(images), trajectory, out_dir)
