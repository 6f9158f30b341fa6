"""Runs inside the YOLO environment of tests/test_eval_yolo.py (torch 2.14.1, torchvision, ultralytics).

python tests/yolo_check.py OUT_DIR: builds a randomly initialised YOLO11n from ultralytics' own
model definition, with COCO's class names and its last class layers redrawn (a fresh head's biases
make every score about 1e-4, so nothing would be detected; unit-variance weights and zero biases
spread the boxes over the classes), saves it as OUT_DIR/yolo11n.pt, and
writes OUT_DIR/check.json with the adapter's detections beside ultralytics' own predictions on
the same frames. Then scores a quick synthetic scene's frames with `recondreamer evaluate
--detector OUT_DIR/yolo11n.pt` (the shipped lane and feature models beside it) into
OUT_DIR/metrics.json.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import torch
from ultralytics import YOLO
from ultralytics.utils import YAML
from ultralytics.utils.checks import check_yaml

from PIL import Image

from recondreamer.cli import main as recondreamer
from recondreamer.evaluation import inference
from recondreamer.scene import load_scene

SHIPPED = Path(__file__).resolve().parents[1] / "recondreamer" / "weights"

SCORE_THRESHOLD = 0.3


def random_yolo11n(path: Path) -> None:
    torch.manual_seed(0)
    model = YOLO("yolo11n.yaml")  # ultralytics' model definition, random weights; nothing downloaded
    model.model.names = YAML.load(check_yaml("coco.yaml"))["names"]  # {0: 'person', 2: 'car', ...}
    generator = torch.Generator().manual_seed(0)
    with torch.no_grad():
        for branch in model.model.model[-1].cv3:  # the class branches of the Detect head
            branch[-1].weight.copy_(torch.randn(branch[-1].weight.shape, generator=generator))
            branch[-1].bias.zero_()
    model.save(str(path))


def main(out: Path) -> None:
    weights = out / "yolo11n.pt"
    random_yolo11n(weights)
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, (3, 96, 144, 3), dtype=np.uint8)
    detector = inference.load_detector(weights)
    ours = inference.detect_vehicles(detector.module, frames, SCORE_THRESHOLD)
    # Reference: ultralytics on every class (no cap on the box count), the vehicle classes picked
    # by name afterwards by the test.
    reference = YOLO(str(weights)).predict([f[..., ::-1].copy() for f in frames], conf=SCORE_THRESHOLD, max_det=10**6, verbose=False)
    names = reference[0].names
    check = {
        "kind": detector.kind,
        "describe": detector.describe(),
        "ours": [{"boxes": b.tolist(), "scores": s.tolist()} for b, s in ours],
        "reference": [
            {
                "boxes": r.boxes.xyxy.double().numpy().tolist(),
                "scores": r.boxes.conf.double().numpy().tolist(),
                "classes": [names[int(c)] for c in r.boxes.cls],
            }
            for r in reference
        ],
    }
    (out / "check.json").write_text(json.dumps(check))

    scene_dir, renders = out / "scene", out / "renders"
    assert recondreamer(["synth", "--seed", "7", "--preset", "quick", "--no-novel", "--out", str(scene_dir)]) == 0
    scene = load_scene(scene_dir)
    renders.mkdir()
    for t in range(scene.num_frames):
        Image.fromarray(scene.image(t)).save(renders / f"{t:03d}.png")
    assert recondreamer([
        "evaluate", "--scene", str(scene_dir), "--renders", str(renders), "--trajectory", "original",
        "--models", str(SHIPPED), "--detector", str(weights), "--out", str(out / "metrics.json"),
    ]) == 0


if __name__ == "__main__":
    main(Path(sys.argv[1]))
