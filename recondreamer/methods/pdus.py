"""The Progressive Data Update Strategy (paper, Algorithm 1) as a pure schedule, plus the mixing rule.

Algorithm 1, with ``k`` counting updates::

    every S steps:  k += 1;  w = k / sum_{j=1..k} j;  y = k * dy
                    D_novel = (1 - w) * D_novel  U  w * V_novel(y)

So after ``k`` updates the j-th restored video is sampled (within the novel half) with
probability ``j / sum_{i<=k} i``: 1 -> [1], 2 -> [1/3, 2/3], 3 -> [1/6, 2/6, 3/6]. Training
batches draw 50/50 from the original and the novel data (``D = 0.5 D_ori U 0.5 D_novel``).

Updates happen before steps ``S, 2S, ...`` (the first one after ``S`` steps on the original
data only: at step 0 the model has nothing to render). Offsets are capped at ``max_offset``
(6 m, the widest evaluated shift), so a 6 m stride jumps straight to the widest shift and
keeps refreshing it: the paper's "no PDUS".
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

import numpy as np

from recondreamer.errors import ConfigValueError

if TYPE_CHECKING:  # recon.data imports torch; the CLI imports this module to build its options
    from recondreamer.recon.data import TrainingSet

# Every backbone preset gets this many update intervals: updates before steps S..4S, S = T/5.
UPDATE_INTERVALS = 5


@dataclass(frozen=True)
class PdusSchedule:
    """When to update, how far to the left, and how the restored videos are weighted."""

    # Comments beside the fields are the help of train-recondreamer's --stride, --update-every, --max-offset.
    stride: float  # PDUS stride dy: metres added to the leftward offset at each update (6 = one jump to the widest shift, no PDUS)
    update_every: int  # S: training steps between updates
    iterations: int  # T: total training steps
    max_offset: float = 6.0  # largest lateral offset in metres: update k renders min(k * stride, max_offset)
    novel_fraction: float = 0.5  # share of batches drawn from the novel data once there is some

    def __post_init__(self) -> None:
        self.check()

    def check(self) -> None:
        """Raise ConfigValueError naming the first field outside its range (the CLI turns it into the flag)."""
        if not (math.isfinite(self.stride) and self.stride > 0):
            raise ConfigValueError("stride", f"must be a positive number of metres, got {self.stride}")
        if not (math.isfinite(self.max_offset) and self.max_offset > 0):
            raise ConfigValueError("max_offset", f"must be a positive number of metres, got {self.max_offset}")
        if self.update_every < 1:
            raise ConfigValueError("update_every", f"must be at least 1 step, got {self.update_every}")
        if self.iterations < 1:
            raise ConfigValueError("iterations", f"must be at least 1, got {self.iterations}")
        if not 0.0 < self.novel_fraction < 1.0:
            raise ConfigValueError("novel_fraction", f"must lie in (0, 1), got {self.novel_fraction}")

    @classmethod
    def for_iterations(cls, stride: float, iterations: int, update_every: int | None = None,
                       max_offset: float = 6.0) -> PdusSchedule:
        """Default S = T / 5: four updates, so a 1.5 m stride reaches 6 m (1.5, 3, 4.5, 6)."""
        every = update_every if update_every is not None else max(1, iterations // UPDATE_INTERVALS)
        return cls(stride=float(stride), update_every=int(every), iterations=int(iterations), max_offset=float(max_offset))

    @property
    def num_updates(self) -> int:
        """Updates before steps S, 2S, ... that are still < T."""
        return (self.iterations - 1) // self.update_every

    def update_step(self, k: int) -> int:
        """Training step before which update ``k`` (1-based) happens."""
        return k * self.update_every

    def updates_due(self, step: int) -> int:
        """How many updates must have happened before training step ``step`` runs."""
        return min(step // self.update_every, self.num_updates)

    def offset(self, k: int) -> float:
        """Lateral offset (metres to the left) of the k-th novel trajectory: min(k * dy, max)."""
        return min(k * self.stride, self.max_offset)

    def offsets(self) -> list[float]:
        return [self.offset(k) for k in range(1, self.num_updates + 1)]

    def to_dict(self) -> dict:
        return asdict(self)


def newest_weight(k: int) -> float:
    """w = k / sum_{j=1..k} j: the sampling probability Algorithm 1 gives the k-th video."""
    if k < 1:
        raise ValueError(f"update index k starts at 1, got {k}")
    return k / sum(range(1, k + 1))


def video_weights(k: int) -> np.ndarray:  # (k,) probabilities of videos 1..k within D_novel
    """Apply Algorithm 1's update ``D = (1 - w) D U w V`` k times, starting from an empty set."""
    weights = np.zeros(0)
    for step in range(1, k + 1):
        w = newest_weight(step)
        weights = np.append((1.0 - w) * weights, w)
    return weights


def apply_mixing(training_set: TrainingSet, novel_sources: list[str], novel_fraction: float = 0.5) -> None:
    """Set sampling weights: original views share ``1 - novel_fraction``, novel video j gets
    ``novel_fraction * video_weights(k)[j]`` (spread evenly over its frames).

    Sampling a view with probability proportional to its weight is then exactly "with
    probability 0.5 an original view, else a novel view from video j with probability w_j".
    Without novel data every batch is original.
    """
    from recondreamer.recon.data import ORIGINAL

    if not novel_sources:
        training_set.set_source_weight(ORIGINAL, 1.0)
        return
    training_set.set_source_weight(ORIGINAL, 1.0 - novel_fraction)
    for source, weight in zip(novel_sources, video_weights(len(novel_sources))):
        training_set.set_source_weight(source, novel_fraction * float(weight))


def coverage_gap(trained_offsets: list[float], target_offsets: np.ndarray) -> float:
    """Largest distance (m) from a target lateral offset to the nearest trained one (0 = original).

    Used to state how the constant-shift offsets trained by PDUS cover the lane change, whose
    drifts linearly from 0 to 3.9 m to the left over the clip.
    """
    trained = np.asarray([0.0, *trained_offsets], dtype=np.float64)
    targets = np.asarray(target_offsets, dtype=np.float64)
    if targets.size == 0:
        return 0.0
    return float(np.abs(targets[:, None] - trained[None, :]).min(axis=1).max())
