"""Reading a directory of rendered frames of one trajectory, with clear errors.

A render directory holds one image per frame named by its frame index (``000.png``, ``1.jpg``,
...; PNG or JPEG); every frame 0..T-1 of the scene must be there, at the scene's image size.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from recondreamer.errors import RecondreamerError

RENDER_SUFFIXES = (".png", ".jpg", ".jpeg")


class RenderError(RecondreamerError):
    """A render directory is missing frames or holds frames of the wrong size or format."""


def render_files(directory: str | Path, num_frames: int) -> list[Path]:
    """The files of frames 0..num_frames-1 in ``directory``; RenderError naming what is missing."""
    directory = Path(directory)
    if not directory.is_dir():
        raise RenderError(f"render directory {directory} does not exist")
    by_index: dict[int, Path] = {}
    for path in sorted(directory.iterdir()):
        if path.suffix.lower() not in RENDER_SUFFIXES or not path.stem.isdigit():
            continue
        index = int(path.stem)
        if index in by_index:
            raise RenderError(f"{path}: frame {index} is given twice (also {by_index[index].name})")
        by_index[index] = path
    missing = [t for t in range(num_frames) if t not in by_index]
    if missing:
        shown = ", ".join(str(directory / f"{t:03d}.png") for t in missing[:3])
        more = f" and {len(missing) - 3} more" if len(missing) > 3 else ""
        raise RenderError(f"render directory {directory} lacks {len(missing)} of {num_frames} frames: {shown}{more} (PNG or JPEG)")
    extra = sorted(t for t in by_index if t >= num_frames)
    if extra:
        raise RenderError(f"{by_index[extra[0]]}: frame {extra[0]} is beyond the scene's {num_frames} frames")
    return [by_index[t] for t in range(num_frames)]


def read_frame(path: Path, width: int, height: int) -> np.ndarray:  # -> (H,W,3) uint8
    try:
        with Image.open(path) as image:
            size = image.size
            if size != (width, height):
                raise RenderError(f"{path}: frame is {size[0]}x{size[1]}, the scene's images are {width}x{height}")
            return np.asarray(image.convert("RGB"))
    except RenderError:
        raise
    except Exception as error:  # PIL raises several types for unreadable files
        raise RenderError(f"{path}: not a readable image ({error})") from None


def load_render_frames(directory: str | Path, num_frames: int, width: int, height: int) -> np.ndarray:  # (T,H,W,3) uint8
    return np.stack([read_frame(path, width, height) for path in render_files(directory, num_frames)])
