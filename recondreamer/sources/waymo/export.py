"""Write a synthetic scene as a Waymo Open Dataset v1 segment (``.tfrecord``).

The inverse of ``convert.py`` for what the converter reads: the FRONT camera's JPEG frames and
calibration, vehicle poses, upright 3D laser labels, a TOP LiDAR range image and the map
features (in record 0). It lets the real-data path (``source: waymo``) run end to end on scenes
whose truth is known: converting the written file must give the scene back. Synthetic scenes are
the input because their LiDAR is a spinning scanner on a known grid (rings at listed
inclinations, equal azimuth steps), which a Waymo range image stores without loss.

The segment's global frame is the scene's world frame moved by ``global_from_world`` (Waymo poses
are far from the origin; the converter's world frame is the first frame's vehicle frame again).
"""

from __future__ import annotations

import io
import os
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from recondreamer.errors import ConversionError
from recondreamer.scene import Scene, load_scene
from recondreamer.sources.waymo import geometry, schema
from recondreamer.sources.waymo.tfrecord import write_records

JPEG_QUALITY = 95
FIRST_TIMESTAMP_MICROS = 1_500_000_000_000_000  # the segment's first frame (2017-07-14): any fixed time works
DEFAULT_GLOBAL_FROM_WORLD = np.array(
    [
        [np.cos(0.3), -np.sin(0.3), 0.0, 4200.0],
        [np.sin(0.3), np.cos(0.3), 0.0, -1800.0],
        [0.0, 0.0, 1.0, 35.0],
        [0.0, 0.0, 0.0, 1.0],
    ]
)  # (4,4): a global frame kilometres away and turned, as Waymo's is
LABEL_TYPE_OF = {label: number for number, label in schema.LABEL_TYPES.items()}
MAP_FIELD_OF = {"lane_center": "lane", "road_line": "road_line", "road_edge": "road_edge", "crosswalk": "crosswalk"}


@dataclass(frozen=True)
class LidarGrid:
    """A spinning LiDAR's range image layout: rings x equal azimuth steps, mounted without rotation."""

    inclinations: np.ndarray  # (H,) radians, ascending (Waymo lists them from the lowest beam up)
    num_azimuths: int  # W
    mount: np.ndarray  # (3,) metres, vehicle frame

    @classmethod
    def of_synthetic(cls, scene: Scene) -> LidarGrid:
        """The grid a synthetic scene's LiDAR was cast on (from the generator's recorded config)."""
        from recondreamer.sources.synthetic.segment import GENERATOR, LIDAR_ELEVATIONS_DEG, LIDAR_MOUNT

        metadata = scene.metadata
        if metadata.get("generator") != GENERATOR or "config" not in metadata:
            raise ConversionError(
                f"{scene.path}: not a synthetic scene (metadata.generator is {metadata.get('generator')!r}): "
                "only scenes of the synthetic world have a known LiDAR grid to write as a range image"
            )
        config = metadata["config"]
        inclinations = np.radians(np.linspace(*LIDAR_ELEVATIONS_DEG, int(config["lidar_beams"])))
        return cls(inclinations, int(config["lidar_azimuths"]), np.asarray(LIDAR_MOUNT, dtype=np.float64))

    def range_image(self, points_vehicle: np.ndarray) -> np.ndarray:  # (N,3) -> (H,W,4) float32
        """Range image of vehicle-frame points: each point goes to its nearest ring and azimuth
        column (Waymo's columns: azimuth +pi at column 0 down to -pi); the nearest return wins a
        cell; empty cells hold -1. Channels: range, intensity, elongation, no-label-zone (0)."""
        height, width = len(self.inclinations), self.num_azimuths
        image = np.zeros((height, width, 4), dtype=np.float32)
        image[..., 0] = -1.0
        local = points_vehicle - self.mount  # (N,3) laser frame (no rotation)
        distance = np.linalg.norm(local, axis=1)
        keep = distance > 0
        local, distance = local[keep], distance[keep]
        inclination = np.arcsin(local[:, 2] / distance)
        descending = self.inclinations[::-1]  # row 0 = highest beam
        row = np.abs(inclination[:, None] - descending[None, :]).argmin(axis=1)
        azimuth = np.arctan2(local[:, 1], local[:, 0])
        column = np.round(width * (np.pi - azimuth) / (2.0 * np.pi) - 0.5).astype(np.int64) % width
        for index in np.argsort(-distance):  # farthest first, so the nearest return is written last
            image[row[index], column[index], 0] = distance[index]
        return image


def _transform(message, matrix: np.ndarray) -> None:
    message.transform[:] = np.asarray(matrix, dtype=np.float64).reshape(-1).tolist()


def _compressed_matrix(array: np.ndarray) -> bytes:
    matrix = schema.MatrixFloat()
    matrix.data[:] = array.astype(np.float32).reshape(-1).tolist()
    matrix.shape.dims[:] = list(array.shape)
    return zlib.compress(matrix.SerializeToString())


