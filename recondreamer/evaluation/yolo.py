"""A user's Ultralytics YOLO weights (the paper's YOLO11) as the NTA-IoU vehicle detector.

``eval_models.detector`` (``evaluate --detector``) may name a local Ultralytics detection
checkpoint instead of the corpus-trained stand-in. It is read by the ``ultralytics`` package
(extra ``[yolo]``; nothing is downloaded), run on the frames at its own input size (letterboxed,
``predict``'s default 640), and its boxes of the vehicle classes go to the same NTA-IoU code as
the stand-in's. The vehicle classes are matched by the checkpoint's own class names: COCO's car,
bus and truck (``VEHICLE_CLASSES``).
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from recondreamer.errors import CheckpointError

YOLO_KIND = "yolo_detector"
VEHICLE_CLASSES = ("car", "bus", "truck")


def is_ultralytics_checkpoint(path: str | Path) -> bool:
    """A torch archive whose pickle refers to ``ultralytics`` classes (read without unpickling it)."""
    try:
        with zipfile.ZipFile(path) as archive:
            pickles = [name for name in archive.namelist() if name.endswith("/data.pkl")]
            return bool(pickles) and b"ultralytics" in archive.read(pickles[0])
    except (zipfile.BadZipFile, OSError):
        return False


@dataclass(frozen=True)
class YOLODetectorConfig:
    classes: tuple[str, ...]  # vehicle class names kept
    class_ids: tuple[int, ...]  # their indices in the checkpoint
    num_classes: int  # classes the checkpoint detects


class YOLOVehicleDetector(torch.nn.Module):
    """Vehicle boxes from an Ultralytics ``YOLO`` model, in the frames' own pixel coordinates."""

    def __init__(self, yolo, path: Path, classes: tuple[str, ...] = VEHICLE_CLASSES):
        super().__init__()
        names = dict(yolo.names)  # {index: class name}
        class_ids = tuple(sorted(index for index, name in names.items() if name in classes))
        if not class_ids:
            shown = ", ".join(repr(names[index]) for index in sorted(names)[:12])
            raise CheckpointError(
                f"{path}: a YOLO checkpoint with none of the vehicle classes {', '.join(classes)} "
                f"(its {len(names)} classes begin {shown})"
            )
        self.yolo = yolo
        self.config = YOLODetectorConfig(tuple(names[index] for index in class_ids), class_ids, len(names))

    @torch.no_grad()
    def detect(self, images: np.ndarray, score_threshold: float) -> list[tuple[np.ndarray, np.ndarray]]:
        """(N,H,W,3) uint8 RGB -> N x (boxes (n,4) xyxy px, scores (n,)) of the vehicle classes."""
        frames = [np.ascontiguousarray(image[..., ::-1]) for image in images]  # Ultralytics reads arrays as OpenCV BGR
        results = self.yolo.predict(frames, conf=score_threshold, classes=list(self.config.class_ids), verbose=False)
        return [(r.boxes.xyxy.double().cpu().numpy(), r.boxes.conf.double().cpu().numpy()) for r in results]


def load_yolo_detector(path: Path) -> YOLOVehicleDetector:
    try:
        from ultralytics import YOLO
    except ImportError as error:
        raise CheckpointError(
            f"{path}: an Ultralytics (YOLO) checkpoint; reading it needs the ultralytics package "
            f"(pip install -e '.[yolo]', docs/evaluation.md), which failed to import: {error}"
        ) from None
    try:
        yolo = YOLO(str(path))
    except Exception as error:  # ultralytics raises many types for files it cannot use
        raise CheckpointError(f"{path}: ultralytics could not load it ({type(error).__name__}: {error})") from None
    if yolo.task != "detect":
        raise CheckpointError(f"{path}: a YOLO {yolo.task!r} model; NTA-IoU needs a detection ('detect') model")
    return YOLOVehicleDetector(yolo, path)
