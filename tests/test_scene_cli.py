"""``recondreamer validate``: exit codes and messages."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

from recondreamer.cli import main
from recondreamer.scene import write_scene
from scene_fixtures import make_scene_data


def test_validate_a_valid_scene(tmp_path, capsys):
    write_scene(tmp_path / "scene", make_scene_data())
    assert main(["validate", str(tmp_path / "scene")]) == 0
    out = capsys.readouterr().out
    assert "scene 'tiny'" in out and "3 frames" in out and "shift@3" in out and out.strip().endswith("valid")


def test_validate_reports_the_file_and_exits_1(tmp_path, capsys):
    write_scene(tmp_path / "scene", make_scene_data())
    boxes = tmp_path / "scene" / "boxes.json"
    content = json.loads(boxes.read_text())
    content["frames"][0][0]["size"][0] = -2.0
    boxes.write_text(json.dumps(content))
    assert main(["validate", str(tmp_path / "scene")]) == 1
    err = capsys.readouterr().err
    assert str(boxes) in err and "positive" in err
    assert len(err.strip().splitlines()) == 1


def test_full_check_decodes_data_that_headers_only_misses(tmp_path, capsys):
    write_scene(tmp_path / "scene", make_scene_data())
    np.save(tmp_path / "scene" / "lidar" / "002.npy", np.full((4, 3), np.nan, np.float32))
    assert main(["validate", "--headers-only", str(tmp_path / "scene")]) == 0
    assert main(["validate", str(tmp_path / "scene")]) == 1
    assert "lidar/002.npy: LiDAR points have non-finite values" in capsys.readouterr().err


def test_validate_as_a_process(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "recondreamer", "validate", str(tmp_path / "missing")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 1
    assert "not a scene directory" in result.stderr
    help_text = subprocess.run(
        [sys.executable, "-m", "recondreamer", "validate", "--help"], capture_output=True, text=True, timeout=60
    )
    assert help_text.returncode == 0 and "--headers-only" in help_text.stdout
