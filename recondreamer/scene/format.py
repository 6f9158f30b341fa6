"""The scene directory: atomic writing, validation on load, lazy per-frame reading.

One directory per segment, plain files only (JSON, PNG/JPEG, ``.npy``), so that any tool can
read it; ``docs/scene-format.md`` documents every file. ``load_scene`` parses the small JSON
files completely and checks that every per-frame file exists with the right image size or
array shape by reading file headers only; pixel and point data are read when a frame is asked
for (and checked then). ``Scene.check_all()`` decodes everything (``recondreamer validate``).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
from PIL import Image

from recondreamer.errors import SceneFormatError
from recondreamer.image_codec import decode_rgb, encode_rgb
from recondreamer.io import OUTPUT_MARKER, atomic_directory
from recondreamer.scene import trajectories
from recondreamer.scene.types import (
    BOX_LABELS,
    POLYLINE_KINDS,
    SEMANTIC_CLASSES,
    Box,
    FrameChannels,
    Polyline,
    SceneData,
)

FORMAT_VERSION = 1
SUPPORTED_FORMAT_VERSIONS = (1,)
SCENE_FILE = "scene.json"
BOXES_FILE = "boxes.json"
MAP_FILE = "map.json"
IMAGE_SUFFIXES = {"png": ".png", "jpg": ".jpg"}
# Optional per-frame channels: directory name = channel name; file suffix and accepted PIL modes.
CHANNEL_SUFFIXES = {"depth": ".npy", "semantics": ".png", "instances": ".png", "sky_masks": ".png"}
CHANNEL_PNG_MODES = {"semantics": ("L",), "instances": ("I;16", "I;16B", "I"), "sky_masks": ("L", "1")}
ROTATION_TOLERANCE = 1e-4  # max |R^T R - I| entry; float32 round trips stay far below it
PNG_COMPRESS_LEVEL = 1  # fast; the scene writer sits inside the synthetic 30 s budget


def _fail(file: Path | str, problem: str) -> NoReturn:
    raise SceneFormatError(f"{file}: {problem}")


# ----------------------------------------------------------------------------------------------
# Checks shared by the JSON parser and the per-frame readers
# ----------------------------------------------------------------------------------------------


def _array(value: Any, shape: tuple[int, ...], file: Path, what: str) -> np.ndarray:
    """A finite float64 array of the given shape (-1 = any length) or a SceneFormatError."""
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        _fail(file, f"{what}: not a numeric array")
    if array.ndim != len(shape) or any(want not in (-1, got) for want, got in zip(shape, array.shape, strict=True)):
        wanted = "(" + ", ".join("N" if s == -1 else str(s) for s in shape) + ")"
        _fail(file, f"{what}: expected shape {wanted}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        _fail(file, f"{what}: non-finite values (NaN or infinity)")
    return array


def _check_rigid(matrix: np.ndarray, file: Path, what: str) -> None:
    """A (4,4) rigid transform: orthonormal rotation with det +1, last row 0 0 0 1."""
    if np.abs(matrix[3] - np.array([0.0, 0.0, 0.0, 1.0])).max() > 1e-9:
        _fail(file, f"{what}: last row must be [0, 0, 0, 1], got {matrix[3].tolist()}")
    rotation = matrix[:3, :3]
    error = np.abs(rotation.T @ rotation - np.eye(3)).max()
    if error > ROTATION_TOLERANCE or np.linalg.det(rotation) <= 0:
        _fail(
            file,
            f"{what}: rotation is not orthonormal with det +1 (max |R^T R - I| = {error:.2e}, det = {np.linalg.det(rotation):.4f})",
        )


def _field(obj: Any, key: str, file: Path, kind: type | tuple[type, ...], where: str = "") -> Any:
    if not isinstance(obj, dict) or key not in obj:
        _fail(file, f"missing field '{where}{key}'")
    value = obj[key]
    kinds = kind if isinstance(kind, tuple) else (kind,)
    # bool is an int subclass in Python; JSON true/false is never a valid number here.
    if not isinstance(value, kinds) or isinstance(value, bool):
        names = "/".join(k.__name__ for k in kinds)
        _fail(file, f"field '{where}{key}' must be {names}, got {type(value).__name__}")
    return value


def _read_json(file: Path) -> Any:
    if not file.is_file():
        _fail(file, "missing file")
    try:
        return json.loads(file.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        _fail(file, f"not valid JSON ({error})")


def _image_header(file: Path, modes: tuple[str, ...], width: int, height: int) -> None:
    """Check an image file's size and pixel mode from its header (no pixel decoding)."""
    if not file.is_file():
        _fail(file, "missing file")
    try:
        with Image.open(file) as image:
            size, mode = image.size, image.mode
    except (OSError, SyntaxError) as error:
        _fail(file, f"not a readable image ({error})")
    if size != (width, height):
        _fail(file, f"wrong image size {size[0]}x{size[1]}, the scene is {width}x{height}")
    if mode not in modes:
        _fail(file, f"wrong pixel mode {mode!r}, expected one of {modes}")


