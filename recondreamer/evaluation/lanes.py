"""NTL-IoU ground truth (HD-map lane mask in any camera) and the NTL-IoU score.

The lane mask follows DriveDreamer4D's public recipe: road lines, road edges and the long
sides of crosswalks are transformed into the evaluated camera, kept within 75 m ahead and
10 m to either side, projected with a plain pinhole model and drawn 20 px thick at 1280 px
image height (scaled with the height), all merged into one lane class.

Segments are clipped exactly against the keep region (instead of dropping vertices) so a line
that leaves the region is drawn up to its boundary, not cut at its last kept vertex.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from PIL import Image, ImageDraw

from recondreamer.scene.cameras import world_to_camera
from recondreamer.scene.types import Polyline

LANE_KINDS = ("road_line", "road_edge", "crosswalk")
MAX_FORWARD_M = 75.0
MAX_LATERAL_M = 10.0
NEAR_M = 0.5  # segments closer than this to the camera plane are cut (they lie below a forward camera's view)
REFERENCE_THICKNESS_PX = 20.0
REFERENCE_HEIGHT_PX = 1280.0


def lane_thickness(height: int) -> int:
    """20 px at 1280 px image height, scaled, rounded half up, at least 1 px (240x160 -> 3 px)."""
    return max(1, int(np.floor(REFERENCE_THICKNESS_PX * height / REFERENCE_HEIGHT_PX + 0.5)))


def clip_segments(p0: np.ndarray, p1: np.ndarray, normals: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Liang-Barsky clip of segments p0->p1 (S,D) to the convex region {p : normals @ p + offsets >= 0}.

    Returns (kept (S,) bool, clipped p0 (S,D), clipped p1 (S,D)); rows not kept are meaningless.
    """
    start = p0 @ normals.T + offsets  # (S,C) signed distance of p0 to each half-space
    delta = (p1 - p0) @ normals.T  # (S,C)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -start / delta
    entering = delta > 0
    leaving = delta < 0
    t_in = np.max(np.where(entering, t, 0.0), axis=1, initial=0.0)
    t_out = np.min(np.where(leaving, t, 1.0), axis=1, initial=1.0)
    outside_parallel = np.any((delta == 0) & (start < 0), axis=1)
    kept = (t_in <= t_out) & ~outside_parallel
    direction = p1 - p0
    return kept, p0 + t_in[:, None] * direction, p0 + t_out[:, None] * direction


def lane_segments_world(polylines: Sequence[Polyline]) -> list[tuple[np.ndarray, np.ndarray]]:
    """World-space segments of the lane classes; a crosswalk contributes its two longest sides."""
    segments = []
    for line in polylines:
        if line.kind not in LANE_KINDS:
            continue
        points = np.asarray(line.points, dtype=np.float64)
        if line.kind == "crosswalk":
            ring = points if np.allclose(points[0], points[-1]) else np.vstack([points, points[:1]])
            sides = [(ring[i], ring[i + 1]) for i in range(len(ring) - 1)]
            sides.sort(key=lambda side: -float(np.linalg.norm(side[1] - side[0])))
            segments.extend(sides[:2])
        else:
            segments.extend((points[i], points[i + 1]) for i in range(len(points) - 1))
    return segments


