"""The paper's YOLO11 as the NTA-IoU detector (``recondreamer/evaluation/yolo.py``).

ultralytics needs torchvision, which does not import beside the project's pinned CPU torch, so
the adapter runs in an environment of its own (tests/yolo_env.py; .ci/run builds it with
``python3 tests/yolo_env.py``). There tests/yolo_check.py builds a random YOLO11n, runs the
adapter and ultralytics side by side and `recondreamer evaluate --detector` on a quick scene.
Here, without ultralytics, a YOLO file is refused by name. System tier (``pytest -m system``):
without the environment these tests fail, naming the command that builds it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from recondreamer.errors import CheckpointError
from recondreamer.evaluation import inference
from recondreamer.evaluation.yolo import is_ultralytics_checkpoint
from yolo_env import BUILD_COMMAND, built_python, venv_path

ROOT = Path(__file__).resolve().parents[1]
VEHICLES = {"car", "bus", "truck"}


@pytest.fixture(scope="module")
def yolo_python() -> Path:
    found = built_python()
    if found is None:
        pytest.fail(f"no YOLO environment with today's requirements at {venv_path()}: build it with `{BUILD_COMMAND}` (.ci/run does)")
    return found


@pytest.fixture(scope="module")
def yolo_run(yolo_python, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("yolo")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "YOLO_CONFIG_DIR": str(out / "ultralytics-settings")}
    subprocess.run([str(yolo_python), str(ROOT / "tests" / "yolo_check.py"), str(out)], check=True, env=env, timeout=900)
    return out


def _multiset(boxes, scores) -> Counter:
    return Counter((*np.round(box, 3), round(score, 5)) for box, score in zip(boxes, scores))


@pytest.mark.system
class TestYOLODetector:
    def test_gives_ultralytics_own_boxes_of_the_vehicle_classes_in_frame_pixels(self, yolo_run):
        check = json.loads((yolo_run / "check.json").read_text())
        assert sum(len(frame["boxes"]) for frame in check["ours"]) > 0
        for ours, reference in zip(check["ours"], check["reference"], strict=True):
            vehicles = [(box, score) for box, score, name in zip(reference["boxes"], reference["scores"], reference["classes"]) if name in VEHICLES]
            assert set(reference["classes"]) - VEHICLES, "the reference must hold other classes for the filter to matter"
            assert _multiset(ours["boxes"], ours["scores"]) == _multiset(*zip(*vehicles)) if vehicles else not ours["boxes"]
            boxes = np.array(ours["boxes"]).reshape(-1, 4)
            assert (boxes[:, [0, 1]] >= -1e-3).all() and (boxes[:, 2] <= 144 + 1e-3).all() and (boxes[:, 3] <= 96 + 1e-3).all()
            assert min(ours["scores"], default=1.0) >= 0.3

    def test_is_recorded_as_the_users_yolo_with_its_vehicle_classes(self, yolo_run):
        described = json.loads((yolo_run / "check.json").read_text())["describe"]
        assert described["kind"] == "yolo_detector" and described["path"].endswith("yolo11n.pt")
        assert described["config"] == {"classes": ["car", "bus", "truck"], "class_ids": [2, 5, 7], "num_classes": 80}

    def test_evaluate_scores_nta_iou_with_it(self, yolo_run):
        document = json.loads((yolo_run / "metrics.json").read_text())
        assert document["settings"]["models"]["vehicle_detector"]["kind"] == "yolo_detector"
        agents = document["trajectories"]["original"]["nta_iou"]
        assert agents["num_gt_boxes"] > 0 and 0.0 <= agents["nta_iou"] <= 1.0


class TestWithoutUltralytics:
    @pytest.mark.system
    def test_a_yolo_file_is_refused_naming_the_file_and_the_extra(self, yolo_run, monkeypatch):
        monkeypatch.setitem(sys.modules, "ultralytics", None)  # import fails, as in the project's own environment
        path = yolo_run / "yolo11n.pt"
        with pytest.raises(CheckpointError, match=r"yolo11n\.pt: an Ultralytics \(YOLO\) checkpoint; .*\[yolo\]"):
            inference.load_detector(path)

    @pytest.mark.system
    def test_only_ultralytics_archives_are_taken_for_yolo(self, yolo_run, tmp_path):
        assert is_ultralytics_checkpoint(yolo_run / "yolo11n.pt")
        assert not is_ultralytics_checkpoint(ROOT / "recondreamer" / "weights" / "vehicle_detector.pt")
        junk = tmp_path / "junk.pt"
        junk.write_bytes(b"not a checkpoint")
        assert not is_ultralytics_checkpoint(junk)
        assert not is_ultralytics_checkpoint(tmp_path / "missing.pt")

    def test_the_shipped_detector_still_loads_as_the_stand_in(self):
        assert inference.load_detector(ROOT / "recondreamer" / "weights" / "vehicle_detector.pt").kind == "vehicle_detector"
