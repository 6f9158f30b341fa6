"""The converter on a real Waymo frame (``../shared/data/waymo/pvps_data_one_frame.tfrecord``).

The truth is Waymo's own ``projected_lidar_labels`` of each camera: the smallest image rectangle
around the projected corners of each 3D laser label (with lens distortion), clamped to the image;
for the converter's undistorted images, those rectangles moved into the undistorted image
(benchmarks/waymo_undistortion.py prints the whole table). Corrupted copies of the file are
written into tmp_path, never into the project.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from recondreamer import cli
from recondreamer.errors import ConversionError
from recondreamer.scene import load_scene
from recondreamer.scene.cameras import distort_normalized
from recondreamer.sources.waymo import schema
from recondreamer.sources.waymo.convert import convert_waymo
from recondreamer.sources.waymo.tfrecord import iter_records
from recondreamer.sources.waymo.undistort import Undistortion, box_fit_errors, projected_labels, undistorted_rectangle

FIXTURE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "waymo" / "pvps_data_one_frame.tfrecord"

pytestmark = pytest.mark.skipif(
    not FIXTURE.is_file(), reason=f"Waymo fixture not found at {FIXTURE} (../shared/data is not part of this checkout)"
)


@pytest.fixture(scope="module")
def raw_frame():
    return schema.Frame.FromString(next(iter_records(FIXTURE)))


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return load_scene(convert_waymo(FIXTURE, tmp_path_factory.mktemp("waymo") / "scene"))


@pytest.fixture(scope="module")
def camera_errors(raw_frame, tmp_path_factory):
    """Per camera: the box errors (pixels, by label id) of the recorded camera with and without its
    distortion and of the undistorted scene's pinhole camera, and the ids of the labels inside the image."""
    found = {}
    for camera, number in schema.CAMERA_NAMES.items():
        converted = load_scene(convert_waymo(FIXTURE, tmp_path_factory.mktemp("waymo") / camera, camera=camera))
        recorded = converted.metadata["recorded_camera"]
        K, distortion = np.array(recorded["K"]), np.array(recorded["distortion"])
        labels = projected_labels(raw_frame, number, camera)
        undistortion = Undistortion.of_camera(K, distortion, converted.width, converted.height)
        moved = {track: undistorted_rectangle(undistortion, rectangle) for track, rectangle in labels.items()}
        size = np.array([converted.width, converted.height])
        inside = [track for track, r in labels.items() if min(r[:2]) >= 1 and np.all(r[2:] <= size - 1)]
        found[camera] = {
            "distorted": box_fit_errors(converted, labels, K, distortion),
            "recorded pinhole": box_fit_errors(converted, labels, K, None),
            "undistorted": box_fit_errors(converted, moved, converted.K, converted.distortion),
            "labels": labels,
            "inside": inside,
        }
    return found


def _centre_errors(per_box: dict, tracks) -> np.ndarray:
    return np.array([per_box[track][0] for track in tracks])


def test_every_projected_label_finds_its_box_in_every_camera(camera_errors):
    counts = {camera: len(found["labels"]) for camera, found in camera_errors.items()}
    assert counts == {"FRONT": 12, "FRONT_LEFT": 18, "FRONT_RIGHT": 12, "SIDE_LEFT": 6, "SIDE_RIGHT": 14}
    for found in camera_errors.values():
        assert set(found["undistorted"]) == set(found["distorted"]) == set(found["labels"])


def test_recorded_camera_with_distortion_reproduces_waymo_labels_inside_the_image(camera_errors):
    for camera, found in camera_errors.items():
        errors = _centre_errors(found["distorted"], found["inside"])
        assert errors.max() < 0.5, (camera, errors)  # measured: at most 0.33 px


def test_undistorted_scene_with_its_pinhole_camera_reproduces_the_undistorted_labels(camera_errors):
    for camera, found in camera_errors.items():
        errors = _centre_errors(found["undistorted"], found["inside"])
        # measured: medians 0.05-0.36 px; at most 2.15 px, for a box filling a quarter of the image,
        # whose label's outline bends when undistorted
        assert np.median(errors) < 0.5 and errors.max() < 3.0, (camera, errors)


