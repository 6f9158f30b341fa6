"""Quality gates of the evaluation models on held-out clean corpus frames.

- Detector: AP50 (all-point interpolated precision-recall area, VOC style) for the vehicles
  NTA-IoU scores (ground-truth filter of ``corpus._vehicle_boxes``). Detections matching, at
  IoU >= 0.5, a vehicle the filter drops (too few LiDAR points, cut by the image border) are
  ignored rather than counted as false positives, as VOC treats "difficult" objects.
- Lane segmenter: IoU of the lane class against the visible lane markings, pooled over the
  held-out pixels, plus the NTL-IoU of the same frames against the map-projected lane mask (the
  metric's value on perfect renders).
- FID feature network: held-out semantic pixel accuracy (no gate; reported).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from recondreamer.evaluation.lanes import ntl_iou
from recondreamer.evaluation.nta_iou import nta_iou, pairwise_iou

DETECTOR_AP50_GATE = 0.9
LANE_IOU_GATE = 0.7
AP_SCORE_FLOOR = 0.05  # detections kept for the precision-recall curve


def _match_image(boxes: np.ndarray, scores: np.ndarray, gt: np.ndarray, ignore: np.ndarray, iou_threshold: float) -> list[tuple[float, int]]:
    """Greedy matching in descending score order -> (score, 1 hit / 0 false positive) per counted detection."""
    records = []
    order = np.argsort(-scores, kind="stable")
    ious_gt = pairwise_iou(boxes, gt)  # (n,m)
    ious_ignore = pairwise_iou(boxes, ignore)  # (n,k)
    taken = np.zeros(len(gt), bool)
    for d in order:
        if len(gt):
            candidates = np.where(~taken, ious_gt[d], -1.0)
            best = int(candidates.argmax())
            if candidates[best] >= iou_threshold:
                taken[best] = True
                records.append((float(scores[d]), 1))
                continue
        if len(ignore) and ious_ignore[d].max() >= iou_threshold:
            continue
        records.append((float(scores[d]), 0))
    return records


def average_precision_50(
    detections: Sequence[tuple[np.ndarray, np.ndarray]],  # per image: boxes (n,4), scores (n,)
    gt_boxes: Sequence[np.ndarray],  # per image: (m,4)
    ignore_boxes: Sequence[np.ndarray],  # per image: (k,4)
    iou_threshold: float = 0.5,
) -> dict:
    """AP at IoU 0.5 over all images (all-point interpolation), plus precision and recall at
    the detections' lowest kept score."""
    records = []
    num_gt = 0
    for (boxes, scores), gt, ignore in zip(detections, gt_boxes, ignore_boxes, strict=True):
        num_gt += len(gt)
        records.extend(_match_image(boxes, scores, gt, ignore, iou_threshold))
    hits = np.array([hit for _, hit in sorted(records, key=lambda r: -r[0])], dtype=np.float64)
    tp, fp = np.cumsum(hits), np.cumsum(1.0 - hits)
    summary = {
        "num_gt": num_gt,
        "num_counted_detections": len(records),
        "precision": float(tp[-1] / len(hits)) if len(hits) else None,
        "recall": float(tp[-1] / num_gt) if num_gt and len(hits) else (0.0 if num_gt else None),
    }
    if num_gt == 0:
        return {"ap50": None, **summary}
    recall = tp / num_gt
    precision = tp / np.maximum(tp + fp, 1e-12)
    # All-point interpolation: precision made monotonically non-increasing, area under the steps.
    mrec = np.concatenate([[0.0], recall, [1.0]])
    mpre = np.concatenate([[1.0], precision, [0.0]])
    mpre = np.maximum.accumulate(mpre[::-1])[::-1]
    steps = np.where(mrec[1:] != mrec[:-1])[0]
    ap = float(np.sum((mrec[steps + 1] - mrec[steps]) * mpre[steps + 1]))
    return {"ap50": ap, **summary}


def detector_gate(
    detections: Sequence[tuple[np.ndarray, np.ndarray]],  # scores >= AP_SCORE_FLOOR
    gt_boxes: Sequence[np.ndarray],
    ignore_boxes: Sequence[np.ndarray],
    width: int,
    height: int,
    score_threshold: float,
    scene_ids: Sequence[str] | None = None,  # per frame: also report AP50 per scene
) -> dict:
    """AP50 gate plus precision/recall and NTA-IoU at the metric's score threshold.

    With ``scene_ids``, AP50 of each scene's frames beside the pooled value: a few held-out
    scenes differ much in difficulty (occluded vehicles), and the spread shows how far the pooled
    number would move with other scenes.
    """
    curve = average_precision_50(detections, gt_boxes, ignore_boxes)
    kept = [(boxes[scores > score_threshold], scores[scores > score_threshold]) for boxes, scores in detections]
    operating = average_precision_50(kept, gt_boxes, ignore_boxes)
    nta = nta_iou(gt_boxes, [boxes for boxes, _ in kept], width, height)
    ap = curve["ap50"]
    per_scene = {}
    if scene_ids is not None:
        if len(scene_ids) != len(detections):
            raise ValueError(f"scene_ids must name every frame: {len(scene_ids)} ids for {len(detections)} frames")
        for scene in dict.fromkeys(scene_ids):
            frames = [i for i, s in enumerate(scene_ids) if s == scene]
            per_scene[scene] = average_precision_50([detections[i] for i in frames], [gt_boxes[i] for i in frames], [ignore_boxes[i] for i in frames])["ap50"]
    return {
        "ap50": ap,
        **({"ap50_per_scene": per_scene} if scene_ids is not None else {}),
        "gate": DETECTOR_AP50_GATE,
        "passed": bool(ap is not None and ap >= DETECTOR_AP50_GATE),
        "num_gt_boxes": curve["num_gt"],
        "precision_at_threshold": operating["precision"],
        "recall_at_threshold": operating["recall"],
        "score_threshold": score_threshold,
        "nta_iou_clean": nta["nta_iou"],
    }


def lane_gate(predictions: Sequence[np.ndarray], markings: Sequence[np.ndarray], map_masks: Sequence[np.ndarray]) -> dict:
    """Lane IoU against the visible lane markings (the segmenter's task), pooled over frames; beside
    it what NTL-IoU gives these clean frames against its map-projected ground truth."""
    against_markings = ntl_iou(predictions, markings)
    against_map = ntl_iou(predictions, map_masks)
    iou = against_markings["lane_iou_pooled"]
    return {
        "lane_iou": iou,
        "gate": LANE_IOU_GATE,
        "passed": bool(iou is not None and iou >= LANE_IOU_GATE),
        "ntl_iou_clean": against_map["ntl_iou"],
        "lane_iou_vs_map_clean": against_map["lane_iou_pooled"],
        "num_frames": against_markings["num_frames"],
    }


def semantic_accuracy(predictions: Sequence[np.ndarray], truths: Sequence[np.ndarray], num_classes: int) -> dict:
    """Pixel accuracy and mean IoU over the classes present in the truth."""
    confusion = np.zeros((num_classes, num_classes), dtype=np.int64)
    for pred, truth in zip(predictions, truths, strict=True):
        confusion += np.bincount(truth.ravel().astype(np.int64) * num_classes + pred.ravel(), minlength=num_classes**2).reshape(num_classes, num_classes)
    present = confusion.sum(axis=1) > 0
    inter = np.diag(confusion)
    union = confusion.sum(axis=0) + confusion.sum(axis=1) - inter
    return {
        "pixel_accuracy": float(inter.sum() / confusion.sum()),
        "mean_iou": float(np.mean(inter[present] / np.maximum(union[present], 1))),
    }
