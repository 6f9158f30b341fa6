"""The PDUS schedule (Algorithm 1), the 50/50 mixing and the lane-change coverage, without training."""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest

from recondreamer.errors import RecondreamerError
from recondreamer.methods.pdus import (
    PdusSchedule,
    apply_mixing,
    coverage_gap,
    newest_weight,
    video_weights,
)
from recondreamer.recon.data import TrainingSet, TrainingView
from recondreamer.scene.trajectories import lateral_offsets


def test_weights_follow_algorithm_1_exactly():
    assert np.allclose(video_weights(1), [1.0])
    assert np.allclose(video_weights(2), [1 / 3, 2 / 3])
    assert np.allclose(video_weights(3), [1 / 6, 2 / 6, 3 / 6])
    assert newest_weight(1) == 1.0 and newest_weight(2) == pytest.approx(2 / 3) and newest_weight(4) == pytest.approx(0.4)
    # Independent exact computation: apply D = (1 - w) D U w V with rationals, compare to j / sum(i).
    exact: list[Fraction] = []
    for k in range(1, 9):
        w = Fraction(k, sum(range(1, k + 1)))
        exact = [(1 - w) * p for p in exact] + [w]
        assert exact == [Fraction(j, k * (k + 1) // 2) for j in range(1, k + 1)]
        assert np.allclose(video_weights(k), [float(p) for p in exact], rtol=0, atol=1e-12)
        assert video_weights(k).sum() == pytest.approx(1.0)
    with pytest.raises(ValueError):
        newest_weight(0)


def test_schedule_steps_offsets_and_the_no_pdus_stride():
    schedule = PdusSchedule.for_iterations(1.5, 2000)
    assert schedule.update_every == 400 and schedule.num_updates == 4
    assert [schedule.update_step(k) for k in range(1, 5)] == [400, 800, 1200, 1600]
    assert schedule.offsets() == [1.5, 3.0, 4.5, 6.0]
    # Updates due before a step: none before S, k after k*S, never more than planned.
    assert [schedule.updates_due(s) for s in (0, 399, 400, 401, 1599, 1600, 1999)] == [0, 0, 1, 1, 3, 4, 4]
    # Stride 6 m: one jump straight to the widest shift, then the same offset refreshed.
    assert PdusSchedule.for_iterations(6.0, 2000).offsets() == [6.0, 6.0, 6.0, 6.0]
    assert PdusSchedule.for_iterations(3.0, 2000).offsets() == [3.0, 6.0, 6.0, 6.0]
    assert PdusSchedule.for_iterations(0.5, 300, update_every=60, max_offset=1.0).offsets() == [0.5, 1.0, 1.0, 1.0]
    for bad in ({"stride": 0.0}, {"stride": float("nan")}, {"update_every": 0}, {"max_offset": -1.0}):
        with pytest.raises(RecondreamerError):
            PdusSchedule(**{"stride": 1.5, "update_every": 10, "iterations": 100, **bad})


def _views(source: str, count: int) -> list[TrainingView]:
    image = np.zeros((4, 6, 3), dtype=np.uint8)
    return [TrainingView(np.eye(4), float(i), image, source=source) for i in range(count)]


def test_mixing_draws_half_original_and_novel_videos_by_their_weights():
    # Unequal view counts per source: the weights must be per source, not per view.
    training_set = TrainingSet(np.eye(3), 6, 4, _views("original", 10))
    apply_mixing(training_set, [])
    assert np.allclose(training_set.probabilities(), 0.1)
    sources = ["pdus1@1.5m", "pdus2@3m", "pdus3@4.5m"]
    for source, count in zip(sources, (3, 7, 5)):
        training_set.extend(_views(source, count))
    apply_mixing(training_set, sources)
    rng = np.random.default_rng(0)
    draws = 40000
    counts = {name: 0 for name in ["original", *sources]}
    for _ in range(draws):
        counts[training_set.sample(rng).source] += 1
    expected = {"original": 0.5, **{s: 0.5 * w for s, w in zip(sources, [1 / 6, 2 / 6, 3 / 6])}}
    for name, p in expected.items():
        # Binomial standard error at 40k draws is <= 0.0025: 4 sigma.
        assert abs(counts[name] / draws - p) < 0.01, (name, counts[name] / draws, p)


def test_lane_change_coverage_of_the_progressive_offsets():
    lane_change = lateral_offsets("lane_change", 40)  # 0 .. 3.9 m in 0.1 m steps (40 frames)
    # 0, 1.5, 3, 4.5, 6: the worst lane-change poses (0.7/0.8, 2.2/2.3 m) are 0.7 m from a trained one.
    assert coverage_gap(PdusSchedule.for_iterations(1.5, 2000).offsets(), lane_change) == pytest.approx(0.7)
    # No PDUS (6 m at once) leaves the middle of the lane change 3 m from anything trained.
    assert coverage_gap([6.0], lane_change) == pytest.approx(3.0)
    assert coverage_gap([], np.array([0.0, 0.2])) == pytest.approx(0.2)
