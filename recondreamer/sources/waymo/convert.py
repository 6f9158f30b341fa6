"""Convert a Waymo Open Dataset v1 segment (``.tfrecord``) into a scene directory.

Records are streamed one at a time; only record 0 (which holds the segment's map) and the
selected frames are parsed. The world frame is the ego (vehicle) frame of the first selected
frame; every camera image is undistorted onto a pinhole camera (``undistort.py``), whose
intrinsics the scene holds (distortion zero). See ``docs/waymo.md``.
"""

from __future__ import annotations

import io
import logging
import os
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np
from google.protobuf.message import DecodeError
from PIL import Image

from recondreamer.errors import ConversionError
from recondreamer.io import check_replaceable
from recondreamer.scene.types import Box, FrameChannels, Polyline, SceneData
from recondreamer.sources.waymo import geometry, schema
from recondreamer.sources.waymo.tfrecord import iter_records
from recondreamer.sources.waymo.undistort import Undistortion

log = logging.getLogger(__name__)

PROGRESS_EVERY = 10  # frames between progress messages


class _VehicleBox(NamedTuple):
    """One laser label, still in its frame's vehicle frame."""

    track_id: str
    label: str
    size: np.ndarray  # (3,) length, width, height
    box_to_vehicle: np.ndarray  # (4,4)
    num_points: int
    speed: float


@dataclass
class _Selection:
    """What the stream collects from the selected frames (poses, labels and map still in Waymo frames)."""

    segment_name: str = ""
    stats: dict = field(default_factory=dict)
    undistortion: Undistortion | None = None  # the recorded camera and its pinhole twin
    cam_to_ego: np.ndarray | None = None  # (4,4)
    width: int = 0
    height: int = 0
    top_laser: object | None = None  # LaserCalibration of the TOP LiDAR, None when the file has none
    timestamps_micros: list[int] = field(default_factory=list)
    vehicle_to_global: list[np.ndarray] = field(default_factory=list)  # T x (4,4)
    map_pose_offsets: list[np.ndarray] = field(default_factory=list)  # T x (3,)
    jpegs: list[bytes] = field(default_factory=list)  # undistorted
    lidar_world: list[np.ndarray] = field(default_factory=list)  # T x (N,3) float32 world frame
    boxes_vehicle: list[list[_VehicleBox]] = field(default_factory=list)  # T x boxes
    skipped_labels: int = 0
    map_features: list = field(default_factory=list)  # MapFeature messages of record 0


def convert_waymo(
    tfrecord: str | os.PathLike,
    out: str | os.PathLike,
    start: int | None = None,
    end: int | None = None,
    camera: str = "FRONT",
) -> Path:
    """Convert frames ``start..end`` (inclusive, 0-based; default: all) of one camera to a scene at ``out``.

    Raises ConversionError (naming the file) for a truncated or corrupted file, a file that is
    not a Waymo TFRecord, a frame range outside the file or a missing camera; nothing is
    written then. The scene directory is written atomically.
    """
    from recondreamer.scene import write_scene

    tfrecord, out = Path(tfrecord), Path(out)
    camera = camera.upper()
    if camera not in schema.CAMERA_NAMES:
        raise ConversionError(f"unknown camera {camera!r}; choose one of {', '.join(schema.CAMERA_NAMES)}")
    if start is not None and start < 0:
        raise ConversionError(f"--start must be >= 0, got {start}")
    if end is not None and end < (start or 0):
        raise ConversionError(f"--end ({end}) must not be before --start ({start or 0})")
    check_replaceable(out, "scene")
    first = start or 0
    selection = _read_selection(tfrecord, first, end, camera)
    last = first + len(selection.timestamps_micros) - 1
    data = _scene_data(selection, tfrecord, first, last, camera)
    log.info("writing %s: %d frames, %d tracks, %d map polylines", out, data.num_frames, len(data.track_ids),
             len(data.map_polylines))
    write_scene(out, data, image_format="jpg")
    return out


def _read_selection(path: Path, first: int, end: int | None, camera: str) -> _Selection:
    selection = _Selection()
    num_records = 0
    for index, record in enumerate(iter_records(path)):
        num_records = index + 1
        if index == 0 or index >= first:
            frame = _parse_frame(path, index, record)
            if index == 0:
                selection.map_features = list(frame.map_features)
            if index >= first:
                _add_frame(selection, frame, path, index, camera)
                done = index - first + 1
                if done % PROGRESS_EVERY == 0:
                    log.info("%s: read %d frames (record %d)", path.name, done, index)
        if end is not None and index == end:
            break
    if num_records == 0:
        raise ConversionError(f"{path}: holds no records ({path.stat().st_size} bytes): not a Waymo Open Dataset segment (an interrupted download?)")
    if num_records <= first or (end is not None and num_records <= end):
        requested = f"{first}..{end}" if end is not None else f"{first}..(end)"
        raise ConversionError(
            f"{path}: frame range {requested} is outside the file, which holds {num_records} frames "
            f"(0..{num_records - 1})"
        )
    return selection


