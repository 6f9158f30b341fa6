"""experiments/residual_scale.py: the scaled correction between a render and its restored clip."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SPEC = importlib.util.spec_from_file_location("residual_scale", REPO / "experiments" / "residual_scale.py")
residual_scale = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(residual_scale)


def test_scale_zero_is_the_render_and_one_the_restored_clip():
    rng = np.random.default_rng(0)
    render, restored = (rng.integers(0, 256, size=(2, 4, 6, 3), dtype=np.uint8) for _ in range(2))
    np.testing.assert_array_equal(residual_scale.scaled(render, restored, 0.0), render)
    np.testing.assert_array_equal(residual_scale.scaled(render, restored, 1.0), restored)


def test_half_scale_lies_midway_and_large_scales_clip_to_the_pixel_range():
    render = np.full((1, 1, 2, 3), 100, np.uint8)
    restored = np.array([[[[110] * 3, [0] * 3]]], np.uint8)
    half = residual_scale.scaled(render, restored, 0.5)
    assert half.dtype == np.uint8 and half[0, 0, 0, 0] == 105 and half[0, 0, 1, 0] == 50
    tripled = residual_scale.scaled(render, restored, 3.0)
    assert tripled[0, 0, 0, 0] == 130 and tripled[0, 0, 1, 0] == 0  # 100 - 300 clipped at 0