def test_a_pinhole_camera_fits_undistorted_images_better_than_recorded_ones(camera_errors):
    """What the converter is for: the pinhole model (the rasterizer's) on the recorded images misses
    Waymo's labels by more than on the undistorted ones."""
    recorded = np.concatenate([_centre_errors(f["recorded pinhole"], f["inside"]) for f in camera_errors.values()])
    undistorted = np.concatenate([_centre_errors(f["undistorted"], f["inside"]) for f in camera_errors.values()])
    assert np.median(undistorted) < 0.5 * np.median(recorded), (np.median(undistorted), np.median(recorded))
    assert recorded.max() > 4.0  # measured: 4.39 px


def test_the_remap_samples_where_the_distortion_model_puts_each_pinhole_pixel(scene):
    """map_x/map_y of every pixel agree with the scene format's own distortion model (cameras.py)."""
    recorded = scene.metadata["recorded_camera"]
    undistortion = Undistortion.of_camera(np.array(recorded["K"]), np.array(recorded["distortion"]), scene.width, scene.height)
    rows, cols = np.mgrid[0 : scene.height : 37, 0 : scene.width : 53]
    pixels = np.stack([cols.ravel(), rows.ravel(), np.ones(rows.size)], 1).astype(np.float64)
    normalized = (pixels @ np.linalg.inv(undistortion.pinhole_K).T)[:, :2]
    distorted = np.concatenate([distort_normalized(normalized, undistortion.distortion), np.ones((rows.size, 1))], 1) @ undistortion.K[:2].T
    np.testing.assert_allclose(undistortion.map_x[rows.ravel(), cols.ravel()], distorted[:, 0], atol=2e-3)
    np.testing.assert_allclose(undistortion.map_y[rows.ravel(), cols.ravel()], distorted[:, 1], atol=2e-3)
    # and the sparse inverse (undistortPoints) takes those positions back to the pinhole pixels
    np.testing.assert_allclose(undistortion.points(distorted), pixels[:, :2], atol=1e-4)


def test_converted_scene_content(scene, raw_frame):
    assert (scene.num_frames, scene.width, scene.height, scene.source) == (1, 1920, 1280, "waymo")
    calibration = [c for c in raw_frame.context.camera_calibrations if c.name == 1][0]
    fu, fv, cu, cv, *distortion = calibration.intrinsic
    np.testing.assert_allclose(scene.metadata["recorded_camera"]["K"], [[fu, 0, cu], [0, fv, cv], [0, 0, 1]])
    np.testing.assert_allclose(scene.metadata["recorded_camera"]["distortion"], distortion)
    undistortion = Undistortion.of_camera(np.array([[fu, 0, cu], [0, fv, cv], [0, 0, 1]]), np.array(distortion), 1920, 1280)
    np.testing.assert_allclose(scene.K, undistortion.pinhole_K)
    np.testing.assert_array_equal(scene.distortion, np.zeros(5))
    assert np.abs(np.diag(scene.K)[:2] / np.array([fu, fv]) - 1).max() < 0.01  # the pinhole camera is nearly the recorded one
    # OpenCV z (optical axis) = Waymo camera x; OpenCV x (right) = -Waymo camera y.
    extrinsic = np.array(calibration.extrinsic.transform).reshape(4, 4)
    np.testing.assert_allclose(scene.cam_to_ego[:3, 2], extrinsic[:3, 0])
    np.testing.assert_allclose(scene.cam_to_ego[:3, 0], -extrinsic[:3, 1])
    np.testing.assert_allclose(scene.cam_to_ego[:3, 3], extrinsic[:3, 3])
    np.testing.assert_allclose(scene.ego_to_world[0], np.eye(4), atol=1e-12)
    np.testing.assert_array_equal(scene.timestamps, [0.0])
    jpeg = [image.image for image in raw_frame.images if image.name == 1][0]
    recorded = np.asarray(Image.open(io.BytesIO(jpeg)).convert("RGB"))
    expected = undistortion.image(recorded).astype(np.float64)
    assert scene.image(0).shape == (1280, 1920, 3)
    mse = np.mean((scene.image(0).astype(np.float64) - expected) ** 2)
    assert 10 * np.log10(255**2 / mse) > 35  # the undistorted image, re-encoded as JPEG (quality 95)
    assert scene.lidar(0).shape == (0, 3)  # the fixture's range images were stripped
    assert scene.map_polylines == []

    labels = {label.id: label for label in raw_frame.laser_labels}
    boxes = scene.boxes(0)
    assert len(boxes) == len(labels) == 75
    names = {1: "vehicle", 2: "pedestrian", 3: "sign", 4: "cyclist"}
    for box in boxes:
        label = labels[box.track_id]
        assert box.label == names[label.type]
        np.testing.assert_allclose(box.size, [label.box.length, label.box.width, label.box.height])
        centre = [label.box.center_x, label.box.center_y, label.box.center_z]
        np.testing.assert_allclose(box.obj_to_world[:3, 3], centre)
        np.testing.assert_allclose(np.arctan2(box.obj_to_world[1, 0], box.obj_to_world[0, 0]), label.box.heading)
        assert box.num_points == label.num_lidar_points_in_box  # this file predates num_top_lidar_points_in_box
        assert box.speed == pytest.approx(np.hypot(label.metadata.speed_x, label.metadata.speed_y))
    assert sorted(scene.track_ids) == sorted(labels)


