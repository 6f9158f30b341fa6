"""The converter on a small synthetic Waymo segment built with the own schema.

The segment has known truth in the global frame: a moving ego, a static object labelled in each
frame's vehicle frame, a flat ground seen by a TOP range image (with per-pixel poses), and map
features with a map pose offset. The converted scene must put all of them back where they are.
"""

from __future__ import annotations

import io
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from recondreamer.errors import ConversionError
from recondreamer.scene import load_scene
from recondreamer.scene.cameras import project_points, world_to_camera
from recondreamer.sources.waymo import schema
from recondreamer.sources.waymo.convert import convert_waymo
from recondreamer.sources.waymo.tfrecord import write_records
from recondreamer.sources.waymo.undistort import Undistortion

NUM_FRAMES = 6
WIDTH, HEIGHT = 64, 48
INTRINSIC = [60.0, 62.0, 31.0, 25.0, 0.05, -0.1, 0.002, -0.001, 0.01]  # fu fv cu cv k1 k2 p1 p2 k3
LASER_HEIGHT = 2.0  # metres above the ground (vehicle z = 0 is the ground)
LASER_YAW = 0.2
INCLINATIONS = np.linspace(-0.3, 0.05, 8)  # ascending, as Waymo lists them
RANGE_WIDTH = 32
MAP_POSE_OFFSET = np.array([0.4, -0.3, 0.2])
PIXEL_POSE_SHIFT = np.array([0.5, -0.25, 0.0])  # global shift of frame 3's per-pixel poses


def _pose(x: float, y: float, z: float, yaw: float) -> np.ndarray:  # (4,4)
    c, s = np.cos(yaw), np.sin(yaw)
    pose = np.eye(4)
    pose[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    pose[:3, 3] = [x, y, z]
    return pose


def vehicle_to_global(t: int) -> np.ndarray:  # (4,4): a curving drive far from the global origin
    return _pose(3000.0, -1500.0, 40.0, 0.7) @ _pose(4.0 * t, 0.1 * t * t, 0.0, 0.05 * t)


OBJECT_TO_GLOBAL = vehicle_to_global(0) @ _pose(25.0, 3.0, 0.8, 0.4)  # a parked car
CAMERA_EXTRINSIC = _pose(1.5, 0.1, 1.6, 0.03)  # Waymo camera axes (x forward) to vehicle
LASER_EXTRINSIC = _pose(1.0, 0.0, LASER_HEIGHT, LASER_YAW)


def _transform(message, matrix: np.ndarray) -> None:
    message.transform[:] = matrix.reshape(-1).tolist()


def _matrix_float(array: np.ndarray) -> bytes:
    matrix = schema.MatrixFloat()
    matrix.data[:] = array.astype(np.float32).reshape(-1).tolist()
    matrix.shape.dims[:] = list(array.shape)
    return zlib.compress(matrix.SerializeToString())


def _ground_range_image() -> np.ndarray:  # (H,W,4): the downward beams hit the flat ground
    rows = INCLINATIONS[::-1]  # row 0 = highest beam
    ranges = np.where(rows < 0, LASER_HEIGHT / np.sin(-np.minimum(rows, -1e-6)), -1.0)
    image = np.zeros((len(rows), RANGE_WIDTH, 4), dtype=np.float32)
    image[..., 0] = ranges[:, None]
    return image


def _pixel_pose(pose: np.ndarray) -> np.ndarray:  # (H,W,6) roll pitch yaw x y z, planar pose
    yaw = np.arctan2(pose[1, 0], pose[0, 0])
    values = np.array([0.0, 0.0, yaw, *pose[:3, 3]])
    return np.broadcast_to(values, (len(INCLINATIONS), RANGE_WIDTH, 6)).copy()


def _jpeg(t: int) -> bytes:
    image = np.full((HEIGHT, WIDTH, 3), 40 * t, dtype=np.uint8)
    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="JPEG")
    return buffer.getvalue()


def map_points_world(start: int) -> np.ndarray:  # (4,3) in the world frame of frame `start`
    return np.array([[5.0, -2.0, 0.0], [15.0, -2.5, 0.1], [30.0, -2.0, 0.2], [30.0, 2.0, 0.2]])


