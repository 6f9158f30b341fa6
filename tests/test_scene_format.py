"""Scene format: round trip, lazy reading, image formats, atomic writing."""

from __future__ import annotations

import io
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from recondreamer.errors import SceneFormatError
from recondreamer.scene import FORMAT_VERSION, load_scene, write_scene
from recondreamer.scene.types import SEMANTIC_CLASSES
from scene_fixtures import FRAMES, HEIGHT, WIDTH, make_scene_data


def test_round_trip_restores_every_field(tmp_path):
    data = make_scene_data()
    write_scene(tmp_path / "scene", data)
    scene = load_scene(tmp_path / "scene")

    assert (scene.scene_id, scene.source, scene.num_frames) == ("tiny", "test", FRAMES)
    assert (scene.width, scene.height) == (WIDTH, HEIGHT)
    assert scene.metadata == {"seed": 0, "note": "hand-built"}
    np.testing.assert_array_equal(scene.K, data.K)
    np.testing.assert_array_equal(scene.distortion, data.distortion)
    np.testing.assert_array_equal(scene.cam_to_ego, data.cam_to_ego)
    np.testing.assert_array_equal(scene.ego_to_world, data.ego_to_world)
    np.testing.assert_array_equal(scene.timestamps, data.timestamps)
    np.testing.assert_allclose(scene.cam_to_world, data.ego_to_world @ data.cam_to_ego, atol=1e-12)
    assert scene.track_ids == data.track_ids
    assert scene.semantic_classes == SEMANTIC_CLASSES
    assert scene.novel_trajectories == ("shift@3",)

    for t in range(FRAMES):
        image = scene.image(t)
        assert image.shape == (HEIGHT, WIDTH, 3) and image.dtype == np.uint8
        np.testing.assert_array_equal(image, data.frames.images[t])
        np.testing.assert_array_equal(scene.depth(t), data.frames.depth[t])
        np.testing.assert_array_equal(scene.semantics(t), data.frames.semantics[t])
        assert scene.instances(t).dtype == np.int32
        np.testing.assert_array_equal(scene.instances(t), data.frames.instances[t])
        np.testing.assert_array_equal(scene.sky_mask(t), data.frames.sky_masks[t])
        np.testing.assert_array_equal(scene.lidar(t), data.lidar[t])
        assert scene.lidar(t).dtype == np.float32
        for got, want in zip(scene.boxes(t), data.boxes[t], strict=True):
            assert (got.track_id, got.label, got.num_points, got.speed) == (
                want.track_id,
                want.label,
                want.num_points,
                want.speed,
            )
            np.testing.assert_array_equal(got.size, want.size)
            np.testing.assert_array_equal(got.obj_to_world, want.obj_to_world)
        novel = data.novel["shift@3"]
        np.testing.assert_array_equal(scene.novel_image("shift@3", t), novel.images[t])
        np.testing.assert_array_equal(scene.novel_depth("shift@3", t), novel.depth[t])
        np.testing.assert_array_equal(scene.novel_semantics("shift@3", t), novel.semantics[t])
        np.testing.assert_array_equal(scene.novel_instances("shift@3", t), novel.instances[t])
    for got, want in zip(scene.map_polylines, data.map_polylines, strict=True):
        assert got.kind == want.kind
        np.testing.assert_array_equal(got.points, want.points)
    assert scene.image_path(1) == tmp_path / "scene" / "images" / "001.png"
    scene.check_all()


def test_frame_arrays_are_fresh_and_scene_arrays_read_only(tmp_path):
    write_scene(tmp_path / "scene", make_scene_data())
    scene = load_scene(tmp_path / "scene")
    frame_arrays = (scene.image(0), scene.depth(0), scene.semantics(0), scene.instances(0), scene.sky_mask(0))
    assert all(array.flags.writeable for array in (*frame_arrays, scene.lidar(0), scene.novel_image("shift@3", 0)))
    scene.image(0)[:] = 0
    assert scene.image(0).any()  # the next read is not affected
    with pytest.raises(ValueError):
        scene.cam_to_world[0, 0, 3] = 5.0
    moved = scene.trajectory("original")
    moved[0, 0, 3] = 5.0  # a copy
    assert scene.cam_to_world[0, 0, 3] != 5.0


def test_files_are_plain_and_documented_names(tmp_path):
    write_scene(tmp_path / "scene", make_scene_data())
    root = tmp_path / "scene"
    header = json.loads((root / "scene.json").read_text())
    assert header["format_version"] == FORMAT_VERSION
    with Image.open(root / "images" / "002.png") as image:
        assert image.size == (WIDTH, HEIGHT)
    assert np.load(root / "depth" / "000.npy").shape == (HEIGHT, WIDTH)
    assert (root / "novel" / "shift@3" / "semantics" / "002.png").is_file()
    assert not (root / "novel" / "shift@3" / "sky_masks").exists()
    assert np.load(root / "lidar" / "002.npy").shape == (12, 3)


def test_missing_channels_give_none_and_unknown_novel_names_fail(tmp_path):
    data = make_scene_data()
    data.frames.depth = None
    data.frames.sky_masks = None
    write_scene(tmp_path / "scene", data)
    scene = load_scene(tmp_path / "scene")
    assert scene.depth(0) is None and scene.sky_mask(0) is None
    assert scene.novel_channels("shift@3") == ("depth", "semantics", "instances")
    with pytest.raises(SceneFormatError, match="lane_change"):
        scene.novel_image("lane_change", 0)
    with pytest.raises(IndexError):
        scene.image(FRAMES)


