"""True views of a synthetic segment from any camera poses: the oracle a real dataset lacks.

A synthetic scene records its world seed and settings in ``scene.json``'s metadata, so the
procedural world can be rebuilt and ray-cast from cameras the recording never had. The
ReconDreamer loop uses this as an *oracle restorer* (``train-recondreamer --restorer truth``):
an upper bound that separates what PDUS itself can give from what DriveRestorer's quality
allows.
"""

from __future__ import annotations

import logging
import time as clock

import numpy as np

from recondreamer.errors import RecondreamerError
from recondreamer.sources.synthetic.config import SyntheticConfig
from recondreamer.sources.synthetic.render import render_view
from recondreamer.sources.synthetic.segment import GENERATOR, GENERATOR_VERSION
from recondreamer.sources.synthetic.world import build_world

log = logging.getLogger(__name__)


class TrueViewRenderer:
    """Renders the true RGB views of one synthetic scene (``recondreamer.scene`` object or SceneData)."""

    def __init__(self, scene) -> None:
        metadata = scene.metadata or {}
        name = getattr(scene, "scene_id", "scene")
        if metadata.get("generator") != GENERATOR:
            raise RecondreamerError(f"{name}: true views exist only for synthetic scenes (metadata generator "
                                    f"{metadata.get('generator')!r}, expected {GENERATOR!r})")
        if metadata.get("generator_version") != GENERATOR_VERSION:
            raise RecondreamerError(f"{name}: written by synthetic generator version {metadata.get('generator_version')}, "
                                    f"this code renders version {GENERATOR_VERSION}; regenerate the scene")
        settings = SyntheticConfig(**metadata["config"])
        self.timestamps = np.asarray(scene.timestamps, dtype=np.float64)  # (T,)
        self.world = build_world(int(metadata["seed"]), horizon=float(self.timestamps[-1]),
                                 camera_forward=settings.camera_forward)
        self.K = np.asarray(scene.K, dtype=np.float64)  # (3,3)
        self.width, self.height = int(scene.width), int(scene.height)

    def render(self, cam_to_world: np.ndarray) -> np.ndarray:  # (T,4,4) -> (T,H,W,3) uint8
        """The true RGB frame of every pose at the frame's own time."""
        cam_to_world = np.asarray(cam_to_world, dtype=np.float64)
        if cam_to_world.shape != (len(self.timestamps), 4, 4):
            raise RecondreamerError(f"true views: poses of shape {cam_to_world.shape}, expected "
                                    f"({len(self.timestamps)}, 4, 4) (one per frame)")
        started = clock.perf_counter()
        frames = np.stack([
            render_view(self.world, self.world.primitives_at(float(time)), pose, self.K, self.width, self.height).rgb
            for time, pose in zip(self.timestamps, cam_to_world)
        ])
        log.info("true views: %d frames rendered in %.1f s", len(frames), clock.perf_counter() - started)
        return frames
