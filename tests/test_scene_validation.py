"""Scene validation: every kind of corruption gives a SceneFormatError naming the file and the problem."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from recondreamer.errors import SceneFormatError
from recondreamer.scene import load_scene, write_scene
from scene_fixtures import HEIGHT, WIDTH, make_scene_data


@pytest.fixture(scope="module")
def written_scene(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("valid") / "scene"
    write_scene(path, make_scene_data())
    return path


@pytest.fixture
def scene_copy(written_scene, tmp_path) -> Path:
    import shutil

    target = tmp_path / "scene"
    shutil.copytree(written_scene, target)
    return target


def edit_json(file: Path, change: Callable[[dict], None]) -> None:
    obj = json.loads(file.read_text())
    change(obj)
    file.write_text(json.dumps(obj))


def scale_rotation(matrix: list) -> None:
    for row in matrix[:3]:
        row[0] *= 1.1


def set_nested(keys: tuple, value) -> Callable[[dict], None]:
    def change(obj):
        for key in keys[:-1]:
            obj = obj[key]
        obj[keys[-1]] = value

    return change


def image_of(width: int, height: int, mode: str = "RGB") -> Callable[[Path], None]:
    def write(file: Path) -> None:
        Image.new(mode, (width, height)).save(file)

    return write


# (case id, file relative to the scene, corruption, expected fragment of the message)
LOAD_CASES = [
    ("missing image", "images/001.png", Path.unlink, "missing file"),
    ("missing depth", "depth/002.npy", Path.unlink, "missing file"),
    ("missing semantics", "semantics/000.png", Path.unlink, "missing file"),
    ("missing sky mask", "sky_masks/001.png", Path.unlink, "missing file"),
    ("missing lidar", "lidar/001.npy", Path.unlink, "missing file"),
    ("missing novel image", "novel/shift@3/images/002.png", Path.unlink, "missing file"),
    ("missing novel instances", "novel/shift@3/instances/000.png", Path.unlink, "missing file"),
    ("missing scene.json", "scene.json", Path.unlink, "missing file"),
    ("missing boxes.json", "boxes.json", Path.unlink, "missing file"),
    ("missing map.json", "map.json", Path.unlink, "missing file"),
    ("wrong image width", "images/002.png", image_of(WIDTH - 1, HEIGHT), f"wrong image size {WIDTH - 1}x{HEIGHT}"),
    ("wrong image height", "images/000.png", image_of(WIDTH, HEIGHT + 2), "wrong image size"),
    ("wrong novel semantics size", "novel/shift@3/semantics/001.png", image_of(8, 8, "L"), "wrong image size"),
    ("grey image", "images/001.png", image_of(WIDTH, HEIGHT, "L"), "wrong pixel mode"),
    ("not an image", "images/001.png", lambda f: f.write_text("hello"), "not a readable image"),
    (
        "depth wrong shape",
        "depth/001.npy",
        lambda f: np.save(f, np.zeros((HEIGHT, WIDTH + 1), np.float32)),
        "depth must be",
    ),
    ("depth wrong dtype", "depth/001.npy", lambda f: np.save(f, np.zeros((HEIGHT, WIDTH), np.float64)), "float32"),
    ("lidar wrong shape", "lidar/000.npy", lambda f: np.save(f, np.zeros((5, 4), np.float32)), "(N, 3) float32"),
    ("lidar not npy", "lidar/000.npy", lambda f: f.write_text("x"), "not a readable .npy"),
    ("invalid json", "scene.json", lambda f: f.write_text("{"), "not valid JSON"),
    (
        "unknown format version",
        "scene.json",
        lambda f: edit_json(f, set_nested(("format_version",), 99)),
        "unknown format version 99",
    ),
    (
        "missing format version",
        "scene.json",
        lambda f: edit_json(f, lambda o: o.pop("format_version")),
        "unknown format version None",
    ),
    ("missing camera", "scene.json", lambda f: edit_json(f, lambda o: o.pop("camera")), "missing field 'camera'"),
    ("missing K", "scene.json", lambda f: edit_json(f, lambda o: o["camera"].pop("K")), "missing field 'camera.K'"),
    (
        "width not int",
        "scene.json",
        lambda f: edit_json(f, set_nested(("camera", "width"), "32")),
        "'camera.width' must be int",
    ),
    (
        "too few timestamps",
        "scene.json",
        lambda f: edit_json(f, lambda o: o["timestamps"].pop()),
        "frame-count mismatch: 2 timestamps",
    ),
    (
        "too few ego poses",
        "scene.json",
        lambda f: edit_json(f, lambda o: o["ego_to_world"].pop()),
        "frame-count mismatch: 2 ego_to_world",
    ),
    (
        "timestamps not increasing",
        "scene.json",
        lambda f: edit_json(f, set_nested(("timestamps",), [0.0, 0.2, 0.1])),
        "strictly increasing",
    ),
    (
        "NaN in K",
        "scene.json",
        lambda f: edit_json(f, lambda o: o["camera"]["K"][0].__setitem__(2, float("nan"))),
        "camera.K: non-finite",
    ),
    (
        "infinite timestamp",
        "scene.json",
        lambda f: edit_json(f, lambda o: o["timestamps"].__setitem__(2, float("inf"))),
        "timestamps: non-finite",
    ),
    (
        "NaN in ego pose",
        "scene.json",
        lambda f: edit_json(f, lambda o: o["ego_to_world"][1][0].__setitem__(3, float("nan"))),
        "ego_to_world: non-finite",
    ),
    (
        "negative fx",
        "scene.json",
        lambda f: edit_json(f, lambda o: o["camera"]["K"][0].__setitem__(0, -5.0)),
        "fx, fy > 0",
    ),
    (
        "distortion length",
        "scene.json",
        lambda f: edit_json(f, set_nested(("camera", "distortion"), [0.0] * 4)),
        "expected shape (5)",
    ),
    (
        "scaled ego rotation",
        "scene.json",
        lambda f: edit_json(f, lambda o: scale_rotation(o["ego_to_world"][1])),
        "ego_to_world[1]: rotation is not orthonormal",
    ),
    (
        "scaled camera rotation",
        "scene.json",
        lambda f: edit_json(f, lambda o: scale_rotation(o["camera"]["cam_to_ego"])),
        "camera.cam_to_ego: rotation is not orthonormal",
    ),
    (
        "mirrored camera",
        "scene.json",
        lambda f: edit_json(f, lambda o: [row.__setitem__(0, -row[0]) for row in o["camera"]["cam_to_ego"][:3]]),
        "det +1",
    ),
    (
        "bad last row",
        "scene.json",
        lambda f: edit_json(f, lambda o: o["ego_to_world"][2][3].__setitem__(0, 1.0)),
        "last row",
    ),
    (
        "duplicate track ids",
        "scene.json",
        lambda f: edit_json(f, set_nested(("track_ids",), ["a", "a"])),
        "distinct strings",
    ),
    (
        "unknown channel",
        "scene.json",
        lambda f: edit_json(f, lambda o: o["channels"].append("normals")),
        "unknown channel 'normals'",
    ),
    (
        "bad novel name",
        "scene.json",
        lambda f: edit_json(f, lambda o: o["novel"].__setitem__("sideways", {"channels": []})),
        "unknown trajectory 'sideways'",
    ),
    (
        "unknown image format",
        "scene.json",
        lambda f: edit_json(f, set_nested(("image_format",), "tiff")),
        "image_format must be",
    ),
    (
        "boxes frame count",
        "boxes.json",
        lambda f: edit_json(f, lambda o: o["frames"].pop()),
        "frame-count mismatch: 2 frames of boxes",
    ),
    (
        "zero box size",
        "boxes.json",
        lambda f: edit_json(f, lambda o: o["frames"][1][0]["size"].__setitem__(1, 0.0)),
        "frames[1][0].size: box sizes must be positive",
    ),
    (
        "negative box size",
        "boxes.json",
        lambda f: edit_json(f, lambda o: o["frames"][2][1]["size"].__setitem__(2, -1.0)),
        "frames[2][1].size",
    ),
    (
        "NaN box size",
        "boxes.json",
        lambda f: edit_json(f, lambda o: o["frames"][0][0]["size"].__setitem__(0, float("nan"))),
        "non-finite",
    ),
    (
        "unknown box label",
        "boxes.json",
        lambda f: edit_json(f, lambda o: o["frames"][0][1].__setitem__("label", "horse")),
        "unknown box label 'horse'",
    ),
    (
        "box rotation",
        "boxes.json",
        lambda f: edit_json(f, lambda o: scale_rotation(o["frames"][2][0]["obj_to_world"])),
        "frames[2][0].obj_to_world: rotation is not orthonormal",
    ),
    (
        "negative point count",
        "boxes.json",
        lambda f: edit_json(f, lambda o: o["frames"][0][0].__setitem__("num_points", -1)),
        "num_points",
    ),
    (
        "duplicate box track",
        "boxes.json",
        lambda f: edit_json(f, lambda o: o["frames"][1].append(o["frames"][1][0])),
        "appears more than once",
    ),
    (
        "unknown polyline kind",
        "map.json",
        lambda f: edit_json(f, lambda o: o["polylines"][1].__setitem__("kind", "rail")),
        "unknown polyline kind 'rail'",
    ),
    (
        "one-point polyline",
        "map.json",
        lambda f: edit_json(f, lambda o: o["polylines"][0].__setitem__("points", [[0.0, 0.0, 0.0]])),
        "at least 2 points",
    ),
    (
        "NaN polyline point",
        "map.json",
        lambda f: edit_json(f, lambda o: o["polylines"][0]["points"][1].__setitem__(2, float("nan"))),
        "polylines[0].points: non-finite",
    ),
    (
        "2D polyline",
        "map.json",
        lambda f: edit_json(f, lambda o: o["polylines"][0].__setitem__("points", [[0.0, 0.0], [1.0, 1.0]])),
        "expected shape (N, 3)",
    ),
]


@pytest.mark.parametrize(
    "relative, corrupt, fragment", [case[1:] for case in LOAD_CASES], ids=[case[0] for case in LOAD_CASES]
)
def test_corruption_is_reported_on_load_naming_the_file(scene_copy, relative, corrupt, fragment):
    file = scene_copy / relative
    corrupt(file)
    with pytest.raises(SceneFormatError) as error:
        load_scene(scene_copy)
    message = str(error.value)
    assert str(file) in message
    assert fragment in message


# Value problems inside per-frame data are found when the frame is read (and by check_all).
DATA_CASES = [
    (
        "NaN lidar",
        "lidar/001.npy",
        lambda f: np.save(f, np.array([[0.0, np.nan, 1.0]], np.float32)),
        "non-finite",
        lambda s: s.lidar(1),
    ),
    (
        "infinite depth",
        "depth/000.npy",
        lambda f: np.save(f, np.full((HEIGHT, WIDTH), np.inf, np.float32)),
        "non-finite",
        lambda s: s.depth(0),
    ),
    (
        "negative depth",
        "novel/shift@3/depth/002.npy",
        lambda f: np.save(f, np.full((HEIGHT, WIDTH), -1.0, np.float32)),
        "negative",
        lambda s: s.novel_depth("shift@3", 2),
    ),
    (
        "instance id beyond tracks",
        "instances/001.png",
        lambda f: Image.fromarray(np.full((HEIGHT, WIDTH), 7, np.uint16)).save(f),
        "instance id 7",
        None,
    ),
    (
        "semantic id beyond classes",
        "semantics/002.png",
        lambda f: Image.fromarray(np.full((HEIGHT, WIDTH), 200, np.uint8)).save(f),
        "semantic id 200",
        None,
    ),
]


@pytest.mark.parametrize(
    "relative, corrupt, fragment, read", [case[1:] for case in DATA_CASES], ids=[case[0] for case in DATA_CASES]
)
def test_bad_values_are_reported_when_read_and_by_check_all(scene_copy, relative, corrupt, fragment, read):
    file = scene_copy / relative
    corrupt(file)
    scene = load_scene(scene_copy)
    if read is not None:
        with pytest.raises(SceneFormatError, match=fragment) as error:
            read(scene)
        assert str(file) in str(error.value)
    with pytest.raises(SceneFormatError, match=fragment) as error:
        scene.check_all()
    assert str(file) in str(error.value)


def test_not_a_directory(tmp_path):
    with pytest.raises(SceneFormatError, match="not a scene directory"):
        load_scene(tmp_path / "nowhere")


def test_valid_scene_loads(written_scene):
    load_scene(written_scene).check_all()
