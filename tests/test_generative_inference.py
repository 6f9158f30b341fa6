"""Windowed restoration, checkpoints and input checking of the generative stack (tiny sizes)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from test_generative_models import STRUCTURE, H, W, tiny_model

from recondreamer.errors import CheckpointError, RecondreamerError
from recondreamer.generative import inference
from recondreamer.generative.autoencoder import decode_latents, encode_frames
from recondreamer.generative.checkpoint import load_checkpoint, save_checkpoint
from recondreamer.generative.config import RestoreConfig
from recondreamer.generative.data import structure_from_uint8, structure_to_uint8
from recondreamer.generative.inference import (
    blend_windows,
    clip_noise,
    generate_clip,
    load_restorer,
    load_world_model,
    restore_clip,
    window_starts,
)
from recondreamer.generative.models import autoencoder_payload, model_config_dict

# Small tensors: one torch thread each (tests/conftest.py).
pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_window_starts_cover_the_clip_and_end_on_its_last_frame():
    assert window_starts(5, 8, 2) == [0]
    assert window_starts(16, 8, 0) == [0, 8]
    assert window_starts(20, 8, 2) == [0, 6, 12]
    assert window_starts(21, 8, 2) == [0, 6, 12, 13]
    with pytest.raises(ValueError, match="overlap"):
        window_starts(10, 4, 4)


def test_blending_is_a_partition_of_unity_with_linear_cross_fades():
    # Each window returns a constant = its index: the blend shows the weights directly.
    calls = []

    def sample_window(start, end):
        calls.append((start, end))
        return torch.full((end - start, 1), float(len(calls) - 1))

    blended = blend_windows(14, 8, 2, sample_window)[:, 0]
    assert calls == [(0, 8), (6, 14)]
    expected = torch.tensor([0.0] * 6 + [1 / 3, 2 / 3] + [1.0] * 6)
    assert torch.allclose(blended, expected)
    # Constant input stays constant whatever the windows (weights sum to one).
    flat = blend_windows(21, 8, 3, lambda s, e: torch.ones(e - s, 2))
    assert torch.allclose(flat, torch.ones(21, 2))


def test_windowed_restoration_equals_single_window_restoration_without_overlap():
    restorer = tiny_model("dd2_mask", kind="restorer")
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, size=(8, H, W, 3), dtype=np.uint8)
    structure = rng.random((8, len(STRUCTURE), H, W)).astype(np.float32)
    long = restore_clip(restorer, frames, structure, window=4, overlap=0, num_steps=2, seed=7)
    # Each 4-frame window sampled on its own from the same slice of the clip's noise.
    latents = encode_frames(restorer.autoencoder, frames)
    noise = torch.randn(latents.shape, generator=torch.Generator().manual_seed(7))
    s = structure_from_uint8(structure_to_uint8(structure))
    for start in (0, 4):
        window = slice(start, start + 4)
        single = _sample_clip_from_noise(restorer, latents[window], s[window], noise[window])
        assert np.array_equal(long[window], decode_latents(restorer.autoencoder, single))
    # With overlap the windows are cross-faded, so the result differs.
    blended = restore_clip(restorer, frames, structure, window=4, overlap=2, num_steps=2, seed=7)
    assert not np.array_equal(blended, long)


def _sample_clip_from_noise(restorer, latents, structure, noise):
    """One window sampled directly with the DDIM sampler, as an independent reference."""
    from recondreamer.generative.diffusion import ddim_sample

    def model_fn(x, t):
        return restorer.unet(x, t, latents[0][None], structure=structure[None], degraded=latents[None])

    return ddim_sample(model_fn, restorer.schedule, noise[None], 2)[0]


def test_averaged_samples_are_the_mean_of_single_samples_from_the_same_noise():
    restorer = tiny_model("dd2_mask", kind="restorer")
    rng = np.random.default_rng(2)
    frames = rng.integers(0, 256, size=(4, H, W, 3), dtype=np.uint8)
    structure = rng.random((4, len(STRUCTURE), H, W)).astype(np.float32)
    latents = encode_frames(restorer.autoencoder, frames)
    s = structure_from_uint8(structure_to_uint8(structure))
    noise = clip_noise(latents, 3, seed=5)
    # The first draw is a single-sample restoration's noise.
    assert torch.equal(noise[0], torch.randn(latents.shape, generator=torch.Generator().manual_seed(5)))
    assert torch.equal(clip_noise(latents, 1, seed=5)[0], noise[0])
    batched = inference._sample_clip(restorer, latents, s, latents, 2, 4, 0, 1.0, noise)
    singles = [_sample_clip_from_noise(restorer, latents, s, noise[k]) for k in range(3)]
    assert torch.allclose(batched, torch.stack(singles).mean(dim=0), atol=1e-5)
    assert not torch.allclose(singles[0], singles[1], atol=1e-3)  # the draws differ, so the mean is not one of them
    one = restore_clip(restorer, frames, structure, window=4, num_steps=2, seed=5)
    assert np.array_equal(one, restore_clip(restorer, frames, structure, window=4, num_steps=2, seed=5, samples=1))
    assert not np.array_equal(one, restore_clip(restorer, frames, structure, window=4, num_steps=2, seed=5, samples=3))
    with pytest.raises(RecondreamerError, match="samples must be >= 1"):
        restore_clip(restorer, frames, structure, samples=0)


def test_generation_follows_the_structure_conditions():
    world = tiny_model("dd2")
    rng = np.random.default_rng(1)
    reference = rng.integers(0, 256, size=(4, H, W, 3), dtype=np.uint8)
    structure = rng.random((4, len(STRUCTURE), H, W)).astype(np.float32)
    a = generate_clip(world, reference, structure, num_steps=2, window=4, seed=0)
    b = generate_clip(world, reference, structure, num_steps=2, window=4, seed=0)
    c = generate_clip(world, reference, np.zeros_like(structure), num_steps=2, window=4, seed=0)
    assert a.shape == reference.shape and np.array_equal(a, b) and not np.array_equal(a, c)


def test_bad_inputs_give_clear_errors():
    restorer = tiny_model("dd2_mask", kind="restorer")
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, size=(4, H, W, 3), dtype=np.uint8)
    structure = rng.random((4, len(STRUCTURE), H, W)).astype(np.float32)
    with pytest.raises(RecondreamerError, match="needs structure conditions"):
        restore_clip(restorer, frames, None)
    with pytest.raises(RecondreamerError, match="structure conditions have shape"):
        restore_clip(restorer, frames, structure[:, :, :16])
    with pytest.raises(RecondreamerError, match="not divisible"):
        restore_clip(restorer, frames[:, :30], structure[:, :, :30])
    with pytest.raises(RecondreamerError, match="uint8"):
        restore_clip(restorer, frames.astype(np.float32), structure)
    with pytest.raises(RecondreamerError, match="needs a restorer"):
        restore_clip(tiny_model("dd2"), frames, structure)
    with pytest.raises(RecondreamerError, match="pretrained world model"):
        generate_clip(restorer, frames, structure)


def _save_model(path, model):
    save_checkpoint(
        path, model.kind, model.arch, model_config_dict(model), model.unet.state_dict(),
        autoencoder=autoencoder_payload(model.autoencoder),
    )


def test_checkpoints_round_trip_and_wrong_kinds_are_rejected(tmp_path):
    restorer = tiny_model("svd", kind="restorer")
    restorer.restore_config = RestoreConfig(window=4, overlap=1, sample_steps=2, seed=5)
    _save_model(tmp_path / "r.pt", restorer)
    loaded = load_restorer(tmp_path / "r.pt")
    assert loaded.arch == "svd" and loaded.restore_config == restorer.restore_config
    frames = np.random.default_rng(0).integers(0, 256, size=(6, H, W, 3), dtype=np.uint8)
    assert np.array_equal(restore_clip(loaded, frames, None), restore_clip(restorer, frames, None))

    with pytest.raises(CheckpointError, match="kind is 'restorer', expected 'world_model'"):
        load_world_model(tmp_path / "r.pt")
    with pytest.raises(CheckpointError, match="does not exist"):
        load_restorer(tmp_path / "missing.pt")
    torch.save({"something": 1}, tmp_path / "foreign.pt")
    with pytest.raises(CheckpointError, match="not a recondreamer"):
        load_restorer(tmp_path / "foreign.pt")
    (tmp_path / "garbage.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="not a readable"):
        load_checkpoint(tmp_path / "garbage.pt", "restorer")


def test_residual_decoding_adds_only_the_decoded_change_to_the_input(monkeypatch):
    restorer = tiny_model("dd2_mask", kind="restorer")
    rng = np.random.default_rng(2)
    frames = rng.integers(0, 256, size=(5, H, W, 3), dtype=np.uint8)
    structure = rng.random((5, len(STRUCTURE), H, W)).astype(np.float32)
    plain = restore_clip(restorer, frames, structure, window=4, overlap=1, seed=3)
    residual = restore_clip(restorer, frames, structure, window=4, overlap=1, seed=3, residual_decoding=True)
    reconstruction = decode_latents(restorer.autoencoder, encode_frames(restorer.autoencoder, frames)).astype(np.int32)
    expected = np.clip(frames.astype(np.int32) + plain.astype(np.int32) - reconstruction, 0, 255)
    assert np.array_equal(residual, expected)
    assert not np.array_equal(residual, plain)
    # A restorer that returns the input's own latents changes nothing at all.
    monkeypatch.setattr(inference, "_sample_clip", lambda model, reference, *args: reference)
    assert np.array_equal(restore_clip(restorer, frames, structure, residual_decoding=True), frames)
