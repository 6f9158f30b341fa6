"""NTA-IoU (novel-trajectory agent IoU) as DriveDreamer4D's public code computes it.

Per frame: the ground-truth vehicle boxes (enough LiDAR points, 3D corners projected with a
plain pinhole model into the evaluated camera, min/max of the corners, boxes not fully inside
the image dropped) are each matched to the detection with the nearest box centre; the match
is accepted when the centre distance is below a threshold (10 px at 480x320, scaled with the
image size), and the ground-truth box then scores the IoU of the two boxes, else 0. False
positives are not penalised and one detection may serve several ground-truth boxes. The score
is the mean over every ground-truth box of every frame of a trajectory.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from recondreamer.scene.types import Box

REFERENCE_SIZE = (480, 320)  # (width, height) at which the public code's 10 px threshold is defined
REFERENCE_MATCH_DISTANCE = 10.0  # pixels at REFERENCE_SIZE
DEFAULT_MIN_LIDAR_POINTS = 10  # Waymo's >= 10 top-LiDAR points visibility filter
DETECTION_SCORE_THRESHOLD = 0.5


def match_distance_threshold(width: int, height: int) -> float:
    """The 10 px (at 480x320) centre-distance threshold scaled to a width x height image.

    The scale is the geometric mean of the width and height ratios, so it equals the plain
    ratio for images of the reference 3:2 aspect (240x160 -> 5 px, 1920x1280 -> 40 px).
    """
    ref_w, ref_h = REFERENCE_SIZE
    return REFERENCE_MATCH_DISTANCE * float(np.sqrt((width / ref_w) * (height / ref_h)))


def box_centres(boxes: np.ndarray) -> np.ndarray:  # (N,4) xyxy -> (N,2)
    return np.stack([(boxes[:, 0] + boxes[:, 2]) / 2.0, (boxes[:, 1] + boxes[:, 3]) / 2.0], axis=1)


def pairwise_iou(boxes1: np.ndarray, boxes2: np.ndarray) -> np.ndarray:  # (N,4), (M,4) xyxy -> (N,M)
    """IoU of every pair of axis-aligned boxes; empty boxes give 0."""
    boxes1 = np.asarray(boxes1, dtype=np.float64).reshape(-1, 4)
    boxes2 = np.asarray(boxes2, dtype=np.float64).reshape(-1, 4)
    x0 = np.maximum(boxes1[:, None, 0], boxes2[None, :, 0])
    y0 = np.maximum(boxes1[:, None, 1], boxes2[None, :, 1])
    x1 = np.minimum(boxes1[:, None, 2], boxes2[None, :, 2])
    y1 = np.minimum(boxes1[:, None, 3], boxes2[None, :, 3])
    inter = np.clip(x1 - x0, 0.0, None) * np.clip(y1 - y0, 0.0, None)
    area1 = np.clip(boxes1[:, 2] - boxes1[:, 0], 0.0, None) * np.clip(boxes1[:, 3] - boxes1[:, 1], 0.0, None)
    area2 = np.clip(boxes2[:, 2] - boxes2[:, 0], 0.0, None) * np.clip(boxes2[:, 3] - boxes2[:, 1], 0.0, None)
    union = area1[:, None] + area2[None, :] - inter
    return np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0)


def match_gt_to_detections(
    gt_boxes: np.ndarray,  # (G,4) xyxy
    det_boxes: np.ndarray,  # (D,4) xyxy, already filtered by score
    max_centre_distance: float,
) -> np.ndarray:  # (G,) IoU per ground-truth box
    """Each GT box's IoU with its nearest-centre detection, or 0 when that is too far or absent.

    The nearest detection is chosen by centre distance alone (not by IoU); a match needs a
    distance strictly below ``max_centre_distance``.
    """
    gt_boxes = np.asarray(gt_boxes, dtype=np.float64).reshape(-1, 4)
    det_boxes = np.asarray(det_boxes, dtype=np.float64).reshape(-1, 4)
    scores = np.zeros(len(gt_boxes))
    if len(gt_boxes) == 0 or len(det_boxes) == 0:
        return scores
    dist = np.linalg.norm(box_centres(gt_boxes)[:, None, :] - box_centres(det_boxes)[None, :, :], axis=2)  # (G,D)
    nearest = dist.argmin(axis=1)
    ious = pairwise_iou(gt_boxes, det_boxes)[np.arange(len(gt_boxes)), nearest]
    accepted = dist[np.arange(len(gt_boxes)), nearest] < max_centre_distance
    scores[accepted] = ious[accepted]
    return scores


def ground_truth_boxes_2d(
    boxes: Sequence[Box],
    K: np.ndarray,  # (3,3)
    cam_to_world: np.ndarray,  # (4,4) the evaluated trajectory's camera at this frame
    width: int,
    height: int,
    min_lidar_points: int = DEFAULT_MIN_LIDAR_POINTS,
) -> np.ndarray:  # (G,4) xyxy
    """NTA-IoU ground truth: vehicles with enough LiDAR points, in front, fully inside the image."""
    from recondreamer.scene.structure import project_box_2d

    kept = []
    for box in boxes:
        if box.label != "vehicle" or box.num_points < min_lidar_points:
            continue
        projected = project_box_2d(box, K, cam_to_world, width, height)
        if projected.in_front and projected.fully_inside:
            kept.append(np.asarray(projected.xyxy, dtype=np.float64))
    return np.array(kept, dtype=np.float64).reshape(-1, 4)


def nta_iou(per_frame_gt: Sequence[np.ndarray], per_frame_det: Sequence[np.ndarray], width: int, height: int) -> dict:
    """Mean IoU over all GT boxes of all frames, with the per-frame sums that produced it.

    ``per_frame_det`` holds the detections already kept by the score threshold. A trajectory
    without any ground-truth box has no NTA-IoU: the value is then None (not 0 or 1).
    """
    if len(per_frame_gt) != len(per_frame_det):
        raise ValueError(f"{len(per_frame_gt)} frames of ground truth but {len(per_frame_det)} frames of detections")
    threshold = match_distance_threshold(width, height)
    all_scores = [match_gt_to_detections(gt, det, threshold) for gt, det in zip(per_frame_gt, per_frame_det, strict=True)]
    pooled = np.concatenate(all_scores) if all_scores else np.zeros(0)
    return {
        "nta_iou": float(pooled.mean()) if pooled.size else None,
        "num_gt_boxes": int(pooled.size),
        "num_positive_iou": int(np.count_nonzero(pooled)),
        "match_distance_px": threshold,
        "per_frame_iou_sum": [float(s.sum()) for s in all_scores],
        "per_frame_gt_count": [int(s.size) for s in all_scores],
    }