def _jpeg(image: np.ndarray) -> bytes:  # (H,W,3) uint8
    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="JPEG", quality=JPEG_QUALITY, subsampling=0)  # 4:4:4: no chroma blur on small frames
    return buffer.getvalue()


def _context(frame, scene: Scene, grid: LidarGrid) -> None:
    frame.context.name = scene.scene_id
    frame.context.stats.time_of_day = "Day"
    calibration = frame.context.camera_calibrations.add(name=schema.CAMERA_NAMES["FRONT"], width=scene.width, height=scene.height)
    K = scene.K
    calibration.intrinsic[:] = [K[0, 0], K[1, 1], K[0, 2], K[1, 2], *np.asarray(scene.distortion, dtype=np.float64)]
    waymo_axes = np.eye(4)
    waymo_axes[:3, :3] = geometry.WAYMO_FROM_OPENCV.T  # Waymo camera axes in OpenCV ones
    _transform(calibration.extrinsic, scene.cam_to_ego @ waymo_axes)
    laser = frame.context.laser_calibrations.add(name=schema.LASER_TOP)
    laser.beam_inclinations[:] = grid.inclinations.tolist()
    laser.beam_inclination_min, laser.beam_inclination_max = float(grid.inclinations[0]), float(grid.inclinations[-1])
    mount = np.eye(4)
    mount[:3, 3] = grid.mount
    _transform(laser.extrinsic, mount)


def _labels(frame, scene: Scene, t: int, world_to_vehicle: np.ndarray) -> None:
    for box in scene.boxes(t):
        to_vehicle = world_to_vehicle @ box.obj_to_world
        label = frame.laser_labels.add(type=LABEL_TYPE_OF[box.label], id=box.track_id, num_top_lidar_points_in_box=box.num_points)
        label.num_lidar_points_in_box = box.num_points
        label.box.center_x, label.box.center_y, label.box.center_z = to_vehicle[:3, 3]
        label.box.length, label.box.width, label.box.height = (float(v) for v in box.size)
        label.box.heading = float(np.arctan2(to_vehicle[1, 0], to_vehicle[0, 0]))
        label.metadata.speed_x, label.metadata.speed_y = box.speed * np.cos(label.box.heading), box.speed * np.sin(label.box.heading)


def _map(frame, scene: Scene, global_from_world: np.ndarray) -> None:
    for number, polyline in enumerate(scene.map_polylines, start=1):
        points = polyline.points @ global_from_world[:3, :3].T + global_from_world[:3, 3]  # (M,3) map frame
        feature = frame.map_features.add(id=number)
        if polyline.kind == "crosswalk":
            target = feature.crosswalk.polygon
            if np.allclose(points[0], points[-1]):
                points = points[:-1]  # Waymo polygons are not closed by a repeated vertex
        else:
            target = getattr(feature, MAP_FIELD_OF[polyline.kind]).polyline
        for x, y, z in points:
            target.add(x=float(x), y=float(y), z=float(z))


def scene_to_waymo_frames(scene: Scene, grid: LidarGrid, global_from_world: np.ndarray = DEFAULT_GLOBAL_FROM_WORLD):
    """Yield the serialized Waymo ``Frame`` of each scene frame (record 0 carries the map)."""
    for t in range(scene.num_frames):
        frame = schema.Frame()
        _context(frame, scene, grid)
        vehicle_to_global = global_from_world @ scene.ego_to_world[t]
        _transform(frame.pose, vehicle_to_global)
        frame.timestamp_micros = FIRST_TIMESTAMP_MICROS + int(round(float(scene.timestamps[t]) * 1e6))
        frame.images.add(name=schema.CAMERA_NAMES["FRONT"], image=_jpeg(scene.image(t)))
        world_to_vehicle = geometry.rigid_inverse(scene.ego_to_world[t])
        points = scene.lidar(t).astype(np.float64) @ world_to_vehicle[:3, :3].T + world_to_vehicle[:3, 3]
        laser = frame.lasers.add(name=schema.LASER_TOP)
        laser.ri_return1.range_image_compressed = _compressed_matrix(grid.range_image(points))
        _labels(frame, scene, t, world_to_vehicle)
        if t == 0:
            _map(frame, scene, global_from_world)
        yield frame.SerializeToString()


def export_waymo(scene_dir: str | os.PathLike, out: str | os.PathLike) -> Path:
    """Write the synthetic scene at ``scene_dir`` as a Waymo Open Dataset v1 segment file ``out``
    (written atomically; the scene is not changed)."""
    out = Path(out)
    if out.suffix != ".tfrecord":
        raise ConversionError(f"--out {out}: a Waymo segment file ends in .tfrecord")
    if out.is_dir():
        raise ConversionError(f"--out {out} is a folder; name the .tfrecord file to write")
    scene = load_scene(scene_dir)
    unknown = sorted({box.label for t in range(scene.num_frames) for box in scene.boxes(t)} - set(LABEL_TYPE_OF))
    if unknown:
        raise ConversionError(f"{scene.path}: box labels {unknown} have no Waymo label type")
    grid = LidarGrid.of_synthetic(scene)
    write_records(out, scene_to_waymo_frames(scene, grid))
    return out
