"""Reading and writing clips as folders of numbered PNG frames (the restorer's file interface)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from PIL import Image

from recondreamer.errors import RecondreamerError
from recondreamer.io import atomic_directory, write_json_atomic

FRAME_SUFFIXES = (".png", ".jpg", ".jpeg")


def read_frames(path: str | os.PathLike, trajectory: str | None = None) -> np.ndarray:  # (T,H,W,3) uint8
    """Frames of a clip: a .npy (T,H,W,3) uint8 array, or a folder of images sorted by name.

    For a folder that has a sub-folder named after ``trajectory``, that sub-folder is read.
    """
    path = Path(path)
    if path.is_file() and path.suffix == ".npy":
        frames = np.load(path)
        if frames.dtype != np.uint8 or frames.ndim != 4 or frames.shape[-1] != 3:
            raise RecondreamerError(f"{path}: expected a (T,H,W,3) uint8 array, got {frames.dtype} {frames.shape}")
        return frames
    if not path.is_dir():
        raise RecondreamerError(f"{path}: renders must be a folder of frames or a .npy clip")
    if trajectory is not None and (path / trajectory).is_dir():
        path = path / trajectory
    files = sorted(p for p in path.iterdir() if p.suffix.lower() in FRAME_SUFFIXES)
    if not files:
        raise RecondreamerError(f"{path}: no frames ({', '.join(FRAME_SUFFIXES)}) found")
    frames = []
    for file in files:
        with Image.open(file) as image:
            frames.append(np.asarray(image.convert("RGB")))
    sizes = {f.shape for f in frames}
    if len(sizes) != 1:
        raise RecondreamerError(f"{path}: frames have different sizes {sorted(sizes)}")
    return np.stack(frames)


def write_frames(path: str | os.PathLike, frames: np.ndarray, info: dict | None = None) -> None:
    """Write ``{t:03d}.png`` frames (and ``info.json``) into a folder, atomically."""
    with atomic_directory(path, "frames") as tmp:
        for t, frame in enumerate(frames):
            Image.fromarray(frame).save(tmp / f"{t:03d}.png", compress_level=1)
        if info is not None:
            write_json_atomic(tmp / "info.json", info)