def _parse_frame(path: Path, index: int, record: bytes):
    try:
        return schema.Frame.FromString(record)
    except DecodeError as error:
        raise ConversionError(f"{path}: record {index} is not a Waymo Frame protobuf ({error})") from None


def _add_frame(selection: _Selection, frame, path: Path, index: int, camera: str) -> None:
    where = f"{path}: frame {index}"
    if not frame.HasField("pose"):
        raise ConversionError(f"{where} has no vehicle pose")
    if selection.undistortion is None:
        _set_calibration(selection, frame, where, camera)
    images = [image for image in frame.images if image.name == schema.CAMERA_NAMES[camera]]
    if not images or not images[0].image:
        raise ConversionError(f"{where} has no {camera} camera image")
    jpeg = images[0].image
    _check_jpeg(jpeg, selection.width, selection.height, where)
    selection.jpegs.append(selection.undistortion.jpeg(jpeg, where))
    if selection.timestamps_micros and frame.timestamp_micros <= selection.timestamps_micros[-1]:
        raise ConversionError(f"{where}: timestamp {frame.timestamp_micros} us does not follow the previous frame's")
    selection.timestamps_micros.append(frame.timestamp_micros)
    pose = _matrix(frame.pose, f"{where} pose")
    selection.vehicle_to_global.append(pose)
    offset = frame.map_pose_offset
    selection.map_pose_offsets.append(np.array([offset.x, offset.y, offset.z]))
    # LiDAR goes to the world frame at once, in float32: it is most of the memory a segment takes.
    ego_to_world = geometry.rigid_inverse(selection.vehicle_to_global[0]) @ pose
    points = _top_lidar(frame, pose, selection.top_laser, where)  # (N,3) vehicle frame
    selection.lidar_world.append((points @ ego_to_world[:3, :3].T + ego_to_world[:3, 3]).astype(np.float32))
    selection.boxes_vehicle.append(_labels(selection, frame))


def _set_calibration(selection: _Selection, frame, where: str, camera: str) -> None:
    context = frame.context
    calibrations = [c for c in context.camera_calibrations if c.name == schema.CAMERA_NAMES[camera]]
    if not calibrations:
        raise ConversionError(f"{where} has no {camera} camera calibration")
    calibration = calibrations[0]
    try:
        K, distortion = geometry.intrinsics(calibration.intrinsic)
    except ValueError as error:
        raise ConversionError(f"{where}: {error}") from None
    extrinsic = _matrix(calibration.extrinsic, f"{where} camera extrinsic")
    selection.cam_to_ego = geometry.camera_to_ego_opencv(extrinsic)
    selection.width, selection.height = calibration.width, calibration.height
    if selection.width <= 0 or selection.height <= 0:
        raise ConversionError(f"{where}: camera calibration has image size {selection.width}x{selection.height}")
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(distortion)) and K[0, 0] > 0 and K[1, 1] > 0):
        raise ConversionError(f"{where}: camera intrinsics {calibration.intrinsic} are not a camera (focal lengths must be positive and finite)")
    selection.undistortion = Undistortion.of_camera(K, distortion, selection.width, selection.height)
    lasers = [c for c in context.laser_calibrations if c.name == schema.LASER_TOP]
    selection.top_laser = lasers[0] if lasers else None
    selection.segment_name = context.name
    stats = context.stats
    selection.stats = {"time_of_day": stats.time_of_day, "location": stats.location, "weather": stats.weather}


def _matrix(transform, what: str) -> np.ndarray:  # (4,4)
    try:
        matrix = geometry.transform_matrix(transform)
    except ValueError as error:
        raise ConversionError(f"{what}: {error}") from None
    if not np.all(np.isfinite(matrix)):
        raise ConversionError(f"{what} holds non-finite values")
    return matrix


def _check_jpeg(jpeg: bytes, width: int, height: int, where: str) -> None:
    try:
        with Image.open(io.BytesIO(jpeg)) as image:  # reads the header only
            kind, size = image.format, image.size
    except OSError as error:
        raise ConversionError(f"{where}: camera image cannot be read ({error})") from None
    if kind != "JPEG":
        raise ConversionError(f"{where}: camera image is {kind}, expected JPEG")
    if size != (width, height):
        raise ConversionError(f"{where}: camera image is {size[0]}x{size[1]} but its calibration says {width}x{height}")


