"""Training and held-out frames for the evaluation models, read from a synthetic corpus.

Every corpus scene contributes frames of its recorded trajectory and of its true novel views
(clean renders from laterally shifted cameras, so the models see the viewpoints they will
score). Targets per frame:

- detector: the 2D boxes (3D corners projected, clipped to the image) of every vehicle with at
  least ``min_visible_pixels`` pixels in the instance mask;
- detector gate (AP50): the NTA-IoU ground truth (vehicles with enough LiDAR points, in front,
  fully inside the image); the other vehicles in view are "ignore" boxes, so detecting them
  is neither a hit nor a false positive;
- lane segmenter: the lane markings visible in the frame (the renderer's semantic
  ``lane_marking`` class), as TwinLiteNet learns painted lanes from images, plus the drivable
  area (semantic road and lane-marking pixels) for the twin head. Not the map-projected mask:
  that mask is NTL-IoU's ground truth and also conditions DriveRestorer and DriveDreamer4D, so
  a segmenter trained on it would reward renders that copy the conditioning rather than paint
  the lanes (``docs/evaluation.md``). The map mask in that camera is kept beside it for the
  gate's clean-frame NTL-IoU;
- FID feature network: the semantic labels.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from recondreamer.errors import RecondreamerError
from recondreamer.evaluation.lanes import lane_mask
from recondreamer.evaluation.nta_iou import DEFAULT_MIN_LIDAR_POINTS

log = logging.getLogger(__name__)

MIN_VISIBLE_PIXELS = 12  # a vehicle smaller than this in its instance mask is not a detector target
MIN_BOX_SIDE_PX = 2.0


@dataclass
class FrameSample:
    scene_id: str
    trajectory: str
    t: int
    image: np.ndarray  # (H,W,3) uint8
    train_boxes: np.ndarray  # (n,4) xyxy, detector targets
    eval_boxes: np.ndarray  # (m,4) xyxy, NTA-IoU ground truth
    ignore_boxes: np.ndarray  # (k,4) xyxy, other vehicles in view
    lane_mask: np.ndarray  # (H,W) bool, visible lane markings (the segmenter's target)
    map_lane_mask: np.ndarray  # (H,W) bool, NTL-IoU ground truth: the map's lane lines in this camera
    road_mask: np.ndarray | None  # (H,W) bool
    semantics: np.ndarray | None  # (H,W) uint8


def corpus_scene_dirs(corpus: str | Path) -> list[Path]:
    """Scene directories directly under ``corpus`` (those holding a scene.json), sorted by name."""
    from recondreamer.scene.format import SCENE_FILE

    corpus = Path(corpus)
    if not corpus.is_dir():
        raise RecondreamerError(f"corpus directory {corpus} does not exist")
    scenes = sorted(p for p in corpus.iterdir() if (p / SCENE_FILE).is_file())
    if not scenes:
        raise RecondreamerError(f"corpus directory {corpus} holds no scene directories (no */{SCENE_FILE})")
    return scenes


def _vehicle_boxes(scene, t: int, cam_to_world: np.ndarray, instances: np.ndarray | None, min_lidar_points: int):
    """(train, eval, ignore) boxes of frame ``t`` seen from ``cam_to_world``."""
    from recondreamer.scene.structure import project_box_2d

    width, height = scene.width, scene.height
    pixel_counts = np.bincount(instances.ravel(), minlength=len(scene.track_ids) + 1) if instances is not None else None
    train, evaluated, ignored = [], [], []
    for box in scene.boxes(t):
        if box.label != "vehicle":
            continue
        projected = project_box_2d(box, scene.K, cam_to_world, width, height)
        if not projected.in_front:
            continue
        x0, y0, x1, y1 = projected.xyxy
        clipped = np.array([max(x0, 0.0), max(y0, 0.0), min(x1, width), min(y1, height)])
        if clipped[2] - clipped[0] < MIN_BOX_SIDE_PX or clipped[3] - clipped[1] < MIN_BOX_SIDE_PX:
            continue
        if box.num_points >= min_lidar_points and projected.fully_inside:
            evaluated.append(np.asarray(projected.xyxy, dtype=np.float64))
        else:
            ignored.append(clipped)
        if pixel_counts is not None:
            index = scene.track_ids.index(box.track_id) + 1 if box.track_id in scene.track_ids else 0
            visible = index > 0 and pixel_counts[index] >= MIN_VISIBLE_PIXELS
        else:
            visible = box.num_points >= min_lidar_points
        if visible:
            train.append(clipped)
    return _as_boxes(train), _as_boxes(evaluated), _as_boxes(ignored)


def _as_boxes(boxes: list[np.ndarray]) -> np.ndarray:  # -> (N,4)
    return np.array(boxes, dtype=np.float64).reshape(-1, 4)


def scene_samples(
    scene, trajectories: list[str], frames: list[int], min_lidar_points: int = DEFAULT_MIN_LIDAR_POINTS
) -> list[FrameSample]:
    """Samples of the given frames of the given trajectories ('original' or true novel views)."""
    road_ids = [scene.semantic_classes.index(name) for name in ("road", "lane_marking") if name in scene.semantic_classes]
    if "lane_marking" not in scene.semantic_classes:
        raise RecondreamerError(f"{scene.scene_id}: the scene's semantic classes have no 'lane_marking' (the lane segmenter's target)")
    marking_id = scene.semantic_classes.index("lane_marking")
    samples = []
    for name in trajectories:
        cams = scene.trajectory(name)
        for t in frames:
            if name == "original":
                image, semantics, instances = scene.image(t), scene.semantics(t), scene.instances(t)
            else:
                image, semantics, instances = scene.novel_image(name, t), scene.novel_semantics(name, t), scene.novel_instances(name, t)
            train, evaluated, ignored = _vehicle_boxes(scene, t, cams[t], instances, min_lidar_points)
            samples.append(
                FrameSample(
                    scene_id=scene.scene_id,
                    trajectory=name,
                    t=t,
                    image=np.ascontiguousarray(image),
                    train_boxes=train,
                    eval_boxes=evaluated,
                    ignore_boxes=ignored,
                    lane_mask=semantics == marking_id,
                    map_lane_mask=lane_mask(scene.map_polylines, scene.K, cams[t], scene.width, scene.height),
                    road_mask=None if semantics is None or not road_ids else np.isin(semantics, road_ids),
                    semantics=None if semantics is None else np.ascontiguousarray(semantics),
                )
            )
    return samples


@dataclass
class CorpusSplit:
    train: list[FrameSample]
    heldout: list[FrameSample]
    train_scenes: list[str]
    heldout_scenes: list[str]
    width: int
    height: int


def labelled_samples(scene, frame_stride: int, heldout: bool, min_lidar_points: int = DEFAULT_MIN_LIDAR_POINTS) -> list[FrameSample]:
    """Every ``frame_stride``-th frame of every trajectory of ``scene`` that has labels (the
    original and the true novel views); for held-out use offset by one frame where possible, so
    that the frame indices differ from training ones too."""
    trajectories = ["original", *[n for n in scene.novel_trajectories if {"semantics", "instances"} <= set(scene.novel_channels(n))]]
    start = min(1, scene.num_frames - 1) if heldout else 0
    return scene_samples(scene, trajectories, list(range(start, scene.num_frames, frame_stride)), min_lidar_points)


def load_corpus(
    corpus: str | Path,
    frame_stride: int = 2,
    holdout_scenes: int = 4,
    min_lidar_points: int = DEFAULT_MIN_LIDAR_POINTS,
    max_scenes: int | None = None,
) -> CorpusSplit:
    """Read the corpus; the last ``holdout_scenes`` scenes (by name) are held out for the gates.

    Training frames: every ``frame_stride``-th frame of every trajectory with images; held-out
    frames: every ``frame_stride``-th frame too (offset by one where possible, so they differ
    from any training frame index as well as by scene).
    """
    from recondreamer.scene import load_scene

    paths = corpus_scene_dirs(corpus)
    if max_scenes is not None:
        paths = paths[:max_scenes]
    if len(paths) <= holdout_scenes or holdout_scenes < 1:
        raise RecondreamerError(
            f"corpus {corpus}: {len(paths)} scenes cannot be split into training and {holdout_scenes} held-out scenes"
        )
    split = CorpusSplit([], [], [], [], 0, 0)
    for index, path in enumerate(paths):
        scene = load_scene(path)
        if split.width == 0:
            split.width, split.height = scene.width, scene.height
        elif (scene.width, scene.height) != (split.width, split.height):
            raise RecondreamerError(
                f"{path}: image size {scene.width}x{scene.height} differs from the corpus's {split.width}x{split.height}"
            )
        if "semantics" not in scene.channels or "instances" not in scene.channels:
            raise RecondreamerError(f"{path}: corpus scenes need semantics and instances channels (synthetic scenes have them)")
        heldout = index >= len(paths) - holdout_scenes
        samples = labelled_samples(scene, frame_stride, heldout, min_lidar_points)
        (split.heldout if heldout else split.train).extend(samples)
        (split.heldout_scenes if heldout else split.train_scenes).append(scene.scene_id)
        log.info("corpus scene %d/%d %s: %d frames (%s)", index + 1, len(paths), scene.scene_id, len(samples), "held out" if heldout else "train")
    return split
