"""Clips as folders of numbered frames: the one reader and writer of every stage.

A frame folder holds one image per frame named by its frame index (``000.png``, ``1.jpg``, ...;
PNG or JPEG), frames 0..T-1 with none missing, all of one size. Renders, restored and generated
clips and the study page's videos are all read through ``read_frame_folder``; the restorer's
commands also take a ``.npy`` clip (``read_clip``).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from recondreamer.errors import RecondreamerError
from recondreamer.image_codec import decode_rgb, encode_rgb
from recondreamer.io import atomic_directory, write_json_atomic

FRAME_SUFFIXES = (".png", ".jpg", ".jpeg")


class FrameError(RecondreamerError):
    """A frame folder is missing frames or holds frames of the wrong size or format."""


def frame_files(directory: str | Path, num_frames: int | None = None) -> list[Path]:
    """The files of frames 0..T-1 in ``directory``: T = ``num_frames``, or as many as are numbered
    from 0 without a gap; FrameError naming what is missing or extra."""
    directory = Path(directory)
    if not directory.is_dir():
        raise FrameError(f"frame folder {directory} does not exist")
    by_index: dict[int, Path] = {}
    for path in sorted(directory.iterdir()):
        if path.suffix.lower() not in FRAME_SUFFIXES or not path.stem.isdigit():
            continue
        index = int(path.stem)
        if index in by_index:
            raise FrameError(f"{path}: frame {index} is given twice (also {by_index[index].name})")
        by_index[index] = path
    if num_frames is None:
        if not by_index:
            raise FrameError(f"frame folder {directory} holds no numbered frames ({', '.join(FRAME_SUFFIXES)})")
        num_frames = max(by_index) + 1
    missing = [t for t in range(num_frames) if t not in by_index]
    if missing:
        shown = ", ".join(str(directory / f"{t:03d}.png") for t in missing[:3])
        more = f" and {len(missing) - 3} more" if len(missing) > 3 else ""
        raise FrameError(f"frame folder {directory} lacks {len(missing)} of {num_frames} frames: {shown}{more} (PNG or JPEG)")
    extra = sorted(t for t in by_index if t >= num_frames)
    if extra:
        raise FrameError(f"{by_index[extra[0]]}: frame {extra[0]} is beyond the scene's {num_frames} frames")
    return [by_index[t] for t in range(num_frames)]


def read_frame(path: Path, size: tuple[int, int] | None = None) -> np.ndarray:  # size (W,H) -> (H,W,3) uint8
    try:
        data = Path(path).read_bytes()
    except OSError as error:
        raise FrameError(f"{path}: not a readable image ({error})") from None
    frame = decode_rgb(data)
    if frame is None:
        raise FrameError(f"{path}: not a readable image (not a PNG or JPEG OpenCV can decode; {len(data)} bytes)")
    if size is not None and (frame.shape[1], frame.shape[0]) != tuple(size):
        raise FrameError(f"{path}: frame is {frame.shape[1]}x{frame.shape[0]}, expected {size[0]}x{size[1]}")
    return frame


def read_frame_folder(directory: str | Path, num_frames: int | None = None, size: tuple[int, int] | None = None) -> np.ndarray:
    """Frames 0..T-1 of a folder as (T,H,W,3) uint8 (``frame_files``), each ``size`` (W,H) or all
    the size of the first."""
    files = frame_files(directory, num_frames)
    first = read_frame(files[0], size)
    size = (first.shape[1], first.shape[0])
    return np.stack([first] + [read_frame(path, size) for path in files[1:]])


def read_clip(path: str | os.PathLike, trajectory: str | None = None) -> np.ndarray:  # (T,H,W,3) uint8
    """A clip: a .npy (T,H,W,3) uint8 array or a frame folder; for a folder that has a sub-folder
    named after ``trajectory``, that sub-folder."""
    path = Path(path)
    if path.is_file() and path.suffix == ".npy":
        try:
            frames = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as error:  # cut short, or not an .npy file at all
            raise RecondreamerError(f"{path}: not a readable .npy clip ({error})") from None
        if frames.dtype != np.uint8 or frames.ndim != 4 or frames.shape[-1] != 3:
            raise RecondreamerError(f"{path}: expected a (T,H,W,3) uint8 array, got {frames.dtype} {frames.shape}")
        return frames
    if not path.is_dir():
        raise RecondreamerError(f"{path}: renders must be a folder of frames or a .npy clip")
    if trajectory is not None and (path / trajectory).is_dir():
        path = path / trajectory
    return read_frame_folder(path)


def write_frames(path: str | os.PathLike, frames: np.ndarray, info: dict | None = None) -> None:
    """Write ``{t:03d}.png`` frames (and ``info.json``) into a folder, atomically."""
    with atomic_directory(path, "frames") as tmp:
        for t, frame in enumerate(frames):
            (tmp / f"{t:03d}.png").write_bytes(encode_rgb(frame, "png"))
        if info is not None:
            write_json_atomic(tmp / "info.json", info)
