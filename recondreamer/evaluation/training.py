"""Training the evaluation models on the synthetic corpus, with resumable checkpoints.

The three networks train in the project's one resumable loop (``recondreamer.training_loop``):
AdamW, linear warm-up times a cosine decay to 0, mini-batches drawn by a generator seeded by
(seed, step) (so a resumed run draws the same batches), progress with loss and ETA every
``log_every`` steps, and ``OUT.resume.pt`` every ``checkpoint_every`` steps.
Augmentations: horizontal flip, brightness/contrast jitter, and (detector, lanes) mild blur
and noise on some frames, so that the models tolerate the softness of good renders while
heavily degraded renders still lose detections.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from recondreamer.configs import to_dict
from recondreamer.evaluation.corpus import FrameSample
from recondreamer.evaluation.models import VehicleDetector
from recondreamer.training_loop import run_training_loop

log = logging.getLogger(__name__)


@dataclass
class TrainSettings:
    steps: int
    batch_size: int = 12
    lr: float = 3e-3
    weight_decay: float = 1e-4
    warmup_steps: int = 20
    log_every: int = 25
    checkpoint_every: int = 100
    seed: int = 0


# ---------------------------------------------------------------------------- batches


@dataclass
class Batch:
    """Augmented frames plus what is needed to transform their targets the same way."""

    images: torch.Tensor  # (B,3,h,w) float [0,255] on the training device
    samples: list[FrameSample]
    flipped: np.ndarray  # (B,) bool, horizontal flip of the full frame (applied before cropping)
    origins: np.ndarray  # (B,2) int, (x0, y0) of the crop in the (flipped) frame

    @property
    def device(self) -> torch.device:
        return self.images.device

    def boxes(self, index: int, boxes: np.ndarray) -> np.ndarray:  # (n,4) frame xyxy -> (m,4) crop xyxy
        """Boxes flipped, shifted into the crop and clipped to it; boxes left with no area dropped."""
        height, width = self.images.shape[-2:]
        frame_width = self.samples[index].image.shape[1]
        boxes = boxes.copy()
        if self.flipped[index]:
            boxes[:, [0, 2]] = frame_width - boxes[:, [2, 0]]
        boxes[:, [0, 2]] = np.clip(boxes[:, [0, 2]] - self.origins[index, 0], 0, width)
        boxes[:, [1, 3]] = np.clip(boxes[:, [1, 3]] - self.origins[index, 1], 0, height)
        return boxes[(boxes[:, 2] - boxes[:, 0] >= 1.0) & (boxes[:, 3] - boxes[:, 1] >= 1.0)]

    def masks(self, masks: list[np.ndarray]) -> torch.Tensor:  # B x (H,W) -> (B,h,w) int64
        height, width = self.images.shape[-2:]
        out = []
        for mask, flip, (x0, y0) in zip(masks, self.flipped, self.origins):
            mask = mask[:, ::-1] if flip else mask
            out.append(mask[y0 : y0 + height, x0 : x0 + width])
        return torch.from_numpy(np.stack(out).astype(np.int64)).to(self.device)


def make_batch(samples: list[FrameSample], rng: np.random.Generator, degrade: bool, crop: tuple[int, int] | None, device: str = "cpu") -> Batch:
    """Flip, crop to ``crop`` = (width, height) at random positions, jitter, and maybe blur or add noise.

    Training on crops costs a fraction of full frames per step; the networks are fully
    convolutional, so they run on full frames afterwards.
    """
    frame_h, frame_w = samples[0].image.shape[:2]
    crop_w, crop_h = crop if crop is not None else (frame_w, frame_h)
    crop_w, crop_h = min(crop_w, frame_w), min(crop_h, frame_h)
    batch = len(samples)
    flipped = rng.random(batch) < 0.5
    origins = np.stack([rng.integers(0, frame_w - crop_w + 1, batch), rng.integers(0, frame_h - crop_h + 1, batch)], axis=1)
    images = np.stack(
        [(s.image[:, ::-1] if f else s.image)[y0 : y0 + crop_h, x0 : x0 + crop_w] for s, f, (x0, y0) in zip(samples, flipped, origins)]
    )  # (B,h,w,3)
    tensor = torch.from_numpy(np.ascontiguousarray(images)).to(device).permute(0, 3, 1, 2).float()
    gain = torch.from_numpy(rng.uniform(0.8, 1.2, size=(batch, 1, 1, 1))).float().to(device)
    bias = torch.from_numpy(rng.uniform(-15.0, 15.0, size=(batch, 1, 1, 1))).float().to(device)
    tensor = tensor * gain + bias
    if degrade:
        import kornia

        for i in np.nonzero(rng.random(batch) < 0.3)[0]:
            sigma = float(rng.uniform(0.3, 1.0))
            tensor[i : i + 1] = kornia.filters.gaussian_blur2d(tensor[i : i + 1], (5, 5), (sigma, sigma))
        noisy = torch.from_numpy(rng.random(batch) < 0.3).float().view(-1, 1, 1, 1).to(device)
        tensor = tensor + noisy * torch.from_numpy(rng.normal(0.0, 4.0, size=tuple(tensor.shape))).float().to(device)
    return Batch(tensor.clamp(0.0, 255.0), samples, flipped, origins)


# ---------------------------------------------------------------------------- losses


def detector_targets(boxes_per_image: list[np.ndarray], out_h: int, out_w: int, stride: float):
    """CenterNet targets: Gaussian heat maps peaking at 1 on the centre cells, sizes and offsets there."""
    batch = len(boxes_per_image)
    heat = np.zeros((batch, out_h, out_w), np.float32)
    size = np.zeros((batch, 2, out_h, out_w), np.float32)
    offset = np.zeros((batch, 2, out_h, out_w), np.float32)
    mask = np.zeros((batch, out_h, out_w), np.float32)
    ys, xs = np.mgrid[0:out_h, 0:out_w]
    for b, boxes in enumerate(boxes_per_image):
        # Larger boxes first, so that a small box in front keeps its own centre values.
        for x0, y0, x1, y1 in sorted(boxes.tolist(), key=lambda box: -(box[2] - box[0]) * (box[3] - box[1])):
            cx, cy = (x0 + x1) / 2 / stride, (y0 + y1) / 2 / stride
            ix, iy = min(int(cx), out_w - 1), min(int(cy), out_h - 1)
            sx = max(0.6, (x1 - x0) / stride / 6.0)
            sy = max(0.6, (y1 - y0) / stride / 6.0)
            gaussian = np.exp(-((xs - ix) ** 2) / (2 * sx**2) - ((ys - iy) ** 2) / (2 * sy**2))
            np.maximum(heat[b], gaussian, out=heat[b])
            size[b, :, iy, ix] = np.log([max(x1 - x0, 1.0), max(y1 - y0, 1.0)])
            offset[b, :, iy, ix] = [cx - ix, cy - iy]
            mask[b, iy, ix] = 1.0
    return tuple(torch.from_numpy(a) for a in (heat, size, offset, mask))


def focal_heatmap_loss(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:  # (B,h,w) each
    """CenterNet's penalty-reduced focal loss (alpha 2, beta 4), normalised by the object count."""
    prob = torch.sigmoid(logits).clamp(1e-4, 1 - 1e-4)
    positive = target.eq(1.0).float()
    pos_loss = -torch.log(prob) * (1 - prob) ** 2 * positive
    neg_loss = -torch.log(1 - prob) * prob**2 * (1 - target) ** 4 * (1 - positive)
    return (pos_loss.sum() + neg_loss.sum()) / positive.sum().clamp(min=1.0)


