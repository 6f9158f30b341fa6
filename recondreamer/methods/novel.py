"""Novel-trajectory videos on disk and as depth-free training views.

A video folder (one PDUS update, or one DriveDreamer4D generation) holds::

    frames.npz        poses (T,4,4), timestamps (T,), supervised (T,H,W,3) uint8: every frame, for
                      training and resume
    rendered/NNN.png  a few frames of what went into the generative model (PDUS: the render)
    restored/NNN.png  the same frames of what came out (PDUS: restored; DD4D: generated)
    update.json       what the video is (offset_m, step, source tag, ...)

It is written as one atomic directory, so after a kill it is either complete or absent.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from recondreamer.errors import RecondreamerError
from recondreamer.io import atomic_directory, write_json_atomic
from recondreamer.recon.data import TrainingView

FRAMES_FILE = "frames.npz"
INFO_FILE = "update.json"


@dataclass
class NovelVideo:
    """Supervision along one novel trajectory: one frame per scene frame."""

    source: str  # training-set tag, e.g. "pdus2@3m"
    poses: np.ndarray  # (T,4,4) camera-to-world
    timestamps: np.ndarray  # (T,)
    frames: np.ndarray  # (T,H,W,3) uint8 restored or generated frames
    info: dict  # written to update.json; holds at least offset_m

    def views(self) -> list[TrainingView]:
        """Depth-free, sky-mask-free views: generated frames get RGB + SSIM only (paper eq. L_novel)."""
        return [
            TrainingView(cam_to_world=np.asarray(pose, dtype=np.float64), timestamp=float(stamp), image=frame,
                         depth=None, sky_mask=None, source=self.source, weight=1.0, frame=t)
            for t, (pose, stamp, frame) in enumerate(zip(self.poses, self.timestamps, self.frames))
        ]


def preview_indices(num_frames: int, count: int) -> list[int]:
    """``count`` frames spread over the clip (first, middle, last for 3)."""
    spread = np.rint(np.linspace(0, num_frames - 1, max(1, min(count, num_frames)))).astype(int)
    return sorted({int(i) for i in spread})


def save_video(folder: str | Path, video: NovelVideo, inputs: np.ndarray, preview: int = 3) -> Path:
    """Write the video folder atomically; ``inputs`` (T,H,W,3) are what the model was given."""
    folder = Path(folder)
    with atomic_directory(folder, "novel-trajectory video") as tmp:
        np.savez(tmp / FRAMES_FILE, poses=video.poses, timestamps=video.timestamps, supervised=video.frames)
        (tmp / "rendered").mkdir()
        (tmp / "restored").mkdir()
        shown = preview_indices(len(video.frames), preview)
        for t in shown:
            Image.fromarray(inputs[t]).save(tmp / "rendered" / f"{t:03d}.png")
            Image.fromarray(video.frames[t]).save(tmp / "restored" / f"{t:03d}.png")
        write_json_atomic(tmp / INFO_FILE, {**video.info, "source": video.source, "preview_frames": shown})
    return folder


def load_video(folder: str | Path, expected_shape: tuple[int, int, int, int]) -> NovelVideo:
    """Read a video folder back; ``expected_shape`` (T,H,W,3) guards against a different scene."""
    folder = Path(folder)
    try:
        info = json.loads((folder / INFO_FILE).read_text())
        with np.load(folder / FRAMES_FILE) as data:
            poses, timestamps, frames = data["poses"], data["timestamps"], data["supervised"]
    except (OSError, KeyError, ValueError) as error:
        raise RecondreamerError(f"{folder}: unreadable novel-video folder ({error}); delete it to regenerate") from None
    if frames.shape != tuple(expected_shape) or frames.dtype != np.uint8 or poses.shape != (expected_shape[0], 4, 4):
        raise RecondreamerError(
            f"{folder / FRAMES_FILE}: frames {frames.shape} {frames.dtype} do not fit this scene {tuple(expected_shape)}; "
            "it belongs to another run: choose another --out directory or delete it"
        )
    return NovelVideo(source=info["source"], poses=poses, timestamps=timestamps, frames=frames, info=info)
