"""Evaluation-model files and running them on frames of any size.

A model file is a torch checkpoint ``{"format": "recondreamer-eval-model", "version": 1,
"kind": ..., "config": {...}, "state_dict": ..., "training": {...}}``. Frames are resized to
the network's input size (antialiased bilinear) and outputs are mapped back to the frame size,
so the same model scores renders at any resolution.

The FID feature network may instead be a user's local copy of pytorch-fid's InceptionV3 weights
(a plain state_dict, see ``inception.py``); ``load_fid_model`` tells the two apart. The vehicle
detector may be a user's Ultralytics YOLO checkpoint (``yolo.py``); ``load_detector`` tells them apart.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from recondreamer.errors import CheckpointError, RecondreamerError
from recondreamer.evaluation.inception import INCEPTION_STATE_DICT_KEY, FIDInceptionV3
from recondreamer.configs import from_dict, to_dict
from recondreamer.evaluation.config import MODEL_CONFIGS
from recondreamer.evaluation.yolo import YOLO_KIND, YOLOVehicleDetector, is_ultralytics_checkpoint, load_yolo_detector
from recondreamer.io import atomic_path
from recondreamer.provenance import command_line

FORMAT = "recondreamer-eval-model"
FORMAT_VERSION = 1
MODEL_FILES = {
    "vehicle_detector": "vehicle_detector.pt",
    "lane_segmenter": "lane_segmenter.pt",
    "fid_features": "fid_features.pt",
}
INCEPTION_KIND = "fid_inception"  # a user's pytorch-fid InceptionV3 weights in place of fid_features


@dataclass
class LoadedModel:
    kind: str
    module: torch.nn.Module  # in eval mode
    path: Path
    sha256: str
    training: dict  # provenance written at training time (corpus, steps, gates)

    def describe(self) -> dict:
        return {"kind": self.kind, "path": str(self.path), "sha256": self.sha256, "config": to_dict(self.module.config)}


def file_sha256(path: str | Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for chunk in iter(lambda: handle.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def save_model(path: str | Path, kind: str, module: torch.nn.Module, training: dict) -> None:
    """Write a model file atomically."""
    payload = {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "kind": kind,
        "config": to_dict(module.config),
        "state_dict": module.state_dict(),
        "training": training,
        "command": command_line(),  # the weight set's manifest names it
    }
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)


def read_torch_file(path: Path, missing_hint: str, unreadable: str = "not a readable torch checkpoint"):
    """The payload of a torch file, read without running code (``weights_only``): a CheckpointError
    naming ``path`` with ``missing_hint`` when it is absent, with ``unreadable`` and the reason when
    torch refuses it (corrupt, foreign, or a pickle that would build more than tensors and containers)."""
    if not path.is_file():
        raise CheckpointError(f"{path}: {missing_hint}")
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # torch raises many types for corrupt, foreign or unsafe files
        raise CheckpointError(f"{path}: {unreadable} ({_refusal_reason(error)})") from None


def _refusal_reason(error: Exception) -> str:
    """The line of a torch.load error that says why (weights-only refusals bury it mid-message)."""
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    for line in lines:
        if "WeightsUnpickler error:" in line:
            return line.split("WeightsUnpickler error:", 1)[1].split(" Please use", 1)[0].strip()
    return f"{type(error).__name__}: {lines[0] if lines else error!r}"


def _model_from_payload(path: Path, payload, kind: str) -> LoadedModel:
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise CheckpointError(f"{path}: not a recondreamer evaluation model file")
    if payload.get("version") != FORMAT_VERSION:
        raise CheckpointError(f"{path}: unknown evaluation model format version {payload.get('version')!r}")
    if payload.get("kind") != kind:
        raise CheckpointError(f"{path}: holds a {payload.get('kind')!r} model, expected {kind!r}")
    if kind not in MODEL_CONFIGS:
        raise CheckpointError(f"{path}: unknown model kind {kind!r}")
    try:
        config = from_dict(MODEL_CONFIGS[kind], payload["config"])
    except RecondreamerError as error:
        raise CheckpointError(f"{path}: {error}; retrain it with this version of the code") from error
    module = config.build()
    module.load_state_dict(payload["state_dict"])
    module.eval()
    return LoadedModel(kind, module, path, file_sha256(path), payload.get("training", {}))


def load_model(path: str | Path, kind: str) -> LoadedModel:
    """Load an evaluation model file of the given kind; CheckpointError naming the file otherwise."""
    path = Path(path)
    return _model_from_payload(path, read_torch_file(path, "evaluation model file not found (train it with 'recondreamer train-eval-models')"), kind)


def load_detector(path: str | Path) -> LoadedModel:
    """The NTA-IoU vehicle detector in ``path``: a recondreamer ``vehicle_detector`` model file, or a
    user's Ultralytics YOLO detection checkpoint (``yolo.py``), told apart by the archive's pickle."""
    path = Path(path)
    if path.is_file() and is_ultralytics_checkpoint(path):
        detector = load_yolo_detector(path)
        return LoadedModel(YOLO_KIND, detector, path, file_sha256(path), {"source": "user-supplied Ultralytics YOLO weights"})
    return load_model(path, "vehicle_detector")


def is_inception(model: LoadedModel) -> bool:
    return model.kind == INCEPTION_KIND


def load_fid_model(path: str | Path) -> LoadedModel:
    """The FID feature network in ``path``: a recondreamer ``fid_features`` model file, or a
    pytorch-fid InceptionV3 state_dict (``pt_inception-2015-12-05-6726825d.pth``), told apart
    by the Inception layer names."""
    path = Path(path)
    payload = read_torch_file(
        path, "FID feature model file not found (train it with 'recondreamer train-eval-models', or name a local copy of pytorch-fid's InceptionV3 weights)"
    )
    if isinstance(payload, dict) and INCEPTION_STATE_DICT_KEY in payload:
        module = FIDInceptionV3()
        try:
            module.load_state_dict(payload, strict=True)
        except RuntimeError as error:  # missing/unexpected keys or wrong shapes, listed by torch
            details = " ".join(str(error).split())  # torch lists the keys on several lines; the CLI prints one
            raise CheckpointError(f"{path}: an Inception state_dict, but not pytorch-fid's FID InceptionV3 ({details})") from None
        module.eval()
        return LoadedModel(INCEPTION_KIND, module, path, file_sha256(path), {"source": "user-supplied pytorch-fid InceptionV3 weights"})
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise CheckpointError(
            f"{path}: neither a recondreamer FID feature model (train-eval-models) nor a pytorch-fid InceptionV3 "
            f"state_dict (no {INCEPTION_STATE_DICT_KEY!r} key)"
        )
    return _model_from_payload(path, payload, "fid_features")


def images_to_tensor(images: np.ndarray, width: int, height: int) -> torch.Tensor:  # (N,H,W,3) uint8 -> (N,3,h,w)
    """uint8 frames to float [0,255] tensors at the network's input size."""
    tensor = torch.from_numpy(np.ascontiguousarray(images)).permute(0, 3, 1, 2).float()
    if tensor.shape[-2:] != (height, width):
        tensor = F.interpolate(tensor, size=(height, width), mode="bilinear", align_corners=False, antialias=True)
    return tensor


