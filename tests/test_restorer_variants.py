"""benchmarks/restorer_variants.py: the inference-time variants of a restorer are what they claim to be."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SPEC = importlib.util.spec_from_file_location("restorer_variants", REPO / "benchmarks" / "restorer_variants.py")
variants = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(variants)


def fake_restore_clip(restorer, frames, structure, *, num_steps, seed):
    """Brightens the left half by 10 plus the seed, and marks the structure's left half the same way."""
    assert num_steps == 1
    out = frames.astype(np.int32)
    out[:, :, : frames.shape[2] // 2] += 10 + seed + int(structure[..., : frames.shape[2] // 2].sum() > structure.sum() / 2)
    return np.clip(out, 0, 255).astype(np.uint8)


@pytest.fixture
def clip():
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 200, size=(3, 4, 6, 3), dtype=np.uint8)
    structure = np.zeros((3, 2, 4, 6), dtype=np.float32)
    structure[..., :3] = 1.0  # all structure on the left: the mirrored clip has it on the right
    return frames, structure


def test_variants_combine_restores_as_documented(monkeypatch, clip):
    from recondreamer.restorer import inference

    monkeypatch.setattr(inference, "restore_clip", fake_restore_clip)
    frames, structure = clip
    outputs = variants.variant_outputs(None, frames, structure, seeds=3, gains=[0.5, 2.0])
    left, right = np.s_[:, :, :3], np.s_[:, :, 3:]
    base = frames.astype(np.float64)
    assert np.array_equal(outputs["seed 0"][left], base[left] + 11) and np.array_equal(outputs["seed 0"][right], base[right])
    assert np.array_equal(outputs["mean of 2 seeds"][left], base[left] + 11.5)
    assert np.array_equal(outputs["mean of 3 seeds"][left], base[left] + 12)
    assert np.array_equal(outputs["correction gain 0.5"][left], base[left] + 5.5)
    assert np.array_equal(outputs["correction gain 2"][left], base[left] + 22)
    assert np.array_equal(outputs["restored twice"][left], base[left] + 22)
    # Mirrored: the left half of the flipped clip is the original's right half, whose structure is empty.
    assert np.array_equal(outputs["mirrored"][right], base[right] + 10) and np.array_equal(outputs["mirrored"][left], base[left])
    assert set(outputs) == {"seed 0", "mean of 2 seeds", "mean of 3 seeds", "correction gain 0.5", "correction gain 2", "restored twice", "mirrored"}


def test_mean_psnr_scores_the_clip_as_saved_uint8_frames():
    gt = np.full((2, 4, 4, 3), 100, dtype=np.uint8)
    assert variants.mean_psnr(gt + 0.4, gt) == float("inf")  # rounds back to the truth
    assert variants.mean_psnr(gt.astype(np.float64) + 300, gt) == pytest.approx(10 * np.log10(255**2 / 155**2))  # clipped at 255