def detector_loss(model: VehicleDetector, batch: Batch) -> torch.Tensor:
    boxes = [batch.boxes(i, s.train_boxes) for i, s in enumerate(batch.samples)]
    out = model(batch.images)
    out_h, out_w = out["heatmap_logits"].shape[-2:]
    heat, size, offset, mask = (t.to(batch.device) for t in detector_targets(boxes, out_h, out_w, model.stride))
    denom = mask.sum().clamp(min=1.0)
    size_loss = ((out["log_size"] - size).abs() * mask[:, None]).sum() / denom
    offset_loss = ((out["offset"] - offset).abs() * mask[:, None]).sum() / denom
    return focal_heatmap_loss(out["heatmap_logits"][:, 0], heat) + size_loss + offset_loss


def _dice_loss(logits: torch.Tensor, target: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:  # (B,2,H,W), (B,H,W) x2
    prob = logits.softmax(dim=1)[:, 1] * valid
    target = target.float() * valid
    inter = (prob * target).sum()
    return 1.0 - (2 * inter + 1.0) / (prob.sum() + target.sum() + 1.0)


def lane_loss(model: torch.nn.Module, batch: Batch) -> torch.Tensor:
    """Cross-entropy + dice on the lane head (visible lane markings), cross-entropy on the area head."""
    lanes = batch.masks([s.lane_mask for s in batch.samples])
    out = model(batch.images)
    loss = F.cross_entropy(out["lane_logits"], lanes) + _dice_loss(out["lane_logits"], lanes, torch.ones_like(lanes))
    if all(s.road_mask is not None for s in batch.samples):
        road = batch.masks([s.road_mask for s in batch.samples])
        loss = loss + 0.5 * F.cross_entropy(out["area_logits"], road)
    return loss


def feature_loss(model: torch.nn.Module, batch: Batch) -> torch.Tensor:
    labels = batch.masks([s.semantics for s in batch.samples])
    return F.cross_entropy(model(batch.images), labels)


# ---------------------------------------------------------------------------- loop


def warm_cosine_to_zero(step: int, total: int, base: float, warmup: int) -> float:
    """The evaluation models' rate: linear warm-up times a cosine over the whole run, down to 0."""
    warm = min(1.0, (step + 1) / max(warmup, 1))
    return base * warm * 0.5 * (1.0 + math.cos(math.pi * step / max(total, 1)))


def train_model(
    name: str,
    model: torch.nn.Module,
    loss_fn: Callable[[torch.nn.Module, Batch], torch.Tensor],
    samples: list[FrameSample],
    settings: TrainSettings,
    out: Path,
    degrade: bool,
    crop: tuple[int, int] | None = None,
    device: str = "cpu",
) -> dict:
    """Train ``model`` in place for the model file ``out`` (resuming from ``OUT.resume.pt`` when it
    holds this job's state); the batches of a step depend on (seed, step) only."""
    if not samples:
        raise ValueError(f"{name}: no training frames")
    model.to(device)

    def step_loss(rng: np.random.Generator, _generator: torch.Generator) -> torch.Tensor:
        picks = rng.choice(len(samples), size=min(settings.batch_size, len(samples)), replace=False)
        return loss_fn(model, make_batch([samples[i] for i in picks], rng, degrade, crop, device))

    identity = {"kind": "evaluation_model", "arch": name, "settings": asdict(settings), "crop": crop, "degrade": degrade,
                "frames": len(samples), "config": to_dict(model.config)}
    began = time.monotonic()
    run_training_loop(
        name, model, step_loss, settings.steps, settings.lr, settings.warmup_steps, out, identity, settings.checkpoint_every,
        settings.log_every, settings.seed, settings.weight_decay, lr_schedule=warm_cosine_to_zero, clip_grad_norm=None,
        per_step_batches=True,
    )
    model.cpu().eval()
    return {"crop": list(crop) if crop else None, "steps": settings.steps, "batch_size": settings.batch_size, "lr": settings.lr, "seconds": round(time.monotonic() - began, 1)}