def lane_mask(
    polylines: Sequence[Polyline],
    K: np.ndarray,  # (3,3)
    cam_to_world: np.ndarray,  # (4,4) OpenCV camera axes
    width: int,
    height: int,
    thickness: int | None = None,
) -> np.ndarray:  # (H,W) bool
    """Ground-truth lane mask of the HD map seen from ``cam_to_world``."""
    thickness = lane_thickness(height) if thickness is None else thickness
    world_to_cam = world_to_camera(cam_to_world)
    K = np.asarray(K, dtype=np.float64)
    # Keep region in camera coordinates (x right, z forward): NEAR <= z <= 75, |x| <= 10.
    keep_normals = np.array([[0, 0, 1], [0, 0, -1], [-1, 0, 0], [1, 0, 0]], dtype=np.float64)
    keep_offsets = np.array([-NEAR_M, MAX_FORWARD_M, MAX_LATERAL_M, MAX_LATERAL_M])
    # Image rectangle widened by the line thickness, to keep PIL's coordinates small.
    margin = float(thickness)
    image_normals = np.array([[1, 0], [-1, 0], [0, 1], [0, -1]], dtype=np.float64)
    image_offsets = np.array([margin, width + margin, margin, height + margin])
    canvas = Image.new("L", (width, height), 0)
    segments = lane_segments_world(polylines)
    if segments:
        p0 = np.array([seg[0] for seg in segments], dtype=np.float64)  # (S,3) world
        p1 = np.array([seg[1] for seg in segments], dtype=np.float64)
        rotation, translation = world_to_cam[:3, :3], world_to_cam[:3, 3]
        kept, c0, c1 = clip_segments(p0 @ rotation.T + translation, p1 @ rotation.T + translation, keep_normals, keep_offsets)
        c0, c1 = c0[kept], c1[kept]
        uv0 = (c0 @ K.T)[:, :2] / c0[:, 2:3]  # (S',2) pinhole
        uv1 = (c1 @ K.T)[:, :2] / c1[:, 2:3]
        kept, uv0, uv1 = clip_segments(uv0, uv1, image_normals, image_offsets)
        draw = ImageDraw.Draw(canvas)
        for (u0, v0), (u1, v1) in zip(uv0[kept].tolist(), uv1[kept].tolist()):
            draw.line([(u0, v0), (u1, v1)], fill=1, width=thickness)
    return np.asarray(canvas, dtype=np.uint8) > 0


def lane_ious(prediction: np.ndarray, truth: np.ndarray) -> tuple[float, float | None]:  # (H,W) bool each
    """(2-class mean IoU, lane-only IoU) of one frame.

    The background IoU is always defined. When neither mask has a lane pixel the lane IoU is
    undefined (None) and the 2-class mean is the background IoU alone (1.0), following the
    usual confusion-matrix mean IoU over the classes present.
    """
    prediction, truth = np.asarray(prediction, bool), np.asarray(truth, bool)
    if prediction.shape != truth.shape:
        raise ValueError(f"prediction {prediction.shape} and ground truth {truth.shape} differ in size")
    lane_union = np.count_nonzero(prediction | truth)
    lane_iou = np.count_nonzero(prediction & truth) / lane_union if lane_union else None
    bg_union = np.count_nonzero(~prediction | ~truth)
    bg_iou = np.count_nonzero(~prediction & ~truth) / bg_union if bg_union else 1.0
    mean_iou = bg_iou if lane_iou is None else (bg_iou + lane_iou) / 2.0
    return float(mean_iou), (None if lane_iou is None else float(lane_iou))


def ntl_iou(predictions: Sequence[np.ndarray], truths: Sequence[np.ndarray]) -> dict:
    """NTL-IoU of a trajectory: per-frame 2-class mean IoU averaged over frames, plus lane-only IoU.

    ``lane_iou`` averages the frames where a lane exists in the prediction or the truth;
    ``lane_iou_pooled`` is the IoU of all lane pixels of all frames together.
    """
    if len(predictions) != len(truths):
        raise ValueError(f"{len(predictions)} predicted masks but {len(truths)} ground-truth masks")
    if not predictions:
        raise ValueError("no frames to score")
    means, lanes = [], []
    inter = union = 0
    for pred, truth in zip(predictions, truths, strict=True):
        mean_iou, lane_iou = lane_ious(pred, truth)
        means.append(mean_iou)
        if lane_iou is not None:
            lanes.append(lane_iou)
        inter += np.count_nonzero(np.asarray(pred, bool) & np.asarray(truth, bool))
        union += np.count_nonzero(np.asarray(pred, bool) | np.asarray(truth, bool))
    return {
        "ntl_iou": float(np.mean(means)),
        "lane_iou": float(np.mean(lanes)) if lanes else None,
        "lane_iou_pooled": float(inter / union) if union else None,
        "num_frames": len(means),
        "num_frames_with_lanes": len(lanes),
        "per_frame_mean_iou": [float(m) for m in means],
    }