def _npy_header(file: Path) -> tuple[tuple[int, ...], np.dtype]:
    """Shape and dtype of a .npy file from its header (no data read)."""
    if not file.is_file():
        _fail(file, "missing file")
    try:
        with open(file, "rb") as handle:
            version = np.lib.format.read_magic(handle)
            if version == (1, 0):
                shape, _, dtype = np.lib.format.read_array_header_1_0(handle)
            else:
                shape, _, dtype = np.lib.format.read_array_header_2_0(handle)
    except (OSError, ValueError) as error:
        _fail(file, f"not a readable .npy file ({error})")
    return shape, dtype


def _load_npy(file: Path) -> np.ndarray:
    try:
        return np.load(file, allow_pickle=False)
    except (OSError, ValueError) as error:
        _fail(file, f"not a readable .npy file ({error})")


def _decode_image(file: Path, width: int, height: int) -> Image.Image:
    if not file.is_file():
        _fail(file, "missing file")
    try:
        image = Image.open(file)
        image.load()
    except (OSError, SyntaxError) as error:
        _fail(file, f"cannot decode image ({error})")
    if image.size != (width, height):
        _fail(file, f"wrong image size {image.size[0]}x{image.size[1]}, the scene is {width}x{height}")
    return image


# ----------------------------------------------------------------------------------------------
# Per-frame files of one trajectory (original or novel)
# ----------------------------------------------------------------------------------------------