def _batches(images: np.ndarray, batch_size: int):
    for start in range(0, len(images), batch_size):
        yield images[start : start + batch_size]


@torch.no_grad()
def detect_vehicles(
    model: torch.nn.Module, images: np.ndarray, score_threshold: float, batch_size: int = 16
) -> list[tuple[np.ndarray, np.ndarray]]:  # images (N,H,W,3) uint8 -> N x (boxes (n,4) xyxy px, scores (n,))
    """Vehicle boxes in the frames' own pixel coordinates, scores above ``score_threshold``."""
    if isinstance(model, YOLOVehicleDetector):
        return model.detect(images, score_threshold)
    config = model.config
    height, width = images.shape[1:3]
    scale = np.array([width / config.input_width, height / config.input_height] * 2)
    results = []
    for chunk in _batches(images, batch_size):
        outputs = model(images_to_tensor(chunk, config.input_width, config.input_height))
        for boxes, scores in model.decode(outputs, score_threshold):
            results.append((boxes.double().numpy() * scale, scores.double().numpy()))
    return results


@torch.no_grad()
def segment_lanes(model: torch.nn.Module, images: np.ndarray, batch_size: int = 16) -> np.ndarray:
    """Lane masks (N,H,W) bool at the frames' own size (2-class argmax of the lane head)."""
    config = model.config
    height, width = images.shape[1:3]
    masks = []
    for chunk in _batches(images, batch_size):
        logits = model(images_to_tensor(chunk, config.input_width, config.input_height))["lane_logits"]
        if logits.shape[-2:] != (height, width):
            logits = F.interpolate(logits, size=(height, width), mode="bilinear", align_corners=False)
        masks.append((logits[:, 1] > logits[:, 0]).numpy())
    return np.concatenate(masks, axis=0)


@torch.no_grad()
def fid_features(model: torch.nn.Module, images: np.ndarray, batch_size: int = 16) -> np.ndarray:  # (N,H,W,3) uint8 -> (N,D) float64
    """One feature vector per frame: the corpus-trained FeatureNet, or InceptionV3's 2048-d pool."""
    if isinstance(model, FIDInceptionV3):
        # pytorch-fid's input: the frame at its own size in [0,1]; the network resizes to 299x299 itself.
        tensors = (torch.from_numpy(np.ascontiguousarray(chunk)).permute(0, 3, 1, 2).float() / 255.0 for chunk in _batches(images, batch_size))
        features = [model(tensor) for tensor in tensors]
    else:
        config = model.config
        features = [model.features(images_to_tensor(chunk, config.input_width, config.input_height)) for chunk in _batches(images, batch_size)]
    return torch.cat(features).double().numpy()