def test_jpeg_scene_keeps_encoded_bytes_and_reencodes_arrays(tmp_path):
    data = make_scene_data()
    smooth = np.tile(np.linspace(0, 255, WIDTH, dtype=np.uint8)[None, :, None], (HEIGHT, 1, 3))
    buffer = io.BytesIO()
    Image.fromarray(smooth).save(buffer, format="JPEG", quality=90)
    data.frames.images[0] = buffer.getvalue()  # already-encoded JPEG: stored as is
    data.frames.images[1] = smooth  # array: encoded by the writer
    png = io.BytesIO()
    Image.fromarray(smooth).save(png, format="PNG")
    data.frames.images[2] = png.getvalue()  # PNG bytes into a JPEG scene: re-encoded
    write_scene(tmp_path / "scene", data, image_format="jpg")
    scene = load_scene(tmp_path / "scene")
    assert scene.image_format == "jpg"
    assert (tmp_path / "scene" / "images" / "000.jpg").read_bytes() == buffer.getvalue()
    assert (tmp_path / "scene" / "images" / "002.jpg").read_bytes()[:2] == b"\xff\xd8"
    for t in range(FRAMES):
        assert np.abs(scene.image(t).astype(int) - smooth).mean() < 3.0


def test_to_data_writes_back_identically(tmp_path):
    write_scene(tmp_path / "a", make_scene_data())
    write_scene(tmp_path / "b", load_scene(tmp_path / "a").to_data())
    files_a = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    files_b = sorted(p.relative_to(tmp_path / "b") for p in (tmp_path / "b").rglob("*") if p.is_file())
    assert files_a == files_b
    for relative in files_a:
        if relative.suffix != ".png":  # PNG encoder output of decoded arrays may differ in bytes
            assert (tmp_path / "a" / relative).read_bytes() == (tmp_path / "b" / relative).read_bytes(), relative


def test_load_reads_headers_only_and_pixels_on_demand(tmp_path):
    write_scene(tmp_path / "scene", make_scene_data())
    image_file = tmp_path / "scene" / "images" / "001.png"
    image_file.write_bytes(image_file.read_bytes()[:60])  # header intact, pixel data cut
    scene = load_scene(tmp_path / "scene")  # headers are fine: loads
    scene.image(0)
    with pytest.raises(SceneFormatError, match="001.png"):
        scene.image(1)
    with pytest.raises(SceneFormatError, match="001.png"):
        scene.check_all()


def test_writer_rejects_frame_count_mismatch_and_bad_arrays(tmp_path):
    data = make_scene_data()
    data.frames.depth = data.frames.depth[:2]
    with pytest.raises(SceneFormatError, match="depth.*frame-count mismatch"):
        write_scene(tmp_path / "scene", data)
    data = make_scene_data()
    data.frames.images[1] = data.frames.images[1].astype(np.float32)
    with pytest.raises(SceneFormatError, match=r"images\[1\]"):
        write_scene(tmp_path / "scene", data)
    data = make_scene_data()
    data.frames.images[2] = data.frames.images[2][:, :-1]
    with pytest.raises(SceneFormatError, match="002.png: wrong image size"):
        write_scene(tmp_path / "scene", data)
    assert not (tmp_path / "scene").exists()
    assert list(tmp_path.iterdir()) == []  # no temporary directory left behind


def test_failed_write_leaves_no_scene_and_keeps_an_existing_one(tmp_path, monkeypatch):
    target = tmp_path / "scene"
    calls = {"n": 0}
    real_save = np.save

    def failing_save(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 4:
            raise OSError("disk full (simulated)")
        return real_save(*args, **kwargs)

    monkeypatch.setattr(np, "save", failing_save)
    with pytest.raises(OSError, match="simulated"):
        write_scene(target, make_scene_data())
    assert not target.exists() and list(tmp_path.iterdir()) == []
    with pytest.raises(SceneFormatError):
        load_scene(target)

    monkeypatch.setattr(np, "save", real_save)
    write_scene(target, make_scene_data(seed=1))
    calls["n"] = 0
    monkeypatch.setattr(np, "save", failing_save)
    with pytest.raises(OSError, match="simulated"):
        write_scene(target, make_scene_data(seed=2))
    assert load_scene(target).metadata["seed"] == 1  # the old scene survives intact


def test_killed_write_leaves_nothing_loadable(tmp_path):
    """A process that dies mid-write (no cleanup runs) leaves no loadable scene anywhere."""
    script = f"""
import os, sys
import numpy as np
sys.path.insert(0, {str(Path(__file__).parent)!r})
from scene_fixtures import make_scene_data
from recondreamer.scene import write_scene
real_save, calls = np.save, [0]
def dying_save(*args, **kwargs):
    calls[0] += 1
    if calls[0] == 5:
        os._exit(9)
    real_save(*args, **kwargs)
np.save = dying_save
write_scene({str(tmp_path / "scene")!r}, make_scene_data())
"""
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert result.returncode == 9, result.stderr
    assert not (tmp_path / "scene").exists()
    leftovers = list(tmp_path.iterdir())
    assert leftovers, "the killed writer should have left its temporary directory"
    for leftover in leftovers:
        assert leftover.name.startswith(".")
        with pytest.raises(SceneFormatError, match="scene.json: missing file"):
            load_scene(leftover)
