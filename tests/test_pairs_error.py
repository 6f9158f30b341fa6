"""experiments/pairs_error.py: where a degraded clip's error sits (edges, road lines, coarse scale)."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SPEC = importlib.util.spec_from_file_location("pairs_error", REPO / "experiments" / "pairs_error.py")
pairs_error = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(pairs_error)

CHANNELS = ["box_vehicle", "road_line", "road_edge"]


def _clip():  # a dark left half and a bright right half: one vertical edge at column 16
    gt = np.full((2, 16, 32, 3), 40, np.uint8)
    gt[:, :, 16:] = 200
    structure = np.zeros((2, len(CHANNELS), 16, 32), np.uint8)
    structure[:, 1, :, 4] = 255  # a road line far from the edge
    return gt, structure


def test_error_only_at_the_edge_is_all_edge_error_and_no_line_error():
    gt, structure = _clip()
    degraded = gt.copy()
    degraded[:, :, 15:17] = 120  # the edge smeared over two columns
    row = pairs_error.error_structure(gt, degraded, structure, CHANNELS)
    assert row["edge_error"] == pytest.approx(1.0) and row["line_error"] == 0.0
    assert 0.0 < row["edge_pixels"] < 0.25 and row["line_pixels"] == pytest.approx(5 / 32)


def test_coarse_oracle_gain_counts_only_what_8x8_block_means_cannot_fix():
    gt, structure = _clip()
    rng = np.random.default_rng(0)
    fine = rng.choice([-4, 4], size=gt.shape)  # zero-mean checker-like noise, the same power everywhere
    offset = 12  # a colour shift, fixed entirely by block means
    degraded = (gt.astype(int) + offset + fine).astype(np.uint8)
    row = pairs_error.error_structure(gt, degraded, structure, CHANNELS)
    fine_part = (fine - fine.reshape(2, 2, 8, 4, 8, 3).mean((2, 4), keepdims=True).repeat(8, 2).repeat(8, 4).reshape(fine.shape)) ** 2
    expected = 10 * np.log10(((offset + fine) ** 2).mean() / fine_part.mean())
    assert row["coarse_oracle_db"] == pytest.approx(expected, rel=1e-9)
    assert row["psnr"] == pytest.approx(-10 * np.log10((((offset + fine) / 255.0) ** 2).mean()))


def test_latent_oracle_is_what_restore_clip_returns_for_a_restorer_that_outputs_the_truth():
    import torch

    from recondreamer.generative.autoencoder import Autoencoder, decode_latents, encode_frames
    from recondreamer.generative.config import AutoencoderConfig
    from recondreamer.generative.inference import residual_decode

    torch.manual_seed(0)
    autoencoder = Autoencoder(AutoencoderConfig(hidden_channels=(8, 8, 8))).eval()
    gt, _ = _clip()
    degraded = (gt.astype(int) + np.random.default_rng(1).integers(-30, 31, size=gt.shape)).clip(0, 255).astype(np.uint8)
    change = decode_latents(autoencoder, encode_frames(autoencoder, gt)).astype(int) - decode_latents(autoencoder, encode_frames(autoencoder, degraded))
    oracle = np.clip(degraded + change, 0, 255)
    expected = pairs_error.psnr(oracle, gt) - pairs_error.psnr(degraded, gt)
    assert pairs_error.latent_oracle_db(autoencoder, gt, degraded) == pytest.approx(expected)
    # A clip that is already the truth gets the zero change: the oracle leaves it exactly as it is.
    assert np.array_equal(residual_decode(autoencoder, gt, encode_frames(autoencoder, gt), encode_frames(autoencoder, gt)), gt)