def make_frame(t: int, map_world_of: int) -> bytes:
    frame = schema.Frame()
    frame.context.name = "synthetic_segment"
    frame.context.stats.time_of_day = "Day"
    for name, width in ((1, WIDTH), (2, WIDTH + 2)):
        calibration = frame.context.camera_calibrations.add(name=name, width=width, height=HEIGHT)
        calibration.intrinsic[:] = INTRINSIC
        _transform(calibration.extrinsic, CAMERA_EXTRINSIC)
    laser_calibration = frame.context.laser_calibrations.add(name=schema.LASER_TOP)
    laser_calibration.beam_inclinations[:] = INCLINATIONS.tolist()
    _transform(laser_calibration.extrinsic, LASER_EXTRINSIC)
    frame.timestamp_micros = 1_553_735_853_000_000 + 100_000 * t
    pose = vehicle_to_global(t)
    _transform(frame.pose, pose)
    frame.images.add(name=1, image=_jpeg(t))
    laser = frame.lasers.add(name=schema.LASER_TOP)
    laser.ri_return1.range_image_compressed = _matrix_float(_ground_range_image())
    pixel_pose = _pixel_pose(pose)
    if t == 3:
        pixel_pose[..., 3:] += PIXEL_POSE_SHIFT
    laser.ri_return1.range_image_pose_compressed = _matrix_float(pixel_pose)
    offset = MAP_POSE_OFFSET * (1 + t)  # drifts over time
    frame.map_pose_offset.x, frame.map_pose_offset.y, frame.map_pose_offset.z = offset

    object_in_vehicle = np.linalg.inv(pose) @ OBJECT_TO_GLOBAL
    car = frame.laser_labels.add(type=1, id="car", num_top_lidar_points_in_box=100 + t, num_lidar_points_in_box=7)
    car.box.center_x, car.box.center_y, car.box.center_z = object_in_vehicle[:3, 3]
    car.box.length, car.box.width, car.box.height = 4.6, 1.9, 1.5
    car.box.heading = np.arctan2(object_in_vehicle[1, 0], object_in_vehicle[0, 0])
    car.metadata.speed_x, car.metadata.speed_y, car.metadata.speed_z = 3.0, 4.0, 0.0
    frame.laser_labels.add(type=0, id="unknown-type").box.length = 1.0  # skipped: no label class
    sign = frame.laser_labels.add(type=3, id=f"sign-{t % 2}", num_top_lidar_points_in_box=5)
    sign.box.center_x, sign.box.length, sign.box.width, sign.box.height = 10.0, 0.1, 0.8, 0.8

    if t == 0:  # Waymo stores the segment's map in the first frame only
        points = map_points_world(map_world_of)
        start_pose = vehicle_to_global(map_world_of)
        map_coordinates = points @ start_pose[:3, :3].T + start_pose[:3, 3] + MAP_POSE_OFFSET * (1 + map_world_of)
        lane = frame.map_features.add(id=1).lane
        road_edge = frame.map_features.add(id=2).road_edge
        crosswalk = frame.map_features.add(id=3).crosswalk
        frame.map_features.add(id=4).road_line.polyline.add(x=1.0)  # a single point is no polyline: skipped
        for x, y, z in map_coordinates:
            lane.polyline.add(x=x, y=y, z=z)
            road_edge.polyline.add(x=x, y=y, z=z)
        for x, y, z in map_coordinates[:3]:
            crosswalk.polygon.add(x=x, y=y, z=z)
    return frame.SerializeToString()


def write_segment(path: Path, map_world_of: int = 0) -> Path:
    write_records(path, (make_frame(t, map_world_of) for t in range(NUM_FRAMES)))
    return path


@pytest.fixture(scope="module")
def converted(tmp_path_factory):
    """Frames 2..4 of the synthetic segment (the map is read from frame 0, which is not selected)."""
    root = tmp_path_factory.mktemp("waymo_synthetic")
    path = write_segment(root / "segment.tfrecord", map_world_of=2)
    return load_scene(convert_waymo(path, root / "scene", start=2, end=4))


def test_frames_poses_and_timestamps(converted):
    scene = converted
    assert scene.num_frames == 3
    assert scene.metadata["frame_range"] == [2, 4]
    assert scene.scene_id == "synthetic_segment_002-004"
    np.testing.assert_allclose(scene.timestamps, [0.0, 0.1, 0.2], atol=1e-9)
    for i, t in enumerate(range(2, 5)):
        expected = np.linalg.inv(vehicle_to_global(2)) @ vehicle_to_global(t)
        np.testing.assert_allclose(scene.ego_to_world[i], expected, atol=1e-9)
        assert scene.image(i)[0, 0, 0] == pytest.approx(40 * t, abs=3)  # the JPEG of frame t