def _top_lidar(frame, pose: np.ndarray, calibration, where: str) -> np.ndarray:  # (N,3) vehicle frame
    lasers = [laser for laser in frame.lasers if laser.name == schema.LASER_TOP]
    if not lasers or not lasers[0].ri_return1.range_image_compressed:
        return np.zeros((0, 3))
    if calibration is None:
        raise ConversionError(f"{where} has a TOP range image but the segment has no TOP laser calibration")
    return_1 = lasers[0].ri_return1
    try:
        range_image = geometry.decode_matrix_float(return_1.range_image_compressed)  # (H,W,4)
        pixel_pose = None
        if return_1.range_image_pose_compressed:
            pixel_pose = geometry.decode_matrix_float(return_1.range_image_pose_compressed)  # (H,W,6)
        if range_image.ndim != 3 or (pixel_pose is not None and pixel_pose.shape[:2] != range_image.shape[:2]):
            raise ValueError(f"range image shape {range_image.shape} does not fit its pose image")
        inclinations = geometry.beam_inclinations(calibration, range_image.shape[0])
        extrinsic = _matrix(calibration.extrinsic, f"{where} TOP laser extrinsic")
        return geometry.range_image_to_points(range_image[..., 0], inclinations, extrinsic, pixel_pose, pose)
    except (ValueError, DecodeError, zlib.error) as error:
        raise ConversionError(f"{where}: TOP range image cannot be decoded ({error})") from None


def _labels(selection: _Selection, frame) -> list[_VehicleBox]:
    boxes = []
    for label in frame.laser_labels:
        kind = schema.LABEL_TYPES.get(label.type)
        box = label.box
        size = np.array([box.length, box.width, box.height])
        if kind is None or not label.id or not np.all(size > 0):
            selection.skipped_labels += 1
            continue
        # Files before v1.3 have no per-TOP-LiDAR count; all LiDARs' count is the closest there is.
        if label.HasField("num_top_lidar_points_in_box"):
            points = label.num_top_lidar_points_in_box
        else:
            points = label.num_lidar_points_in_box
        metadata = label.metadata
        speed = float(np.linalg.norm([metadata.speed_x, metadata.speed_y, metadata.speed_z]))
        boxes.append(_VehicleBox(label.id, kind, size, geometry.box_to_vehicle(box), int(points), speed))
    return boxes


def _scene_data(selection: _Selection, path: Path, first: int, last: int, camera: str) -> SceneData:
    world_from_global = geometry.rigid_inverse(selection.vehicle_to_global[0])
    ego_to_world = np.stack([world_from_global @ pose for pose in selection.vehicle_to_global])  # (T,4,4)
    timestamps = (np.array(selection.timestamps_micros, dtype=np.int64) - selection.timestamps_micros[0]) / 1e6
    track_ids: list[str] = []
    known: set[str] = set()
    boxes: list[list[Box]] = []
    for frame_boxes, ego in zip(selection.boxes_vehicle, ego_to_world, strict=True):
        converted = []
        for box in frame_boxes:
            if box.track_id not in known:
                known.add(box.track_id)
                track_ids.append(box.track_id)
            obj_to_world = ego @ box.box_to_vehicle
            converted.append(Box(box.track_id, box.label, box.size, obj_to_world, box.num_points, box.speed))
        boxes.append(converted)
    # Map features align with LiDAR points after adding the frame's map pose offset; remove
    # the first selected frame's offset to bring the map into that frame's global coordinates.
    map_to_world = world_from_global.copy()
    map_to_world[:3, 3] -= world_from_global[:3, :3] @ selection.map_pose_offsets[0]
    polylines = _polylines(selection.map_features, map_to_world)
    if selection.skipped_labels:
        log.info("skipped %d labels of unknown type, without id or with a non-positive size", selection.skipped_labels)
    return SceneData(
        scene_id=f"{selection.segment_name or path.stem}_{first:03d}-{last:03d}",
        source="waymo",
        width=selection.width,
        height=selection.height,
        K=selection.undistortion.pinhole_K,
        distortion=np.zeros(5),
        cam_to_ego=selection.cam_to_ego,
        ego_to_world=ego_to_world,
        timestamps=timestamps,
        frames=FrameChannels(images=selection.jpegs),
        lidar=selection.lidar_world,
        boxes=boxes,
        map_polylines=polylines,
        track_ids=track_ids,
        metadata={
            "source_file": str(path.resolve()),
            "segment": selection.segment_name,
            "frame_range": [first, last],
            "camera": camera,
            "global_from_world": selection.vehicle_to_global[0].tolist(),
            # The calibration the recorded images follow; the scene's images are undistorted from it.
            "recorded_camera": {"K": selection.undistortion.K.tolist(), "distortion": selection.undistortion.distortion.tolist()},
            "skipped_labels": selection.skipped_labels,
            **selection.stats,
        },
    )


def _polylines(features, map_to_world: np.ndarray) -> list[Polyline]:
    polylines = []
    for feature in features:
        for kind, points, closed in (
            ("lane_center", feature.lane.polyline, False),
            ("road_line", feature.road_line.polyline, False),
            ("road_edge", feature.road_edge.polyline, False),
            ("crosswalk", feature.crosswalk.polygon, True),
        ):
            if len(points) < 2:
                continue
            xyz = np.array([[p.x, p.y, p.z] for p in points])  # (M,3) map frame
            if closed:
                xyz = np.concatenate([xyz, xyz[:1]])
            polylines.append(Polyline(kind, xyz @ map_to_world[:3, :3].T + map_to_world[:3, 3]))
    return polylines
