"""``recondreamer train-eval-models``: the three evaluation networks and their gates.

Output directory: ``vehicle_detector.pt``, ``lane_segmenter.pt``, ``fid_features.pt`` (model
files, see ``inference``) and ``metrics.json`` (gates, training settings, corpus split); while a
model trains, its ``<model>.pt.resume.pt`` (``recondreamer.training_loop``), so that a killed run
resumes where it stopped. A model file that already exists is kept (not retrained); ``--force``
retrains.
"""

from __future__ import annotations

import logging
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from recondreamer.evaluation import gates, inference
from recondreamer.evaluation.corpus import load_corpus
from recondreamer.evaluation.config import EvalModelsConfig
from recondreamer.evaluation.nta_iou import DETECTION_SCORE_THRESHOLD
from recondreamer.evaluation.training import TrainSettings, detector_loss, feature_loss, lane_loss, train_model
from recondreamer.io import write_json_atomic
from recondreamer.training_loop import finish_job

log = logging.getLogger(__name__)


def _round_down(value: int, multiple: int) -> int:
    return max(multiple, value // multiple * multiple)


def train_eval_models(corpus: str | Path, out: str | Path, config: EvalModelsConfig) -> dict:
    """Train (or reuse) the three models on ``corpus``, score them on its held-out scenes, write ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    split = load_corpus(corpus, config.frame_stride, config.holdout_scenes, config.min_lidar_points, config.max_scenes)
    log.info("corpus: %d training frames from %d scenes, %d held-out frames from %d scenes", len(split.train), len(split.train_scenes), len(split.heldout), len(split.heldout_scenes))
    # The networks run at the corpus size (rounded down to their stride multiples).
    config.detector.input_width, config.detector.input_height = _round_down(split.width, 16), _round_down(split.height, 16)
    config.lanes.input_width, config.lanes.input_height = _round_down(split.width, 8), _round_down(split.height, 8)
    config.features.input_width, config.features.input_height = _round_down(split.width, 16), _round_down(split.height, 16)
    provenance = {
        "corpus": str(Path(corpus).resolve()),
        "train_scenes": split.train_scenes,
        "heldout_scenes": split.heldout_scenes,
        "num_train_frames": len(split.train),
        "num_heldout_frames": len(split.heldout),
        "frame_stride": config.frame_stride,
        "min_lidar_points": config.min_lidar_points,
    }
    torch.manual_seed(config.seed)
    jobs = (
        ("vehicle_detector", config.detector, detector_loss, config.detector_steps, True),
        ("lane_segmenter", config.lanes, lane_loss, config.lane_steps, True),
        ("fid_features", config.features, feature_loss, config.feature_steps, False),
    )
    metrics: dict = {"corpus": provenance, "models": {}, "gates": {}}
    for kind, model_config, loss_fn, steps, degrade in jobs:
        path = out / inference.MODEL_FILES[kind]
        if path.is_file() and not config.force:
            log.info("%s: %s exists, reusing it (use --force to retrain)", kind, path)
            loaded = inference.load_model(path, kind)
            model, training = loaded.module, loaded.training.get("run", {})
        else:
            model = model_config.build()
            settings = TrainSettings(steps=steps, batch_size=config.batch_size, seed=config.seed)
            crop = config.crop if all(config.crop) else None
            training = train_model(kind, model, loss_fn, split.train, settings, path, degrade, crop, config.device)
            inference.save_model(path, kind, model, {"run": training, **provenance})
            finish_job(path)
        metrics["models"][kind] = {"path": str(path), "sha256": inference.file_sha256(path), "training": training}
        metrics["gates"][kind] = gate_on_samples(kind, model, split.heldout)
        log.info("%s gate: %s", kind, metrics["gates"][kind])
    metrics["all_gates_passed"] = all(g.get("passed", True) for g in metrics["gates"].values())
    metrics["config"] = {k: v for k, v in asdict(config).items() if k not in ("detector", "lanes", "features")}
    write_json_atomic(out / "metrics.json", metrics)
    return metrics


def gate_on_samples(kind: str, model: torch.nn.Module, heldout: list) -> dict:
    """The gate of one evaluation model (``kind``) on labelled frames it did not train on
    (``corpus.FrameSample``s of one frame size): detector AP50 (also per scene), lane IoU, or the
    feature network's semantic accuracy."""
    images = np.stack([s.image for s in heldout])  # (N,H,W,3)
    height, width = images.shape[1:3]
    if kind == "vehicle_detector":
        detections = inference.detect_vehicles(model, images, gates.AP_SCORE_FLOOR)
        return gates.detector_gate(
            detections, [s.eval_boxes for s in heldout], [s.ignore_boxes for s in heldout], width, height, DETECTION_SCORE_THRESHOLD,
            scene_ids=[s.scene_id for s in heldout],
        )
    if kind == "lane_segmenter":
        return gates.lane_gate(list(inference.segment_lanes(model, images)), [s.lane_mask for s in heldout], [s.map_lane_mask for s in heldout])
    predictions = []
    with torch.no_grad():
        for i in range(0, len(images), 16):
            logits = model(inference.images_to_tensor(images[i : i + 16], model.config.input_width, model.config.input_height))
            logits = torch.nn.functional.interpolate(logits, size=(height, width), mode="bilinear", align_corners=False)
            predictions.extend(logits.argmax(1).numpy())
    return gates.semantic_accuracy(predictions, [s.semantics for s in heldout], model.config.num_classes)
