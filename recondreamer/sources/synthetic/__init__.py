"""The embedded default benchmark: a procedural driving world with its own ground-truth renderer.

``generate_segment(seed)`` returns a ``SceneData`` with RGB, depth, semantics, instances, sky
masks, LiDAR, tracked boxes, HD-map polylines and the true novel views of the evaluation
trajectories. See ``docs/synthetic-world.md``.
"""

from recondreamer.sources.synthetic.config import PRESETS, SyntheticConfig, make_config
from recondreamer.sources.synthetic.segment import generate_segment

__all__ = ["PRESETS", "SyntheticConfig", "generate_segment", "make_config"]