def _corrupt(tmp_path: Path, kind: str) -> Path:
    data = bytearray(FIXTURE.read_bytes())
    if kind == "truncated":
        data = data[: len(data) // 2]
    elif kind == "flipped_data_byte":
        data[len(data) // 2] ^= 0x40
    elif kind == "flipped_crc_byte":
        data[-2] ^= 0x01  # inside the data CRC at the end of the record
    elif kind == "random_bytes":
        data = bytearray(np.random.default_rng(0).integers(0, 256, size=4096, dtype=np.uint8).tobytes())
    path = tmp_path / f"{kind}.tfrecord"
    path.write_bytes(bytes(data))
    return path


@pytest.mark.parametrize(
    ("kind", "message"),
    [
        ("truncated", "truncated"),
        ("flipped_data_byte", "data checksum mismatch in record 0"),
        ("flipped_crc_byte", "data checksum mismatch in record 0"),
        ("random_bytes", "not a TFRecord file"),
    ],
)
def test_bad_file_raises_and_leaves_nothing(tmp_path, kind, message):
    path = _corrupt(tmp_path, kind)
    out = tmp_path / "scenes" / "scene"
    with pytest.raises(ConversionError, match=message) as error:
        convert_waymo(path, out)
    assert str(path) in str(error.value)
    assert not out.exists()
    assert not (tmp_path / "scenes").exists() or list((tmp_path / "scenes").iterdir()) == []


@pytest.mark.parametrize(("start", "end"), [(1, None), (0, 1), (3, 7)])
def test_range_outside_the_file(tmp_path, start, end):
    out = tmp_path / "scene"
    with pytest.raises(ConversionError, match=r"outside the file, which holds 1 frames"):
        convert_waymo(FIXTURE, out, start=start, end=end)
    assert list(tmp_path.iterdir()) == []


def test_failed_conversion_keeps_an_existing_scene(tmp_path):
    out = tmp_path / "scene"
    convert_waymo(FIXTURE, out)
    before = sorted(p.relative_to(out) for p in out.rglob("*"))
    with pytest.raises(ConversionError):
        convert_waymo(_corrupt(tmp_path, "truncated"), out)
    assert sorted(p.relative_to(out) for p in out.rglob("*")) == before
    load_scene(out)


def test_cli(tmp_path, capsys, monkeypatch):
    # Only this package's sub-commands: the test does not depend on other stages' modules.
    monkeypatch.setattr(cli, "COMMAND_MODULES", ("recondreamer.sources.waymo.commands",))
    out = tmp_path / "scene"
    assert cli.main(["convert-waymo", str(FIXTURE), "--out", str(out), "--camera", "FRONT_LEFT"]) == 0
    scene = load_scene(out)
    assert scene.metadata["camera"] == "FRONT_LEFT"
    assert scene.metadata["recorded_camera"]["K"][0][0] == pytest.approx(2056.3902134214923)
    bad = _corrupt(tmp_path, "random_bytes")
    assert cli.main(["convert-waymo", str(bad), "--out", str(tmp_path / "bad")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a TFRecord file" in err[0]
    assert not (tmp_path / "bad").exists()