def test_static_object_stays_put(converted):
    expected = np.linalg.inv(vehicle_to_global(2)) @ OBJECT_TO_GLOBAL
    for t in range(converted.num_frames):
        cars = [box for box in converted.boxes(t) if box.track_id == "car"]
        assert len(cars) == 1
        car = cars[0]
        np.testing.assert_allclose(car.obj_to_world, expected, atol=1e-9)
        np.testing.assert_allclose(car.size, [4.6, 1.9, 1.5])
        assert (car.label, car.num_points, car.speed) == ("vehicle", 102 + t, pytest.approx(5.0))
        assert {box.label for box in converted.boxes(t)} == {"vehicle", "sign"}  # type 0 skipped
    assert converted.track_ids == ["car", "sign-0", "sign-1"]
    assert converted.metadata["skipped_labels"] == 3


def test_camera_matches_waymo_projection(converted):
    """Project through the recorded camera in OpenCV axes and through Waymo's own camera model; the
    scene's pinhole camera puts each point where the undistortion moves Waymo's projection."""
    points_world = np.array([[20.0, 2.0, 1.0], [12.0, -3.0, 0.0], [30.0, 0.5, 3.0]])
    fu, fv, cu, cv, k1, k2, p1, p2, k3 = INTRINSIC
    recorded_K, recorded_distortion = (np.array(v) for v in converted.metadata["recorded_camera"].values())
    undistortion = Undistortion.of_camera(recorded_K, recorded_distortion, converted.width, converted.height)
    np.testing.assert_array_equal(converted.distortion, np.zeros(5))
    for t in range(converted.num_frames):
        world_to_cam = world_to_camera(converted.cam_to_world[t])
        uv, z = project_points(points_world, recorded_K, world_to_cam, recorded_distortion)
        pinhole_uv, _ = project_points(points_world, converted.K, world_to_cam)
        # not the second point: near this small test camera's edge its strong distortion folds back
        # (the radius stops growing), so a distorted position there has no unique inverse
        np.testing.assert_allclose(undistortion.points(uv[[0, 2]]), pinhole_uv[[0, 2]], atol=1e-6)
        # Waymo: camera frame x forward, y left, z up; image coordinates (-y/x, -z/x), OpenCV distortion.
        world_to_waymo_camera = np.linalg.inv(converted.ego_to_world[t] @ CAMERA_EXTRINSIC)
        camera = points_world @ world_to_waymo_camera[:3, :3].T + world_to_waymo_camera[:3, 3]
        x, y = -camera[:, 1] / camera[:, 0], -camera[:, 2] / camera[:, 0]
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        np.testing.assert_allclose(uv, np.stack([fu * xd + cu, fv * yd + cv], axis=1), atol=1e-9)
        np.testing.assert_allclose(z, camera[:, 0], atol=1e-9)


