"""The synth, synth-suite and preview sub-commands, end to end on tiny scenes."""

from __future__ import annotations

import logging

import numpy as np
import pytest
import yaml
from PIL import Image

from recondreamer.cli import main
from recondreamer.errors import RecondreamerError
from recondreamer.scene import load_scene
from recondreamer.scene.trajectories import EVAL_TRAJECTORIES
from recondreamer.sources.synthetic.suite import load_suite, run_suite


def test_synth_and_preview(tmp_path):
    out = tmp_path / "scene"
    assert main(["synth", "--seed", "5", "--out", str(out), "--preset", "quick", "--frames", "3", "--width", "64", "--height", "48"]) == 0
    scene = load_scene(out)
    scene.check_all()
    assert (scene.num_frames, scene.width, scene.height) == (3, 64, 48)
    assert set(scene.novel_trajectories) == set(EVAL_TRAJECTORIES)
    assert scene.metadata["seed"] == 5 and scene.source == "synthetic"
    assert scene.novel_image("shift@6", 2).shape == (48, 64, 3) and scene.novel_depth("shift@6", 2) is not None
    assert (out / "images" / "000.png").is_file()
    sheet = tmp_path / "sheet.png"
    assert main(["preview", str(out), "--out", str(sheet), "--frames", "0", "2"]) == 0
    with Image.open(sheet) as image:
        assert image.format == "PNG" and image.width > 400
    assert main(["preview", str(out), "--out", str(sheet), "--frames", "7"]) == 1  # frame out of range


def _config(tmp_path, segments, corpus_scenes, first_seed):
    file = tmp_path / "config.yaml"
    config = {
        "results_dir": str(tmp_path / "results"),
        "synthetic": {"preset": "quick", "segments": segments, "corpus": {"num_scenes": corpus_scenes, "first_seed": first_seed, "preset": "quick"}},
    }
    file.write_text(yaml.safe_dump(config))
    return file


def test_suite_builds_resumes_and_rebuilds_broken_scenes(tmp_path, monkeypatch, caplog):
    import recondreamer.sources.synthetic.config as config_module

    # Keep the test tiny: the suite renders the named preset, so shrink "quick" for this test only.
    tiny = config_module.PRESETS["quick"].__class__(width=48, height=32, frames=2, lidar_beams=8, lidar_azimuths=90, novel_views=False)
    monkeypatch.setitem(config_module.PRESETS, "quick", tiny)
    file = _config(tmp_path, {"seg-a": 1, "seg-b": 2}, 1, 500)
    jobs = load_suite(file)
    assert [(j.group, j.name, j.seed) for j in jobs] == [("segments", "seg-a", 1), ("segments", "seg-b", 2), ("corpus", "corpus-000", 500)]
    assert jobs[0].out == tmp_path / "results" / "scenes" / "seg-a" and jobs[2].out == tmp_path / "results" / "corpus" / "corpus-000"
    assert len(run_suite(file)) == 3
    assert load_scene(jobs[1].out).scene_id == "seg-b"
    first_image = load_scene(jobs[0].out).image(1)
    assert run_suite(file) == []  # everything current: nothing rebuilt
    (jobs[2].out / "boxes.json").write_text("{")  # a broken scene is rebuilt
    with caplog.at_level(logging.WARNING):
        assert [j.name for j in run_suite(file, only="corpus")] == ["corpus-000"]
    assert "corpus-000" in caplog.text
    assert np.array_equal(load_scene(jobs[0].out).image(1), first_image)


def test_suite_config_errors(tmp_path):
    with pytest.raises(RecondreamerError, match="overlap"):
        load_suite(_config(tmp_path, {"seg-a": 501}, 3, 500))
    with pytest.raises(RecondreamerError, match="seed must be"):
        load_suite(_config(tmp_path, {"seg-a": "x"}, 1, 500))
    (tmp_path / "bad.yaml").write_text("results_dir: [1, 2]\n")  # layered over config/config.yaml: only what it sets
    with pytest.raises(RecondreamerError, match="results_dir"):
        load_suite(tmp_path / "bad.yaml")
    (tmp_path / "list.yaml").write_text("- results_dir\n")
    with pytest.raises(RecondreamerError, match="list.yaml: a config file must hold a mapping of keys, got list"):
        load_suite(tmp_path / "list.yaml")
    with pytest.raises(RecondreamerError, match="missing.yaml: not a readable YAML config"):
        load_suite(tmp_path / "missing.yaml")


def test_suite_previews_drawn_once_per_segment(tmp_path, monkeypatch):
    import recondreamer.sources.synthetic.config as config_module
    from recondreamer.sources.synthetic.suite import write_previews

    tiny = config_module.PRESETS["quick"].__class__(width=48, height=32, frames=2, lidar_beams=8, lidar_azimuths=90, novel_views=False)
    monkeypatch.setitem(config_module.PRESETS, "quick", tiny)
    file = _config(tmp_path, {"seg-a": 1}, 1, 500)
    with pytest.raises(RecondreamerError, match="scene.json"):
        write_previews(file)  # segments not built yet
    run_suite(file)
    (sheet,) = write_previews(file)
    assert sheet == tmp_path / "results" / "previews" / "seg-a.png"
    assert Image.open(sheet).size[0] > 48
    stamp = sheet.stat().st_mtime_ns
    assert write_previews(file) == [sheet] and sheet.stat().st_mtime_ns == stamp  # current: not redrawn
