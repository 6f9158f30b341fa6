"""dd2_mask training masks fall on the sky/scene boundary band and the distant centre only."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from recondreamer.generative.config import MaskConfig
from recondreamer.generative.masks import mask_regions, sample_clip_masks, sample_keep_mask, vanishing_point

# Small tensors: one torch thread each (tests/conftest.py).
pytestmark = pytest.mark.usefixtures("one_torch_thread")


H, W = 80, 120


def wavy_sky(height: int = H, width: int = W) -> np.ndarray:  # (H,W) bool, sky above a wavy skyline
    skyline = (0.3 * height + 6 * np.sin(np.arange(width) / 7.0)).astype(int)
    return np.arange(height)[:, None] < skyline[None, :]


def test_vanishing_point_of_a_level_forward_camera_is_the_principal_point():
    K = np.array([[100.0, 0, 60], [0, 100.0, 35], [0, 0, 1]])
    # OpenCV camera looking along ego x (forward): camera z = world x, camera x = -world y, camera y = -world z.
    cam_to_world = np.eye(4)
    cam_to_world[:3, :3] = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], dtype=float)
    uv = vanishing_point(K, cam_to_world, np.eye(4))
    assert np.allclose(uv, [60, 35])
    # Yaw the ego (and camera) by 10 degrees: the forward direction stays at the principal point.
    yaw = np.deg2rad(10.0)
    rot = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    ego = np.eye(4)
    ego[:3, :3] = rot
    cam = cam_to_world.copy()
    cam[:3, :3] = rot @ cam_to_world[:3, :3]
    assert np.allclose(vanishing_point(K, cam, ego), [60, 35])
    # Pitch the camera down by atan(0.1): the horizon moves up by f * 0.1 = 10 px.
    pitch = np.arctan(0.1)
    down = np.array([[np.cos(pitch), 0, np.sin(pitch)], [0, 1, 0], [-np.sin(pitch), 0, np.cos(pitch)]])
    cam[:3, :3] = down @ cam_to_world[:3, :3]
    assert np.allclose(vanishing_point(K, cam, np.eye(4)), [60, 25])


def test_band_follows_the_sky_boundary_and_falls_back_to_the_horizon():
    config = MaskConfig()
    sky = wavy_sky()
    band, center = mask_regions(H, W, config, np.array([60.0, 30.0]), sky)
    # Independent computation: distance of every pixel to the nearest boundary pixel.
    boundary = np.argwhere(sky & ~np.roll(sky, -1, axis=0))  # last sky row of each column
    radius = config.band_half_width * H
    for r, c in [(5, 5), (20, 40), (70, 100)] + [tuple(p) for p in boundary[::17]]:
        distance = np.min(np.hypot(boundary[:, 0] - r, boundary[:, 1] - c))
        if distance <= radius - 1.5:
            assert band[r, c]
        if distance > radius + 1.5:
            assert not band[r, c]
    assert center[30, 60] and not center[30, 5] and not center[75, 60]
    # No sky boundary (all ground): horizontal band around the horizon row.
    band2, _ = mask_regions(H, W, config, np.array([60.0, 30.0]), np.zeros((H, W), bool))
    rows = np.flatnonzero(band2.any(axis=1))
    assert rows.min() >= 30 - radius and rows.max() <= 30 + radius and band2[30].all()


@pytest.mark.parametrize("with_sky", [True, False])
def test_masked_pixels_lie_only_in_the_specified_regions(with_sky):
    config = dataclasses.replace(MaskConfig(), probability=1.0)
    rng = np.random.default_rng(0)
    sky = wavy_sky() if with_sky else None
    uv = np.array([55.0, 28.0])
    band, center = mask_regions(H, W, config, uv, sky)
    masked_total = 0
    for _ in range(30):
        keep = sample_keep_mask(H, W, config, rng, uv, sky)
        masked = ~keep
        assert not (masked & ~(band | center)).any()
        masked_total += masked.sum()
        assert masked.any()
    # Masks do cover a real part of both regions over many draws.
    assert masked_total > 30 * 0.02 * H * W


def test_mask_probability_controls_how_many_frames_are_masked():
    rng = np.random.default_rng(1)
    uv = np.array([60.0, 30.0])
    none = sample_clip_masks(40, H, W, dataclasses.replace(MaskConfig(), probability=0.0), rng, uv)
    assert none.all()
    half = sample_clip_masks(400, 16, 24, dataclasses.replace(MaskConfig(), probability=0.5), rng, np.array([12.0, 8.0]))
    masked_frames = (~half).any(axis=(1, 2)).mean()
    assert 0.4 < masked_frames < 0.6