def test_lidar_ground_points(converted):
    downward = INCLINATIONS[INCLINATIONS < 0]
    for t in range(converted.num_frames):
        points = converted.lidar(t).astype(np.float64)  # (N,3) world
        assert points.shape == (len(downward) * RANGE_WIDTH, 3)
        ego = converted.ego_to_world[t]
        vehicle = (points - ego[:3, 3]) @ ego[:3, :3]  # back into this frame's vehicle frame
        if t == 1:  # frame 3: the per-pixel poses put the car PIXEL_POSE_SHIFT further in the global frame
            vehicle -= PIXEL_POSE_SHIFT @ vehicle_to_global(3)[:3, :3]
        np.testing.assert_allclose(vehicle[:, 2], 0.0, atol=2e-4)  # on the ground
        offset = vehicle[:, :2] - LASER_EXTRINSIC[:2, 3]
        distances = np.hypot(*offset.T).reshape(len(downward), RANGE_WIDTH)  # rows from the highest beam down
        expected = LASER_HEIGHT / np.tan(-downward[::-1])
        # float32 range images and pixel poses far from the global origin: millimetre accuracy
        np.testing.assert_allclose(distances, np.broadcast_to(expected[:, None], distances.shape), atol=1e-3)
        # Columns sweep the azimuth from +pi (column 0, behind) down to -pi in the vehicle frame,
        # whatever the laser's yaw on the car: column W/2 looks forward, column W/4 to the left.
        azimuth = np.arctan2(offset[:, 1], offset[:, 0]).reshape(len(downward), RANGE_WIDTH)
        column_centres = np.pi * (1 - (2 * np.arange(RANGE_WIDTH) + 1) / RANGE_WIDTH)
        np.testing.assert_allclose(np.angle(np.exp(1j * (azimuth - column_centres))), 0.0, atol=1e-4)
        assert abs(azimuth[0, RANGE_WIDTH // 2]) < 2 * np.pi / RANGE_WIDTH
        assert azimuth[0, RANGE_WIDTH // 4] == pytest.approx(np.pi / 2, abs=2 * np.pi / RANGE_WIDTH)


def test_map_polylines(converted):
    expected = map_points_world(2)
    kinds = [polyline.kind for polyline in converted.map_polylines]
    assert kinds == ["lane_center", "road_edge", "crosswalk"]
    for polyline in converted.map_polylines[:2]:
        np.testing.assert_allclose(polyline.points, expected, atol=1e-6)
    crosswalk = converted.map_polylines[2].points
    np.testing.assert_allclose(crosswalk, np.concatenate([expected[:3], expected[:1]]), atol=1e-6)  # closed


def test_whole_segment_and_second_camera(tmp_path):
    path = write_segment(tmp_path / "segment.tfrecord")
    scene = load_scene(convert_waymo(path, tmp_path / "all"))
    assert scene.num_frames == NUM_FRAMES
    np.testing.assert_allclose(scene.map_polylines[0].points, map_points_world(0), atol=1e-6)
    with pytest.raises(ConversionError, match=r"frame 0 has no FRONT_LEFT camera image"):
        convert_waymo(path, tmp_path / "left", camera="FRONT_LEFT")
    with pytest.raises(ConversionError, match=r"frame 0 has no SIDE_LEFT camera calibration"):
        convert_waymo(path, tmp_path / "side", camera="SIDE_LEFT")
    with pytest.raises(ConversionError, match="unknown camera"):
        convert_waymo(path, tmp_path / "rear", camera="REAR")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["all", "segment.tfrecord"]


@pytest.mark.parametrize(
    ("start", "end", "message"),
    [
        (6, None, r"frame range 6\.\.\(end\) is outside the file, which holds 6 frames \(0\.\.5\)"),
        (4, 6, r"frame range 4\.\.6 is outside the file"),
        (-1, 3, "--start must be >= 0"),
        (3, 2, r"--end \(2\) must not be before --start \(3\)"),
    ],
)
def test_bad_ranges(tmp_path, start, end, message):
    path = write_segment(tmp_path / "segment.tfrecord")
    with pytest.raises(ConversionError, match=message):
        convert_waymo(path, tmp_path / "scene", start=start, end=end)
    assert [p.name for p in tmp_path.iterdir()] == ["segment.tfrecord"]


def test_record_that_is_not_a_frame(tmp_path):
    path = tmp_path / "not_frames.tfrecord"
    write_records(path, [b"\xff\xff\xff"])  # valid TFRecord, invalid protobuf
    with pytest.raises(ConversionError, match=r"record 0 is not a Waymo Frame protobuf"):
        convert_waymo(path, tmp_path / "scene")
    assert not (tmp_path / "scene").exists()


def test_image_size_must_match_calibration(tmp_path):
    frame = schema.Frame.FromString(make_frame(0, 0))
    frame.context.camera_calibrations[0].width = WIDTH + 1
    path = tmp_path / "bad_size.tfrecord"
    write_records(path, [frame.SerializeToString()])
    message = rf"camera image is {WIDTH}x{HEIGHT} but its calibration says {WIDTH + 1}x{HEIGHT}"
    with pytest.raises(ConversionError, match=message):
        convert_waymo(path, tmp_path / "scene")


def test_calibration_comes_from_the_first_selected_frame(tmp_path):
    records = [make_frame(t, 0) for t in range(3)]
    later = schema.Frame.FromString(records[2])
    later.ClearField("context")  # only the first selected frame needs the calibration
    records[2] = later.SerializeToString()
    path = tmp_path / "segment.tfrecord"
    write_records(path, records)
    scene = load_scene(convert_waymo(path, tmp_path / "scene", start=1))
    assert scene.num_frames == 2
    assert len(scene.lidar(1)) == len(scene.lidar(0)) > 0


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        ("no_laser_calibration", "has a TOP range image but the segment has no TOP laser calibration"),
        ("not_zlib", "TOP range image cannot be decoded"),
    ],
)
def test_bad_range_image(tmp_path, damage, message):
    frame = schema.Frame.FromString(make_frame(0, 0))
    if damage == "no_laser_calibration":
        frame.context.ClearField("laser_calibrations")
    else:
        frame.lasers[0].ri_return1.range_image_compressed = b"not zlib data"
    path = tmp_path / f"{damage}.tfrecord"
    write_records(path, [frame.SerializeToString()])
    with pytest.raises(ConversionError, match=rf"frame 0.*{message}"):
        convert_waymo(path, tmp_path / "scene")
    assert not (tmp_path / "scene").exists()


def test_timestamps_must_increase(tmp_path):
    path = tmp_path / "repeated.tfrecord"
    write_records(path, [make_frame(0, 0), make_frame(0, 0)])
    with pytest.raises(ConversionError, match=r"frame 1: timestamp \d+ us does not follow the previous frame's"):
        convert_waymo(path, tmp_path / "scene")
