"""The converter on a real Waymo frame (``../shared/data/waymo/pvps_data_one_frame.tfrecord``).

The truth is Waymo's own ``projected_lidar_labels`` for the FRONT camera: the smallest image
rectangle around the projected corners of each 3D laser label (with lens distortion), clamped
to the image. Corrupted copies of the file are written into tmp_path, never into the project.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from recondreamer import cli
from recondreamer.errors import ConversionError
from recondreamer.scene import load_scene
from recondreamer.scene.cameras import project_points, world_to_camera
from recondreamer.sources.waymo import schema
from recondreamer.sources.waymo.convert import convert_waymo
from recondreamer.sources.waymo.tfrecord import iter_records

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


def _front_projected_labels(raw_frame) -> dict:
    """Waymo's FRONT projected labels by laser label id (projected ids carry a camera suffix)."""
    front = [labels for labels in raw_frame.projected_lidar_labels if labels.name == schema.CAMERA_NAMES["FRONT"]]
    return {label.id.removesuffix("_FRONT"): label.box for label in front[0].labels}


def _box_fit_errors(scene, projected: dict, with_distortion: bool) -> tuple[np.ndarray, np.ndarray]:
    """Centre and size errors (pixels) of the clamped box fits of the projected corners, per matched box."""
    world_to_cam = world_to_camera(scene.cam_to_world[0])
    image_size = np.array([scene.width, scene.height])
    centre_errors, size_errors = [], []
    for box in scene.boxes(0):
        if box.track_id not in projected:
            continue
        distortion = scene.distortion if with_distortion else None
        uv, z = project_points(box.corners(), scene.K, world_to_cam, distortion)
        assert np.all(z > 0), f"box {box.track_id} has corners behind the camera yet Waymo projects it"
        low, high = np.clip(uv.min(0), 0, image_size), np.clip(uv.max(0), 0, image_size)
        truth = projected[box.track_id]  # centre_x/y; length = extent along u, width = extent along v
        centre_errors.append(np.hypot(*((low + high) / 2 - [truth.center_x, truth.center_y])))
        size_errors.append(np.abs((high - low) - [truth.length, truth.width]).max())
    return np.array(centre_errors), np.array(size_errors)


def test_box_corners_reproduce_waymo_projected_labels(scene, raw_frame):
    projected = _front_projected_labels(raw_frame)
    assert len(projected) == 12
    centre_errors, size_errors = _box_fit_errors(scene, projected, with_distortion=True)
    assert len(centre_errors) == 12  # every projected label found its converted box
    assert np.median(centre_errors) < 1.0, centre_errors
    assert np.median(size_errors) < 1.0, size_errors
    assert centre_errors.max() < 0.5, centre_errors  # measured: median 0.06 px, max 0.15 px


def test_distortion_is_needed_for_the_border_boxes(scene, raw_frame):
    """Dropping the distortion moves boxes near the image border by more than a pixel."""
    projected = _front_projected_labels(raw_frame)
    with_distortion, _ = _box_fit_errors(scene, projected, with_distortion=True)
    without_distortion, _ = _box_fit_errors(scene, projected, with_distortion=False)
    assert without_distortion.max() > 1.0 > 3 * with_distortion.max()


def test_converted_scene_content(scene, raw_frame):
    assert (scene.num_frames, scene.width, scene.height, scene.source) == (1, 1920, 1280, "waymo")
    calibration = [c for c in raw_frame.context.camera_calibrations if c.name == 1][0]
    fu, fv, cu, cv, *distortion = calibration.intrinsic
    np.testing.assert_allclose(scene.K, [[fu, 0, cu], [0, fv, cv], [0, 0, 1]])
    np.testing.assert_allclose(scene.distortion, distortion)
    # OpenCV z (optical axis) = Waymo camera x; OpenCV x (right) = -Waymo camera y.
    extrinsic = np.array(calibration.extrinsic.transform).reshape(4, 4)
    np.testing.assert_allclose(scene.cam_to_ego[:3, 2], extrinsic[:3, 0])
    np.testing.assert_allclose(scene.cam_to_ego[:3, 0], -extrinsic[:3, 1])
    np.testing.assert_allclose(scene.cam_to_ego[:3, 3], extrinsic[:3, 3])
    np.testing.assert_allclose(scene.ego_to_world[0], np.eye(4), atol=1e-12)
    np.testing.assert_array_equal(scene.timestamps, [0.0])
    jpeg = [image.image for image in raw_frame.images if image.name == 1][0]
    assert (scene.path / "images" / "000.jpg").read_bytes() == jpeg  # original bytes, no re-encoding
    assert scene.image(0).shape == (1280, 1920, 3)
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
    assert scene.K[0, 0] == pytest.approx(2056.3902134214923)
    bad = _corrupt(tmp_path, "random_bytes")
    assert cli.main(["convert-waymo", str(bad), "--out", str(tmp_path / "bad")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a TFRecord file" in err[0]
    assert not (tmp_path / "bad").exists()