class _FrameFiles:
    """The per-frame image-like files of one camera trajectory under ``root``."""

    def __init__(
        self, root: Path, image_suffix: str, channels: tuple[str, ...], num_frames: int, width: int, height: int
    ):
        self.root = root
        self.image_suffix = image_suffix
        self.channels = channels
        self.num_frames = num_frames
        self.width = width
        self.height = height

    def path(self, channel: str, t: int) -> Path:
        if not 0 <= t < self.num_frames:
            raise IndexError(f"frame {t} out of range: the scene has {self.num_frames} frames")
        suffix = self.image_suffix if channel == "images" else CHANNEL_SUFFIXES[channel]
        return self.root / channel / f"{t:03d}{suffix}"

    def check_headers(self) -> None:
        for t in range(self.num_frames):
            _image_header(self.path("images", t), ("RGB",), self.width, self.height)
            for channel in self.channels:
                file = self.path(channel, t)
                if channel == "depth":
                    shape, dtype = _npy_header(file)
                    if shape != (self.height, self.width) or dtype != np.float32:
                        _fail(file, f"depth must be ({self.height}, {self.width}) float32, got {shape} {dtype}")
                else:
                    _image_header(file, CHANNEL_PNG_MODES[channel], self.width, self.height)

    def image(self, t: int) -> np.ndarray:  # (H,W,3) uint8, a fresh writable array per call
        file = self.path("images", t)
        if not file.is_file():
            _fail(file, "missing file")
        image = decode_rgb(file.read_bytes())
        if image is None:
            _fail(file, "cannot decode image (not a PNG or JPEG OpenCV can decode)")
        if image.shape[:2] != (self.height, self.width):
            _fail(file, f"wrong image size {image.shape[1]}x{image.shape[0]}, the scene is {self.width}x{self.height}")
        return image

    def encoded_image(self, t: int) -> bytes:
        return self.path("images", t).read_bytes()

    def depth(self, t: int) -> np.ndarray | None:  # (H,W) float32
        if "depth" not in self.channels:
            return None
        file = self.path("depth", t)
        depth = _load_npy(file)
        if depth.shape != (self.height, self.width) or depth.dtype != np.float32:
            _fail(file, f"depth must be ({self.height}, {self.width}) float32, got {depth.shape} {depth.dtype}")
        if not np.all(np.isfinite(depth)) or depth.min(initial=0.0) < 0:
            _fail(file, "depth has non-finite or negative values")
        return depth

    def _png(self, channel: str, t: int) -> np.ndarray | None:
        if channel not in self.channels:
            return None
        file = self.path(channel, t)
        with _decode_image(file, self.width, self.height) as image:
            if image.mode not in CHANNEL_PNG_MODES[channel]:
                _fail(file, f"wrong pixel mode {image.mode!r}, expected one of {CHANNEL_PNG_MODES[channel]}")
            return np.asarray(image)

    def semantics(self, t: int) -> np.ndarray | None:  # (H,W) uint8
        labels = self._png("semantics", t)
        return None if labels is None else labels.astype(np.uint8)  # a fresh, writable copy

    def instances(self, t: int) -> np.ndarray | None:  # (H,W) int32
        ids = self._png("instances", t)
        return None if ids is None else ids.astype(np.int32)

    def sky_mask(self, t: int) -> np.ndarray | None:  # (H,W) bool
        mask = self._png("sky_masks", t)
        return None if mask is None else mask > 0

    def to_channels(self) -> FrameChannels:
        frames = range(self.num_frames)
        return FrameChannels(
            images=[self.encoded_image(t) for t in frames],
            depth=[self.depth(t) for t in frames] if "depth" in self.channels else None,
            semantics=[self.semantics(t) for t in frames] if "semantics" in self.channels else None,
            instances=[self.instances(t) for t in frames] if "instances" in self.channels else None,
            sky_masks=[self.sky_mask(t) for t in frames] if "sky_masks" in self.channels else None,
        )


# ----------------------------------------------------------------------------------------------
# Loading
# ----------------------------------------------------------------------------------------------


def _readonly(array: np.ndarray) -> np.ndarray:
    array.setflags(write=False)
    return array


def _parse_box(entry: Any, file: Path, where: str) -> Box:
    track_id = _field(entry, "track_id", file, str, where)
    label = _field(entry, "label", file, str, where)
    if label not in BOX_LABELS:
        _fail(file, f"{where}label: unknown box label {label!r}, expected one of {BOX_LABELS}")
    size = _array(_field(entry, "size", file, list, where), (3,), file, f"{where}size")
    if np.any(size <= 0):
        _fail(file, f"{where}size: box sizes must be positive, got {size.tolist()}")
    obj_to_world = _array(_field(entry, "obj_to_world", file, list, where), (4, 4), file, f"{where}obj_to_world")
    _check_rigid(obj_to_world, file, f"{where}obj_to_world")
    num_points = _field(entry, "num_points", file, int, where)
    if num_points < 0:
        _fail(file, f"{where}num_points: must be >= 0, got {num_points}")
    speed = float(_field(entry, "speed", file, (int, float), where)) if "speed" in entry else 0.0
    if not math.isfinite(speed):
        _fail(file, f"{where}speed: non-finite value")
    return Box(
        track_id=track_id,
        label=label,
        size=_readonly(size),
        obj_to_world=_readonly(obj_to_world),
        num_points=num_points,
        speed=speed,
    )


def _parse_boxes(file: Path, num_frames: int) -> list[list[Box]]:
    frames = _field(_read_json(file), "frames", file, list)
    if len(frames) != num_frames:
        _fail(file, f"frame-count mismatch: {len(frames)} frames of boxes, the scene has {num_frames}")
    boxes: list[list[Box]] = []
    for t, frame in enumerate(frames):
        if not isinstance(frame, list):
            _fail(file, f"frames[{t}] must be a list of boxes")
        parsed = [_parse_box(entry, file, f"frames[{t}][{i}].") for i, entry in enumerate(frame)]
        ids = [box.track_id for box in parsed]
        if len(set(ids)) != len(ids):
            duplicate = next(i for i in ids if ids.count(i) > 1)
            _fail(file, f"frames[{t}]: track id {duplicate!r} appears more than once")
        boxes.append(parsed)
    return boxes


