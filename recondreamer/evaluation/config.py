"""Configs of the evaluation models and of their training (``train-eval-models``).

Torch-free, so that the command line can build its options from them without loading torch;
each network config builds its model (``recondreamer.evaluation.models``) on demand.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from recondreamer.errors import ConfigValueError
from recondreamer.evaluation.nta_iou import DEFAULT_MIN_LIDAR_POINTS, DETECTION_SCORE_THRESHOLD


@dataclass
class DetectorConfig:
    input_width: int = 240  # multiples of 16
    input_height: int = 160
    widths: tuple[int, int, int, int] = (16, 32, 64, 96)  # channels at strides 2, 4, 8, 16
    neck_width: int = 32
    max_detections: int = 64
    # Frames are enlarged this many times (bilinear) before the network, so its stride-4 heat map
    # resolves the few-pixel vehicles of compact frames; boxes stay in input pixels.
    upsample: int = 1

    def check(self) -> None:
        if self.upsample < 1:
            raise ConfigValueError("upsample", f"must be at least 1, got {self.upsample}")

    def build(self):  # -> models.VehicleDetector
        from recondreamer.evaluation import models

        return models.VehicleDetector(self)


@dataclass
class LaneSegmenterConfig:
    input_width: int = 240  # multiples of 8
    input_height: int = 160
    widths: tuple[int, int, int] = (16, 48, 96)  # channels at strides 2, 4, 8
    blocks: tuple[int, int] = (2, 3)  # ESP blocks at strides 4 and 8

    def build(self):  # -> models.LaneSegmenter
        from recondreamer.evaluation import models

        return models.LaneSegmenter(self)


@dataclass
class FeatureNetConfig:
    input_width: int = 240  # multiples of 16
    input_height: int = 160
    widths: tuple[int, int, int, int] = (24, 48, 96, 128)  # channels at strides 2, 4, 8, 16
    num_classes: int = 9  # len(SEMANTIC_CLASSES)

    @property
    def feature_dim(self) -> int:
        return sum(self.widths[1:])  # pooled stages at strides 4, 8 and 16

    def build(self):  # -> models.FeatureNet
        from recondreamer.evaluation import models

        return models.FeatureNet(self)


MODEL_CONFIGS = {
    "vehicle_detector": DetectorConfig,
    "lane_segmenter": LaneSegmenterConfig,
    "fid_features": FeatureNetConfig,
}


@dataclass
class EvalModelsConfig:
    detector_steps: int = 1500  # training steps of the vehicle detector
    lane_steps: int = 2000  # training steps of the lane segmenter
    feature_steps: int = 200  # training steps of the FID feature network
    batch_size: int = 12  # frames per training step
    frame_stride: int = 2  # use every N-th frame of each trajectory
    holdout_scenes: int = 4  # last N corpus scenes held out for the gates
    max_scenes: int | None = None  # use only the first N corpus scenes (None: all)
    min_lidar_points: int = DEFAULT_MIN_LIDAR_POINTS  # NTA-IoU ground-truth LiDAR-point filter
    crop: tuple[int, int] = (160, 112)  # random W x H training crops, multiples of 16 (0 0: full frames)
    seed: int = 0  # random seed of initialisation and batches
    force: bool = False  # retrain models whose files already exist
    device: str = "cpu"  # torch device for training, e.g. cpu or cuda
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    lanes: LaneSegmenterConfig = field(default_factory=LaneSegmenterConfig)
    features: FeatureNetConfig = field(default_factory=FeatureNetConfig)

    def check(self) -> None:
        for name in ("detector_steps", "lane_steps", "feature_steps", "batch_size", "frame_stride", "holdout_scenes"):
            if getattr(self, name) < 1:
                raise ConfigValueError(name, f"must be at least 1, got {getattr(self, name)}")
        if self.max_scenes is not None and self.max_scenes < 1:
            raise ConfigValueError("max_scenes", f"must be at least 1, got {self.max_scenes}")
        if any(c < 0 or c % 16 for c in self.crop):
            raise ConfigValueError("crop", f"must be two multiples of 16 (or 0 0), got {self.crop[0]} {self.crop[1]}")


@dataclass
class ScoringConfig:
    """How ``evaluate`` scores renders (the NTA-IoU protocol's settings)."""

    min_lidar_points: int = DEFAULT_MIN_LIDAR_POINTS  # NTA-IoU ground truth keeps vehicles with at least this many LiDAR points
    score_threshold: float = DETECTION_SCORE_THRESHOLD  # detector confidence above which a detection counts

    def check(self) -> None:
        if self.min_lidar_points < 0:
            raise ConfigValueError("min_lidar_points", f"must be at least 0, got {self.min_lidar_points}")
        if not 0.0 <= self.score_threshold < 1.0:
            raise ConfigValueError("score_threshold", f"must lie in [0, 1), got {self.score_threshold}")
