"""Segment settings of the synthetic world: a dataclass config and its named presets."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from recondreamer.errors import RecondreamerError


@dataclass(frozen=True)
class SyntheticConfig:
    """What one synthetic segment is rendered at; the world itself comes from the seed alone."""

    width: int = 240  # image width in pixels
    height: int = 160  # image height in pixels
    frames: int = 40  # number of frames of the segment
    frame_rate: float = 10.0  # Hz
    hfov_deg: float = 50.0  # horizontal field of view of the front camera
    camera_height: float = 1.6  # metres above the road
    camera_forward: float = 1.5  # metres ahead of the ego origin (rear axle, on the ground)
    camera_pitch_deg: float = 2.0  # downward tilt of the optical axis
    lidar_beams: int = 32  # rings of the virtual spinning LiDAR
    lidar_azimuths: int = 720  # rays per ring over 360 degrees
    lidar_range: float = 75.0  # metres; farther hits are not returned
    novel_views: bool = True  # render the true novel views of the evaluation trajectories

    def validate(self) -> SyntheticConfig:
        """Return self, or raise a RecondreamerError naming the first bad setting."""
        positive_ints = ("width", "height", "frames", "lidar_beams", "lidar_azimuths")
        for name in positive_ints:
            if getattr(self, name) < 1:
                raise RecondreamerError(f"synthetic setting {name}={getattr(self, name)}: must be a positive integer")
        if self.width < 8 or self.height < 8:
            raise RecondreamerError(f"synthetic image size {self.width}x{self.height}: must be at least 8x8 pixels")
        if not 10.0 <= self.hfov_deg <= 120.0:
            raise RecondreamerError(f"synthetic setting hfov_deg={self.hfov_deg}: must lie in [10, 120] degrees")
        for name in ("frame_rate", "camera_height", "lidar_range"):
            if not getattr(self, name) > 0:
                raise RecondreamerError(f"synthetic setting {name}={getattr(self, name)}: must be positive")
        return self


PRESETS: dict[str, SyntheticConfig] = {
    "default": SyntheticConfig(),
    # The embedded workflow's benchmark: sized so that every run of the paper's five tables fits
    # in an hour on two CPU cores (config/config.yaml); same world, camera and LiDAR, fewer pixels
    # and frames. Sides divisible by 16: the autoencoder (4x) and the UNet's two levels (4x) divide them.
    "compact": SyntheticConfig(width=144, height=96, frames=24),
    "quick": SyntheticConfig(width=96, height=64, frames=12, lidar_beams=24, lidar_azimuths=360),
}


def make_config(preset: str = "default", **overrides) -> SyntheticConfig:
    """The named preset with ``overrides`` (field name -> value; None values are ignored)."""
    if preset not in PRESETS:
        raise RecondreamerError(f"unknown synthetic preset {preset!r}; choose one of {', '.join(PRESETS)}")
    fields = {field.name for field in dataclasses.fields(SyntheticConfig)}
    unknown = sorted(set(overrides) - fields)
    if unknown:
        raise RecondreamerError(f"unknown synthetic setting(s) {', '.join(unknown)}; known: {', '.join(sorted(fields))}")
    chosen = {name: value for name, value in overrides.items() if value is not None}
    return dataclasses.replace(PRESETS[preset], **chosen).validate()