def _parse_map(file: Path) -> list[Polyline]:
    entries = _field(_read_json(file), "polylines", file, list)
    polylines = []
    for i, entry in enumerate(entries):
        where = f"polylines[{i}]."
        kind = _field(entry, "kind", file, str, where)
        if kind not in POLYLINE_KINDS:
            _fail(file, f"{where}kind: unknown polyline kind {kind!r}, expected one of {POLYLINE_KINDS}")
        points = _array(_field(entry, "points", file, list, where), (-1, 3), file, f"{where}points")
        if len(points) < 2:
            _fail(file, f"{where}points: a polyline needs at least 2 points, got {len(points)}")
        polylines.append(Polyline(kind=kind, points=_readonly(points)))
    return polylines


def _parse_channels(value: Any, file: Path, what: str) -> tuple[str, ...]:
    if not isinstance(value, list) or not all(isinstance(c, str) for c in value):
        _fail(file, f"{what} must be a list of channel names")
    unknown = [c for c in value if c not in CHANNEL_SUFFIXES]
    if unknown:
        _fail(file, f"{what}: unknown channel {unknown[0]!r}, expected some of {tuple(CHANNEL_SUFFIXES)}")
    return tuple(value)


class Scene:
    """A validated scene directory; per-frame data is read from disk when asked for.

    Array attributes are read-only numpy arrays (copy before modifying).
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        if not self.path.is_dir():
            _fail(self.path, "not a scene directory (it does not exist or is not a directory)")
        file = self.path / SCENE_FILE
        header = _read_json(file)
        if not isinstance(header, dict):
            _fail(file, "must hold a JSON object")
        version = header.get("format_version")
        if not isinstance(version, int) or isinstance(version, bool) or version not in SUPPORTED_FORMAT_VERSIONS:
            _fail(
                file,
                f"unknown format version {version!r} (this recondreamer reads versions {SUPPORTED_FORMAT_VERSIONS})",
            )
        self.format_version: int = version
        self.scene_id: str = _field(header, "scene_id", file, str)
        self.source: str = _field(header, "source", file, str)
        self.metadata: dict = _field(header, "metadata", file, dict)

        camera = _field(header, "camera", file, dict)
        self.width: int = _field(camera, "width", file, int, "camera.")
        self.height: int = _field(camera, "height", file, int, "camera.")
        if self.width <= 0 or self.height <= 0:
            _fail(file, f"camera size must be positive, got {self.width}x{self.height}")
        self.K = _readonly(_array(_field(camera, "K", file, list, "camera."), (3, 3), file, "camera.K"))
        if self.K[0, 0] <= 0 or self.K[1, 1] <= 0 or np.any(self.K[2] != [0.0, 0.0, 1.0]) or self.K[1, 0] != 0:
            _fail(
                file, f"camera.K: expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0, got {self.K.tolist()}"
            )
        self.distortion = _readonly(
            _array(_field(camera, "distortion", file, list, "camera."), (5,), file, "camera.distortion")
        )
        self.cam_to_ego = _readonly(
            _array(_field(camera, "cam_to_ego", file, list, "camera."), (4, 4), file, "camera.cam_to_ego")
        )
        _check_rigid(self.cam_to_ego, file, "camera.cam_to_ego")

        self.num_frames: int = _field(header, "num_frames", file, int)
        if self.num_frames < 1:
            _fail(file, f"num_frames must be at least 1, got {self.num_frames}")
        self.timestamps = _readonly(_array(_field(header, "timestamps", file, list), (-1,), file, "timestamps"))
        ego_to_world = _array(_field(header, "ego_to_world", file, list), (-1, 4, 4), file, "ego_to_world")
        for what, count in (("timestamps", len(self.timestamps)), ("ego_to_world", len(ego_to_world))):
            if count != self.num_frames:
                _fail(file, f"frame-count mismatch: {count} {what} for num_frames = {self.num_frames}")
        if np.any(np.diff(self.timestamps) <= 0):
            _fail(file, "timestamps must be strictly increasing")
        for t, pose in enumerate(ego_to_world):
            _check_rigid(pose, file, f"ego_to_world[{t}]")
        self.ego_to_world = _readonly(ego_to_world)
        self.cam_to_world = _readonly(ego_to_world @ self.cam_to_ego)

        self.track_ids: list[str] = _field(header, "track_ids", file, list)
        if not all(isinstance(i, str) for i in self.track_ids) or len(set(self.track_ids)) != len(self.track_ids):
            _fail(file, "track_ids must be a list of distinct strings")
        self.semantic_classes: tuple[str, ...] = tuple(_field(header, "semantic_classes", file, list))
        if not all(isinstance(name, str) for name in self.semantic_classes):
            _fail(file, "semantic_classes must be a list of class names")
        self.image_format: str = _field(header, "image_format", file, str)
        if self.image_format not in IMAGE_SUFFIXES:
            _fail(file, f"image_format must be one of {tuple(IMAGE_SUFFIXES)}, got {self.image_format!r}")
        self.channels = _parse_channels(_field(header, "channels", file, list), file, "channels")

        suffix = IMAGE_SUFFIXES[self.image_format]
        self._original = _FrameFiles(self.path, suffix, self.channels, self.num_frames, self.width, self.height)
        self._novel: dict[str, _FrameFiles] = {}
        for name, entry in _field(header, "novel", file, dict).items():
            try:
                spec = trajectories.parse_trajectory(name)
            except ValueError as error:
                _fail(file, f"novel: {error}")
            if spec.kind in ("original", "file"):
                _fail(file, f"novel: {name!r} cannot hold true novel views")
            channels = _parse_channels(
                _field(entry, "channels", file, list, f"novel.{name}."), file, f"novel.{name}.channels"
            )
            self._novel[name] = _FrameFiles(
                self.path / "novel" / name, suffix, channels, self.num_frames, self.width, self.height
            )
        self.novel_trajectories: tuple[str, ...] = tuple(self._novel)

        self._boxes = _parse_boxes(self.path / BOXES_FILE, self.num_frames)
        self.map_polylines: list[Polyline] = _parse_map(self.path / MAP_FILE)

        self._original.check_headers()
        for files in self._novel.values():
            files.check_headers()
        for t in range(self.num_frames):
            lidar_file = self._lidar_path(t)
            shape, dtype = _npy_header(lidar_file)
            if len(shape) != 2 or shape[1] != 3 or dtype != np.float32:
                _fail(lidar_file, f"LiDAR points must be (N, 3) float32, got {shape} {dtype}")

    def __repr__(self) -> str:
        return f"Scene({str(self.path)!r}, id={self.scene_id!r}, source={self.source!r}, {self.num_frames} frames, {self.width}x{self.height})"

    # -- per-frame data of the recorded camera ---------------------------------------------------

    def image_path(self, t: int) -> Path:
        return self._original.path("images", t)

    def image(self, t: int) -> np.ndarray:  # (H,W,3) uint8
        return self._original.image(t)

    def images(self) -> np.ndarray:  # (T,H,W,3) uint8
        """Every recorded frame, in order."""
        return np.stack([self.image(t) for t in range(self.num_frames)])

    def depth(self, t: int) -> np.ndarray | None:  # (H,W) float32 metres along z, 0 = no hit
        return self._original.depth(t)

    def semantics(self, t: int) -> np.ndarray | None:  # (H,W) uint8 ids into semantic_classes
        return self._original.semantics(t)

    def instances(self, t: int) -> np.ndarray | None:  # (H,W) int32, 0 = none, i+1 = track_ids[i]
        return self._original.instances(t)

    def sky_mask(self, t: int) -> np.ndarray | None:  # (H,W) bool
        return self._original.sky_mask(t)

    def _lidar_path(self, t: int) -> Path:
        if not 0 <= t < self.num_frames:
            raise IndexError(f"frame {t} out of range: the scene has {self.num_frames} frames")
        return self.path / "lidar" / f"{t:03d}.npy"

    def lidar(self, t: int) -> np.ndarray:  # (N,3) float32 world
        file = self._lidar_path(t)
        points = _load_npy(file)
        if points.ndim != 2 or points.shape[1] != 3 or points.dtype != np.float32:
            _fail(file, f"LiDAR points must be (N, 3) float32, got {points.shape} {points.dtype}")
        if not np.all(np.isfinite(points)):
            _fail(file, "LiDAR points have non-finite values")
        return points

    def boxes(self, t: int) -> list[Box]:
        if not 0 <= t < self.num_frames:
            raise IndexError(f"frame {t} out of range: the scene has {self.num_frames} frames")
        return list(self._boxes[t])

    # -- trajectories and true novel views ------------------------------------------------------

    def trajectory(self, name: str) -> np.ndarray:  # (T,4,4) cam_to_world
        """Camera-to-world poses of a trajectory name (see ``recondreamer.scene.trajectories``)."""
        if name == "original":
            return self.cam_to_world.copy()
        return trajectories.trajectory_cam_to_world(self.cam_to_world, self.ego_to_world, name)

    def _novel_files(self, name: str) -> _FrameFiles:
        if name not in self._novel:
            raise SceneFormatError(
                f"{self.path}: no true novel views for trajectory {name!r} (this scene has {self.novel_trajectories or 'none'})"
            )
        return self._novel[name]

    def novel_image(self, name: str, t: int) -> np.ndarray:  # (H,W,3) uint8
        return self._novel_files(name).image(t)

    def novel_depth(self, name: str, t: int) -> np.ndarray | None:  # (H,W) float32
        return self._novel_files(name).depth(t)

    def novel_semantics(self, name: str, t: int) -> np.ndarray | None:  # (H,W) uint8
        return self._novel_files(name).semantics(t)

    def novel_instances(self, name: str, t: int) -> np.ndarray | None:  # (H,W) int32
        return self._novel_files(name).instances(t)

    def novel_channels(self, name: str) -> tuple[str, ...]:
        """Optional channels stored beside the novel images of ``name`` (images always exist)."""
        return self._novel_files(name).channels

    # -- whole-scene operations -----------------------------------------------------------------

    def check_all(self) -> None:
        """Decode every per-frame file and check its values (``load_scene`` reads headers only)."""
        num_classes, num_tracks = len(self.semantic_classes), len(self.track_ids)
        for files in (self._original, *self._novel.values()):
            for t in range(self.num_frames):
                files.image(t)
                files.depth(t)
                labels = files.semantics(t)
                if labels is not None and num_classes and labels.max() >= num_classes:
                    _fail(
                        files.path("semantics", t),
                        f"semantic id {labels.max()} outside the {num_classes} semantic_classes",
                    )
                ids = files.instances(t)
                if ids is not None and ids.max() > num_tracks:
                    _fail(
                        files.path("instances", t),
                        f"instance id {ids.max()} but the scene has only {num_tracks} track_ids",
                    )
                files.sky_mask(t)
        for t in range(self.num_frames):
            self.lidar(t)

    def to_data(self) -> SceneData:
        """Everything in memory (images stay encoded bytes, so writing it back is lossless)."""
        frames = range(self.num_frames)
        return SceneData(
            scene_id=self.scene_id,
            source=self.source,
            width=self.width,
            height=self.height,
            K=self.K.copy(),
            distortion=self.distortion.copy(),
            cam_to_ego=self.cam_to_ego.copy(),
            ego_to_world=self.ego_to_world.copy(),
            timestamps=self.timestamps.copy(),
            frames=self._original.to_channels(),
            lidar=[self.lidar(t) for t in frames],
            boxes=[self.boxes(t) for t in frames],
            map_polylines=list(self.map_polylines),
            track_ids=list(self.track_ids),
            novel={name: files.to_channels() for name, files in self._novel.items()},
            metadata=json.loads(json.dumps(self.metadata)),
        )

    def fingerprint(self) -> str:
        """sha256 over every file of the scene directory (relative path and bytes): two scenes
        with the same id but other content (another seed, size or frame count, an edit by hand)
        have different fingerprints. About 30 ms for a compact scene (15 MB)."""
        digest = hashlib.sha256()
        for file in sorted(p for p in self.path.rglob("*") if p.is_file() and p.name != OUTPUT_MARKER):
            digest.update(file.relative_to(self.path).as_posix().encode() + b"\0")
            digest.update(file.read_bytes())
        return digest.hexdigest()

    def summary(self) -> str:
        """A few lines for people (``recondreamer validate``)."""
        duration = self.timestamps[-1] - self.timestamps[0]
        num_boxes = sum(len(b) for b in self._boxes)
        lines = [
            f"scene {self.scene_id!r} (source {self.source}, format version {self.format_version}) at {self.path}",
            f"  {self.num_frames} frames over {duration:.2f} s, {self.width}x{self.height} {self.image_format}, "
            f"fx={self.K[0, 0]:.1f} fy={self.K[1, 1]:.1f}, channels: {', '.join(self.channels) or 'images only'}",
            f"  {len(self.track_ids)} tracks, {num_boxes} boxes over all frames, {len(self.map_polylines)} map polylines",
            f"  true novel views: {', '.join(self.novel_trajectories) or 'none'}",
        ]
        return "\n".join(lines)


def load_scene(path: str | os.PathLike) -> Scene:
    """Open and validate a scene directory; SceneFormatError names the file and the problem."""
    return Scene(path)


# ----------------------------------------------------------------------------------------------
# Writing
# ----------------------------------------------------------------------------------------------


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    raise TypeError(f"metadata value {value!r} of type {type(value).__name__} is not JSON serializable")


def _write_json(file: Path, obj: Any, indent: int | None = None) -> None:
    file.write_text(json.dumps(obj, indent=indent, default=_json_default) + "\n", encoding="utf-8")


def _encoded_format(data: bytes) -> str | None:
    if data.startswith(b"\x89PNG\r\n\x1a\n"):
        return "png"
    if data.startswith(b"\xff\xd8"):
        return "jpg"
    return None


def _write_image(file: Path, image: Any, image_format: str, what: str) -> None:
    if isinstance(image, (bytes, bytearray)):
        if _encoded_format(bytes(image)) == image_format:
            file.write_bytes(bytes(image))
            return
        decoded = decode_rgb(bytes(image))
        if decoded is None:
            raise SceneFormatError(f"{what}: encoded image bytes cannot be decoded (not a PNG or JPEG)")
        image = decoded
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise SceneFormatError(
            f"{what}: expected an (H,W,3) uint8 array or encoded bytes, got {image.shape} {image.dtype}"
        )
    file.write_bytes(encode_rgb(image, image_format))


def _check_count(values: list | None, num_frames: int, what: str) -> None:
    if values is not None and len(values) != num_frames:
        raise SceneFormatError(f"{what}: frame-count mismatch: {len(values)} entries for {num_frames} frames")


def _write_frames(root: Path, channels: FrameChannels, image_format: str, num_frames: int, what: str) -> list[str]:
    """Write one trajectory's per-frame files under ``root``; returns the optional channels written."""
    _check_count(channels.images, num_frames, f"{what}.images")
    (root / "images").mkdir(parents=True)
    for t, image in enumerate(channels.images):
        _write_image(
            root / "images" / f"{t:03d}{IMAGE_SUFFIXES[image_format]}", image, image_format, f"{what}.images[{t}]"
        )
    written = []
    for channel in CHANNEL_SUFFIXES:
        values = getattr(channels, channel)
        if values is None:
            continue
        _check_count(values, num_frames, f"{what}.{channel}")
        (root / channel).mkdir()
        for t, value in enumerate(values):
            file = root / channel / f"{t:03d}{CHANNEL_SUFFIXES[channel]}"
            value = np.asarray(value)
            if value.ndim != 2:
                raise SceneFormatError(f"{what}.{channel}[{t}]: expected an (H,W) array, got shape {value.shape}")
            if channel == "depth":
                np.save(file, value.astype(np.float32, copy=False))
            elif channel == "semantics":
                if value.min(initial=0) < 0 or value.max(initial=0) > 255:
                    raise SceneFormatError(f"{what}.semantics[{t}]: label ids must fit in 0..255")
                Image.fromarray(value.astype(np.uint8)).save(file, format="PNG", compress_level=PNG_COMPRESS_LEVEL)
            elif channel == "instances":
                if value.min(initial=0) < 0 or value.max(initial=0) > 65535:
                    raise SceneFormatError(f"{what}.instances[{t}]: instance ids must fit in 0..65535")
                Image.fromarray(value.astype(np.uint16)).save(file, format="PNG", compress_level=PNG_COMPRESS_LEVEL)
            else:
                Image.fromarray((value > 0).astype(np.uint8) * 255).save(
                    file, format="PNG", compress_level=PNG_COMPRESS_LEVEL
                )
        written.append(channel)
    return written


