"""experiments/refiner_bound.py: clipping a refiner's rounded output after the fact is the bounded refiner."""

from __future__ import annotations

import dataclasses
import importlib.util
from pathlib import Path

import numpy as np
import pytest
import torch
from test_generative_models import H, W
from test_generative_refiner import TINY, randomised

from recondreamer.generative.refiner import PixelRefiner, refine_frames

REPO = Path(__file__).resolve().parents[1]
SPEC = importlib.util.spec_from_file_location("refiner_bound", REPO / "experiments" / "refiner_bound.py")
refiner_bound = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(refiner_bound)

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.mark.parametrize("bound", [1, 3, 12])
def test_clipping_the_unbounded_output_equals_the_refiner_run_with_that_bound(bound):
    torch.manual_seed(0)
    refiner = randomised(PixelRefiner(dataclasses.replace(TINY, max_correction=0.0), 0))
    rng = np.random.default_rng(bound)
    restored = rng.integers(0, 256, (3, H, W, 3), dtype=np.uint8)
    restored[0, :4] = 255  # saturated pixels: the clip to 0..255 and the bound must combine as the refiner's do
    restored[1, :4] = 0
    degraded = rng.integers(0, 256, (3, H, W, 3), dtype=np.uint8)
    unbounded = refine_frames(refiner, restored, degraded, None)
    assert np.abs(unbounded.astype(int) - restored).max() > bound  # the bound has something to clip
    refiner.config = dataclasses.replace(refiner.config, max_correction=float(bound))
    assert np.array_equal(refiner_bound.clipped(restored, unbounded, bound), refine_frames(refiner, restored, degraded, None))
