"""Residual target space and high-timestep sampling of DriveRestorer training (tiny sizes)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from test_generative_models import H, W, tiny_model

from recondreamer.generative.autoencoder import decode_latents, encode_frames
from recondreamer.generative.config import DiffusionConfig
from recondreamer.generative.data import Sequence
from recondreamer.generative.diffusion import NoiseSchedule, diffusion_loss_and_estimate
from recondreamer.generative.inference import restore_clip
from recondreamer.generative.training import residual_scale, sample_batch, unet_loss

# Small tensors: one torch thread each (tests/conftest.py).
pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.mark.parametrize("power", [1.0, 3.0, 8.0])
def test_timestep_sampler_follows_its_power_law(power):
    schedule = NoiseSchedule(DiffusionConfig())
    steps = schedule.sample_timesteps(40000, power, torch.Generator().manual_seed(0))
    assert steps.min() >= 0 and steps.max() <= 999
    # Density ~ t^(power-1) on [0, 1000): P(t < x * 1000) = x^power.
    for x in (0.25, 0.5, 0.9):
        assert abs((steps < x * 1000).float().mean().item() - x**power) < 0.01


def test_timestep_sampler_rejects_a_non_positive_power():
    with pytest.raises(ValueError, match="power"):
        NoiseSchedule(DiffusionConfig()).sample_timesteps(4, 0.0)


def test_residual_space_maps_the_degraded_latent_to_zero_and_round_trips():
    schedule = NoiseSchedule(DiffusionConfig(target_space="residual", residual_scale=0.5))
    g = torch.Generator().manual_seed(1)
    clean, degraded = torch.randn(2, 3, 4, 5, 6, generator=g), torch.randn(2, 3, 4, 5, 6, generator=g)
    assert torch.equal(schedule.to_diffusion_space(degraded, degraded), torch.zeros_like(degraded))
    assert torch.allclose(schedule.to_diffusion_space(clean, degraded), (clean - degraded) * 2.0)
    assert torch.allclose(schedule.from_diffusion_space(schedule.to_diffusion_space(clean, degraded), degraded), clean, atol=1e-6)
    # Clean space (world models) is the identity.
    plain = NoiseSchedule(DiffusionConfig())
    assert plain.to_diffusion_space(clean, None) is clean and plain.from_diffusion_space(clean, None) is clean


@pytest.mark.parametrize("bad", [{"target_space": "pixels"}, {"residual_scale": 0.0}])
def test_bad_target_space_settings_are_rejected(bad):
    with pytest.raises(ValueError, match="target space|residual scale"):
        NoiseSchedule(DiffusionConfig(**bad))


def _residual_restorer(arch: str, prediction: str):
    model = tiny_model(arch, kind="restorer")
    config = DiffusionConfig(sample_steps=3, prediction=prediction, target_space="residual", residual_scale=0.7)
    return dataclasses.replace(model, diffusion_config=config, schedule=NoiseSchedule(config))


@pytest.mark.parametrize("arch", ["sd", "dd2_mask"])
def test_a_residual_restorer_that_predicts_no_correction_returns_its_input(arch):
    # x0 prediction of the residual with a zeroed output layer: the network says "no correction"
    # at every step, so the restored latent is the degraded latent whatever the noise and steps.
    restorer = _residual_restorer(arch, "x0")
    with torch.no_grad():
        restorer.unet.conv_out.weight.zero_()
        restorer.unet.conv_out.bias.zero_()
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, size=(6, H, W, 3), dtype=np.uint8)
    structure = rng.random((6, 3, H, W)).astype(np.float32) if arch == "dd2_mask" else None
    for steps, strength in ((1, 1.0), (3, 1.0), (2, 0.5)):
        kept = restore_clip(restorer, frames, structure, num_steps=steps, strength=strength, window=4, overlap=2, residual_decoding=True)
        assert np.array_equal(kept, frames)
        decoded = restore_clip(restorer, frames, structure, num_steps=steps, strength=strength, window=4, overlap=2, residual_decoding=False)
        assert np.array_equal(decoded, decode_latents(restorer.autoencoder, encode_frames(restorer.autoencoder, frames)))


def test_a_residual_restorer_with_a_trained_output_changes_its_input():
    restorer = _residual_restorer("sd", "v")  # randomised weights: some correction
    frames = np.random.default_rng(2).integers(0, 256, size=(4, H, W, 3), dtype=np.uint8)
    assert not np.array_equal(restore_clip(restorer, frames, None, num_steps=1, residual_decoding=True), frames)


def test_residual_scale_is_the_standard_deviation_of_the_latent_residuals():
    g = torch.Generator().manual_seed(3)
    sequences = [
        Sequence(name=str(i), scene_id="x", target=torch.randn(5, 2, 3, 4, generator=g), reference=torch.zeros(5, 2, 3, 4),
                 structure=None, degraded=torch.randn(k, 5, 2, 3, 4, generator=g))
        for i, k in enumerate((1, 3))
    ]
    residuals = np.concatenate([(s.degraded - s.target[None]).numpy().ravel() for s in sequences])
    assert residual_scale(sequences) == pytest.approx(float(np.sqrt(np.mean(residuals**2))), rel=1e-5)


def test_residual_training_loss_targets_the_scaled_residual():
    # The loss of a residual restorer equals the plain diffusion loss of (target - degraded) / scale.
    restorer = _residual_restorer("sd", "v")
    rng = np.random.default_rng(0)
    seq = Sequence(name="s", scene_id="x", target=torch.randn(6, 4, 8, 12), reference=torch.randn(6, 4, 8, 12),
                   structure=None, degraded=torch.randn(2, 6, 4, 8, 12))
    batch = sample_batch([seq], rng, restorer.train_config, 4, False, True)
    got = unet_loss(restorer.unet, restorer.schedule, batch, torch.Generator().manual_seed(4), timestep_power=3.0)

    def model_fn(noisy, timesteps):
        return restorer.unet(noisy, timesteps, batch["reference"], degraded=batch["degraded"])

    x0 = (batch["target"] - batch["degraded"]) / 0.7
    expected = diffusion_loss_and_estimate(model_fn, restorer.schedule, x0, torch.Generator().manual_seed(4), timestep_power=3.0)[0]
    assert torch.allclose(got, expected)
    clean = diffusion_loss_and_estimate(model_fn, restorer.schedule, batch["target"], torch.Generator().manual_seed(4), timestep_power=3.0)[0]
    assert not torch.allclose(got, clean)


def test_pair_latents_are_cached_per_autoencoder_and_equal_fresh_encodings(tmp_path):
    from recondreamer.generative.autoencoder import Autoencoder
    from recondreamer.generative.config import AutoencoderConfig
    from recondreamer.generative.data import autoencoder_digest, load_pair_sequences

    rng = np.random.default_rng(0)
    gt = rng.integers(0, 256, size=(3, H, W, 3), dtype=np.uint8)
    degraded = rng.integers(0, 256, size=(2, 3, H, W, 3), dtype=np.uint8)
    path = tmp_path / "a__run.npz"
    np.savez(path, gt=gt, degraded=degraded, stages=np.array([1, 2]), structure=np.zeros((3, 1, H, W), np.uint8),
             vanishing=np.zeros((3, 2)), scene_id=np.array("a"))
    torch.manual_seed(0)
    first, second = (Autoencoder(AutoencoderConfig(hidden_channels=(8, 8, 8))).eval() for _ in range(2))
    assert autoencoder_digest(first) != autoencoder_digest(second)

    fresh = load_pair_sequences([path], first, False, False)[0]
    cache = tmp_path / f"a__run.latents-{autoencoder_digest(first)}.pt"
    assert cache.is_file()
    assert torch.equal(fresh.target, encode_frames(first, gt))
    assert torch.equal(fresh.degraded[1], encode_frames(first, degraded[1]))
    # A second load reads the cache (poisoned here to prove it is read; fresh's latents are maps of
    # the cache file, so they are copied before it is rewritten) ...
    poisoned = fresh.target + 1.0
    torch.save({"gt": poisoned, "degraded": fresh.degraded.clone()}, cache)
    assert torch.equal(load_pair_sequences([path], first, False, False)[0].target, poisoned)
    # ... and another autoencoder gets its own latents, not those of the first.
    other = load_pair_sequences([path], second, False, False)[0]
    assert torch.equal(other.target, encode_frames(second, gt))


def test_pair_frames_are_memory_mapped_equal_the_pairs_file_and_remade_when_stale(tmp_path):
    import os

    from recondreamer.generative.autoencoder import Autoencoder
    from recondreamer.generative.config import AutoencoderConfig
    from recondreamer.generative.data import load_pair_sequences

    rng = np.random.default_rng(1)
    arrays = {
        "gt": rng.integers(0, 256, size=(3, H, W, 3), dtype=np.uint8),
        "degraded": rng.integers(0, 256, size=(2, 3, H, W, 3), dtype=np.uint8),
        "structure": rng.integers(0, 256, size=(3, 2, H, W), dtype=np.uint8),
        "sky": rng.random((3, H, W)) < 0.3,
    }
    path = tmp_path / "a__run.npz"
    np.savez(path, stages=np.array([1, 2]), vanishing=np.zeros((3, 2)), scene_id=np.array("a"), **arrays)
    torch.manual_seed(0)
    autoencoder = Autoencoder(AutoencoderConfig(hidden_channels=(8, 8, 8))).eval()

    seq = load_pair_sequences([path], autoencoder, True, True)[0]
    cache = tmp_path / "a__run.arrays.pt"
    assert cache.is_file()
    for got, name in ((seq.target_frames, "gt"), (seq.degraded_frames, "degraded"), (seq.structure, "structure"), (seq.sky_masks, "sky")):
        np.testing.assert_array_equal(got, arrays[name])
        assert got.dtype == arrays[name].dtype
    # Writing to a map (training masks copies, but a caller may not) leaves the copy on disk intact.
    seq.degraded_frames[0, 0] = 0
    again = load_pair_sequences([path], autoencoder, False, True)[0]
    np.testing.assert_array_equal(again.degraded_frames, arrays["degraded"])
    assert again.structure is None
    # A pairs file newer than its copy, with other frames of the same shape, gets a new copy.
    arrays["gt"] = 255 - arrays["gt"]
    np.savez(path, stages=np.array([1, 2]), vanishing=np.zeros((3, 2)), scene_id=np.array("a"), **arrays)
    os.utime(cache, (1, 1))
    np.testing.assert_array_equal(load_pair_sequences([path], autoencoder, False, True)[0].target_frames, arrays["gt"])