def _box_entry(box: Box) -> dict:
    return {
        "track_id": box.track_id,
        "label": box.label,
        "size": np.asarray(box.size, dtype=np.float64).tolist(),
        "obj_to_world": np.asarray(box.obj_to_world, dtype=np.float64).tolist(),
        "num_points": int(box.num_points),
        "speed": float(box.speed),
    }


def write_scene(path: str | os.PathLike, data: SceneData, image_format: str = "png") -> Path:
    """Write ``data`` as a scene directory at ``path``, atomically, and validate it.

    The directory is built under a temporary sibling name, validated with the same checks as
    ``load_scene`` and renamed into place only when complete; an existing scene at ``path`` is
    replaced. ``scene.json`` is written last, so a half-built temporary directory never loads.
    """
    if image_format not in IMAGE_SUFFIXES:
        raise ValueError(f"image_format must be one of {tuple(IMAGE_SUFFIXES)}, got {image_format!r}")
    path = Path(path)
    num_frames = data.num_frames
    what = f"writing {path}"
    _check_count(data.lidar, num_frames, f"{what}: lidar")
    _check_count(data.boxes, num_frames, f"{what}: boxes")
    _check_count(list(data.ego_to_world), num_frames, f"{what}: ego_to_world")
    with atomic_directory(path, "scene") as tmp:
        channels = _write_frames(tmp, data.frames, image_format, num_frames, f"{what}: frames")
        novel = {}
        for name, novel_frames in data.novel.items():
            spec = trajectories.parse_trajectory(name)
            if spec.kind in ("original", "file"):
                raise SceneFormatError(f"{what}: novel trajectory {name!r} cannot hold true novel views")
            novel[name] = {
                "channels": _write_frames(
                    tmp / "novel" / name, novel_frames, image_format, num_frames, f"{what}: novel[{name}]"
                )
            }
        (tmp / "lidar").mkdir()
        for t, points in enumerate(data.lidar):
            points = np.asarray(points, dtype=np.float32)
            if points.ndim != 2 or points.shape[1] != 3:
                raise SceneFormatError(f"{what}: lidar[{t}]: expected (N,3) points, got shape {points.shape}")
            np.save(tmp / "lidar" / f"{t:03d}.npy", points)
        _write_json(tmp / BOXES_FILE, {"frames": [[_box_entry(box) for box in frame] for frame in data.boxes]})
        polylines = [
            {"kind": p.kind, "points": np.asarray(p.points, dtype=np.float64).tolist()} for p in data.map_polylines
        ]
        _write_json(tmp / MAP_FILE, {"polylines": polylines})
        header = {
            "format_version": FORMAT_VERSION,
            "scene_id": data.scene_id,
            "source": data.source,
            "num_frames": num_frames,
            "camera": {
                "width": int(data.width),
                "height": int(data.height),
                "K": np.asarray(data.K, dtype=np.float64).tolist(),
                "distortion": np.asarray(data.distortion, dtype=np.float64).reshape(-1).tolist(),
                "cam_to_ego": np.asarray(data.cam_to_ego, dtype=np.float64).tolist(),
            },
            "image_format": image_format,
            "channels": channels,
            "timestamps": np.asarray(data.timestamps, dtype=np.float64).tolist(),
            "ego_to_world": np.asarray(data.ego_to_world, dtype=np.float64).tolist(),
            "track_ids": [str(i) for i in data.track_ids],
            "semantic_classes": list(SEMANTIC_CLASSES),
            "novel": novel,
            "metadata": data.metadata,
        }
        _write_json(tmp / SCENE_FILE, header, indent=1)
        try:
            Scene(tmp)
        except SceneFormatError as error:
            raise SceneFormatError(f"{what}: {str(error).replace(str(tmp), str(path))}") from None
    return path
