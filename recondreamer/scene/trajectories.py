"""Novel camera trajectories, as the public ReconDreamer / DriveDreamer4D code defines them.

Names:

- ``original``: the recorded cameras;
- ``shift@Y``: every camera moved by a constant Y metres along its frame's ego left axis
  (``ego_to_world[t, :3, 1]``), orientation unchanged; any real Y, negative = to the right;
- ``lane_change``: a linear drift to the left that reaches the neighbouring lane, 3.9 m, at the
  last frame (frame i of T moved 3.9*i/(T-1) metres: the public code's 0.1 m per frame on the
  paper's 40-frame clips, and still a full lane on shorter clips), orientation unchanged;
- ``file:PATH``: camera-to-world poses read from a ``.npy`` array or a ``.json`` list of shape
  (T,4,4), T = number of frames of the scene.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

EVAL_TRAJECTORIES = ("shift@3", "shift@6", "lane_change")
LANE_CHANGE_METRES = 3.9  # lateral offset at the last frame: 0.1 m per frame over 40 frames


@dataclass(frozen=True)
class TrajectorySpec:
    """A parsed trajectory name."""

    name: str
    kind: str  # "original" | "shift" | "lane_change" | "file"
    offset: float = 0.0  # metres to the left, for "shift"
    path: Path | None = None  # for "file"


def parse_trajectory(name: str) -> TrajectorySpec:
    """Parse a trajectory name; ValueError naming the accepted forms for anything else."""
    accepted = "expected 'original', 'shift@Y' (Y metres to the left, e.g. shift@3 or shift@-1.5), 'lane_change' or 'file:PATH'"
    if not isinstance(name, str):
        raise ValueError(f"trajectory name must be a string, got {name!r}; {accepted}")
    if name == "original":
        return TrajectorySpec(name, "original")
    if name == "lane_change":
        return TrajectorySpec(name, "lane_change")
    if name.startswith("shift@"):
        text = name[len("shift@") :]
        try:
            offset = float(text)
        except ValueError:
            raise ValueError(f"unknown trajectory {name!r}: {text!r} is not a number of metres; {accepted}") from None
        if not math.isfinite(offset):
            raise ValueError(f"unknown trajectory {name!r}: the shift must be a finite number of metres")
        return TrajectorySpec(name, "shift", offset=offset)
    if name.startswith("file:") and len(name) > len("file:"):
        return TrajectorySpec(name, "file", path=Path(name[len("file:") :]))
    raise ValueError(f"unknown trajectory {name!r}; {accepted}")


def lateral_offsets(name: str, num_frames: int) -> np.ndarray:  # (T,) float64 metres to the left
    """Per-frame lateral offset of a named trajectory (not defined for ``file:`` trajectories)."""
    spec = parse_trajectory(name)
    frames = np.arange(num_frames, dtype=np.float64)
    if spec.kind == "original":
        return np.zeros(num_frames)
    if spec.kind == "shift":
        return np.full(num_frames, spec.offset)
    if spec.kind == "lane_change":
        return LANE_CHANGE_METRES * frames / max(num_frames - 1, 1)
    raise ValueError(f"trajectory {name!r} is read from a file of poses and has no lateral offsets")


def load_pose_file(path: str | Path, num_frames: int) -> np.ndarray:  # (T,4,4)
    """Read (T,4,4) camera-to-world poses from ``.npy`` or ``.json`` and check them."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"trajectory file {path} does not exist")
    try:
        if path.suffix == ".npy":
            with open(path, "rb") as handle:
                if handle.read(6) != b"\x93NUMPY":  # else numpy takes the bytes for a pickle and refuses it as one
                    raise ValueError(f"trajectory file {path}: not a .npy file (it does not start with the .npy magic bytes)")
            try:
                poses = np.load(path, allow_pickle=False)
            except ValueError as error:  # a cut-short or object array
                raise ValueError(f"trajectory file {path}: cannot be read ({error})") from None
        elif path.suffix == ".json":
            poses = json.loads(path.read_text())
            if isinstance(poses, dict) and "cam_to_world" in poses:
                poses = poses["cam_to_world"]
        else:
            raise ValueError(f"trajectory file {path}: expected a .npy or .json file")
        poses = np.asarray(poses, dtype=np.float64)
    except (OSError, json.JSONDecodeError, TypeError) as error:
        raise ValueError(f"trajectory file {path}: cannot be read ({error})") from None
    if poses.shape != (num_frames, 4, 4):
        raise ValueError(
            f"trajectory file {path}: expected ({num_frames}, 4, 4) camera-to-world poses, got shape {poses.shape}"
        )
    if not np.all(np.isfinite(poses)):
        raise ValueError(f"trajectory file {path}: poses contain non-finite values")
    rotations = poses[:, :3, :3]
    gram_error = np.abs(np.einsum("tji,tjk->tik", rotations, rotations) - np.eye(3)).max(axis=(1, 2))
    bad = np.flatnonzero((gram_error > 1e-4) | (np.linalg.det(rotations) < 0))
    if bad.size:
        raise ValueError(f"trajectory file {path}: pose {bad[0]} has a rotation that is not orthonormal with det +1")
    if np.abs(poses[:, 3] - np.array([0.0, 0.0, 0.0, 1.0])).max() > 1e-9:
        raise ValueError(f"trajectory file {path}: the last row of every pose must be [0, 0, 0, 1]")
    return poses


def trajectory_cam_to_world(
    cam_to_world: np.ndarray,  # (T,4,4) recorded cameras
    ego_to_world: np.ndarray,  # (T,4,4)
    name: str,
) -> np.ndarray:  # (T,4,4)
    """Camera-to-world poses of the named trajectory."""
    cam_to_world = np.asarray(cam_to_world, dtype=np.float64)
    ego_to_world = np.asarray(ego_to_world, dtype=np.float64)
    if cam_to_world.ndim != 3 or cam_to_world.shape[1:] != (4, 4) or ego_to_world.shape != cam_to_world.shape:
        raise ValueError(
            f"cam_to_world and ego_to_world must both be (T,4,4), got {cam_to_world.shape} and {ego_to_world.shape}"
        )
    spec = parse_trajectory(name)
    num_frames = len(cam_to_world)
    if spec.kind == "file":
        return load_pose_file(spec.path, num_frames)
    moved = cam_to_world.copy()
    offsets = lateral_offsets(name, num_frames)  # (T,)
    moved[:, :3, 3] += offsets[:, None] * ego_to_world[:, :3, 1]
    return moved
