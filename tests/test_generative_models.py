"""Diffusion UNets, DDIM, autoencoder and training steps of the generative stack (tiny sizes)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from recondreamer.generative.autoencoder import Autoencoder, decode_latents, encode_frames
from recondreamer.generative.config import ARCHS, AutoencoderConfig, DiffusionConfig, TrainConfig, UNetConfig
from recondreamer.generative.data import Sequence
from recondreamer.generative.diffusion import NoiseSchedule, ddim_sample
from recondreamer.generative.inference import restore_clip
from recondreamer.generative.models import GenerativeModel, restorer_unet_from_world_model
from recondreamer.generative.training import sample_batch, unet_loss
from recondreamer.generative.unet import LatentUNet

# Small tensors: one torch thread each (tests/conftest.py).
pytestmark = pytest.mark.usefixtures("one_torch_thread")

STRUCTURE = ("boxes", "lanes", "edges")


H, W = 32, 48  # pixels; latents 8x12


def tiny_unet_config(arch: str, degraded: bool = False) -> UNetConfig:
    return UNetConfig(
        arch=arch, channels=(8, 16), attention_levels=(False, True), temporal_levels=(True, True), num_heads=2,
        time_embed_dim=16, structure_channels=len(STRUCTURE) if arch.startswith("dd2") else 0, structure_hidden=4,
        degraded_condition=degraded,
    )


def tiny_model(arch: str, kind: str = "world_model", seed: int = 0) -> GenerativeModel:
    torch.manual_seed(seed)
    unet = LatentUNet(tiny_unet_config(arch, degraded=kind == "restorer"))
    # Zero-initialised layers would hide bugs in the branches they close: randomise everything.
    with torch.no_grad():
        for parameter in unet.parameters():
            parameter.normal_(0.0, 0.1)
    diffusion = DiffusionConfig(sample_steps=3)
    return GenerativeModel(
        kind=kind, arch=arch, unet=unet.eval(), autoencoder=Autoencoder(AutoencoderConfig(hidden_channels=(8, 8, 8))).eval(),
        schedule=NoiseSchedule(diffusion), unet_config=unet.config, diffusion_config=diffusion,
        train_config=TrainConfig(window=4, crop=(0, 0), batch_size=2), structure_channels=STRUCTURE if arch.startswith("dd2") else (),
        frame_size=(H, W),
    )


def random_inputs(arch: str, b: int = 2, t: int = 4, seed: int = 1) -> dict:
    g = torch.Generator().manual_seed(seed)
    return {
        "noisy": torch.randn(b, t, 4, H // 4, W // 4, generator=g),
        "timesteps": torch.randint(0, 1000, (b,), generator=g),
        "reference": torch.randn(b, 4, H // 4, W // 4, generator=g),
        "structure": torch.rand(b, t, len(STRUCTURE), H, W, generator=g) if arch.startswith("dd2") else None,
    }


@pytest.mark.parametrize("arch", ARCHS)
def test_unet_output_shape_and_seeded_sampling_is_deterministic(arch):
    model = tiny_model(arch)
    x = random_inputs(arch)
    out = model.unet(x["noisy"], x["timesteps"], x["reference"], structure=x["structure"])
    assert out.shape == x["noisy"].shape

    def model_fn(noisy, timesteps):
        return model.unet(noisy, timesteps, x["reference"], structure=x["structure"])

    def sample(seed):
        noise = torch.randn(x["noisy"].shape, generator=torch.Generator().manual_seed(seed))
        return ddim_sample(model_fn, model.schedule, noise, num_steps=3)

    first, again, other = sample(5), sample(5), sample(6)
    assert torch.equal(first, again)
    assert not torch.allclose(first, other)


def test_image_model_is_per_frame_and_video_models_mix_frames():
    for arch, mixes in (("sd", False), ("svd", True), ("dd2", True)):
        model = tiny_model(arch)
        x = random_inputs(arch, b=1)
        out = model.unet(x["noisy"], x["timesteps"], x["reference"], structure=x["structure"])
        changed = x["noisy"].clone()
        changed[:, 3] += 1.0  # perturb the last frame only
        out2 = model.unet(changed, x["timesteps"], x["reference"], structure=x["structure"])
        first_frames_changed = not torch.allclose(out[:, :3], out2[:, :3], atol=1e-6)
        assert first_frames_changed == mixes, arch


def test_structure_conditions_change_the_dd2_prediction():
    model = tiny_model("dd2")
    x = random_inputs("dd2")
    out = model.unet(x["noisy"], x["timesteps"], x["reference"], structure=x["structure"])
    out_other = model.unet(x["noisy"], x["timesteps"], x["reference"], structure=torch.zeros_like(x["structure"]))
    assert not torch.allclose(out, out_other)


@pytest.mark.parametrize("arch", ARCHS)
def test_zero_initialised_degraded_branch_leaves_the_world_model_unchanged(arch):
    world = tiny_model("dd2" if arch == "dd2_mask" else arch)
    restorer_unet = restorer_unet_from_world_model(world, arch).eval()
    x = random_inputs(arch)
    degraded = torch.randn_like(x["noisy"])
    expected = world.unet(x["noisy"], x["timesteps"], x["reference"], structure=x["structure"])
    got = restorer_unet(x["noisy"], x["timesteps"], x["reference"], structure=x["structure"], degraded=degraded)
    assert torch.allclose(got, expected, atol=1e-6)
    # ... and the branch is live: after a nudge of its weights the degraded input matters.
    with torch.no_grad():
        restorer_unet.degraded_in.weight.add_(0.1)
    nudged = restorer_unet(x["noisy"], x["timesteps"], x["reference"], structure=x["structure"], degraded=degraded)
    assert not torch.allclose(nudged, expected, atol=1e-4)


def test_restorer_from_the_wrong_world_model_is_rejected():
    from recondreamer.errors import CheckpointError

    with pytest.raises(CheckpointError, match="dd2"):
        restorer_unet_from_world_model(tiny_model("svd"), "dd2_mask")


@pytest.mark.parametrize("arch", ["sd", "dd2_mask"])
def test_one_training_step_lowers_the_loss_on_a_fixed_batch(arch):
    model = tiny_model(arch, kind="restorer")
    rng = np.random.default_rng(0)
    seq = Sequence(
        name="s", scene_id="x", target=torch.randn(6, 4, 8, 12), reference=torch.randn(6, 4, 8, 12),
        structure=rng.integers(0, 256, size=(6, 3, H, W), dtype=np.uint8), degraded=torch.randn(2, 6, 4, 8, 12),
    )
    batch = sample_batch([seq], rng, model.train_config, 4, arch.startswith("dd2"), True)
    optimizer = torch.optim.SGD(model.unet.parameters(), lr=1e-2)

    def loss():
        # The same noise and timesteps every time: a fixed batch.
        return unet_loss(model.unet, model.schedule, batch, torch.Generator().manual_seed(3))

    before = loss()
    optimizer.zero_grad()
    before.backward()
    optimizer.step()
    with torch.no_grad():
        after = loss()
    assert after.item() < before.item()


def test_sample_batch_crops_structure_at_the_matching_pixels():
    rng = np.random.default_rng(0)
    target = torch.arange(6 * 8 * 12, dtype=torch.float32).reshape(6, 1, 8, 12).expand(6, 4, 8, 12).contiguous()
    # Structure channel 0 holds the latent row index of each pixel, channel 1 the latent column.
    rows = np.repeat(np.arange(8), 4)[:, None].repeat(W, axis=1)
    cols = np.repeat(np.arange(12), 4)[None, :].repeat(H, axis=0)
    structure = np.stack([rows, cols, rows * 0]).astype(np.uint8)[None].repeat(6, axis=0)
    seq = Sequence(name="s", scene_id="x", target=target, reference=target, structure=structure)
    train = dataclasses.replace(TrainConfig(), window=3, crop=(4, 5), batch_size=4)
    batch = sample_batch([seq], rng, train, 4, True, False)
    assert batch["target"].shape == (4, 3, 4, 4, 5)
    assert batch["structure"].shape == (4, 3, 3, 16, 20)
    for i in range(4):
        flat = batch["target"][i, 0, 0]  # (4,5) crop of the index map at the clip's first frame
        first = int(flat[0, 0].item()) % (8 * 12)
        y, x = divmod(first, 12)
        assert round(batch["structure"][i, 0, 0, 0, 0].item() * 255) == y
        assert round(batch["structure"][i, 0, 1, 0, 0].item() * 255) == x
        assert torch.equal(batch["reference"][i], batch["target"][i, 0])


def test_restorer_batches_take_the_degraded_clip_start_as_reference():
    rng = np.random.default_rng(0)
    seq = Sequence(
        name="s", scene_id="x", target=torch.randn(6, 4, 8, 12), reference=torch.randn(6, 4, 8, 12), structure=None,
        degraded=torch.randn(3, 6, 4, 8, 12),
    )
    batch = sample_batch([seq], rng, dataclasses.replace(TrainConfig(), window=3, crop=(0, 0), batch_size=3), 4, False, True)
    for i in range(3):
        assert torch.equal(batch["reference"][i], batch["degraded"][i, 0])
        assert any(torch.equal(batch["degraded"][i], seq.degraded[k, s : s + 3]) for k in range(3) for s in range(4))


def test_autoencoder_shapes_and_uint8_round_trip():
    ae = Autoencoder(AutoencoderConfig(hidden_channels=(8, 8, 8))).eval()
    frames = np.random.default_rng(0).integers(0, 256, size=(3, H, W, 3), dtype=np.uint8)
    latents = encode_frames(ae, frames)
    assert latents.shape == (3, 4, H // 4, W // 4)
    decoded = decode_latents(ae, latents)
    assert decoded.shape == frames.shape and decoded.dtype == np.uint8


def test_restore_clip_is_deterministic_under_a_seed():
    restorer = tiny_model("dd2_mask", kind="restorer")
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, size=(5, H, W, 3), dtype=np.uint8)
    structure = rng.random((5, 3, H, W)).astype(np.float32)
    a = restore_clip(restorer, frames, structure, window=4, overlap=1, seed=3)
    b = restore_clip(restorer, frames, structure, window=4, overlap=1, seed=3)
    c = restore_clip(restorer, frames, structure, window=4, overlap=1, seed=4)
    assert a.shape == frames.shape and a.dtype == np.uint8
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_masked_restorer_batches_encode_the_masked_degraded_frames():
    from recondreamer.generative.autoencoder import frames_to_tensor
    from recondreamer.generative.config import MaskConfig

    ae = Autoencoder(AutoencoderConfig(hidden_channels=(8, 8, 8))).eval()
    rng = np.random.default_rng(0)
    pixels = rng.integers(1, 256, size=(1, 4, H, W, 3), dtype=np.uint8)
    latents = encode_frames(ae, pixels[0])[None]
    seq = Sequence(
        name="s", scene_id="x", target=latents[0], reference=latents[0], structure=None, degraded=latents,
        degraded_frames=pixels, vanishing=np.tile([W / 2, H / 2], (4, 1)),
    )
    train = dataclasses.replace(TrainConfig(), window=4, crop=(0, 0), batch_size=1)
    always = dataclasses.replace(MaskConfig(), probability=1.0)
    batch = sample_batch([seq], np.random.default_rng(5), train, 4, False, True, always, ae)
    # Replay the same draws to know which pixels were masked.
    replay = np.random.default_rng(5)
    replay.integers(1), replay.integers(0, 1), replay.integers(0, 1), replay.integers(0, 1), replay.integers(1)
    from recondreamer.generative.masks import sample_clip_masks

    keep = sample_clip_masks(4, H, W, always, replay, seq.vanishing)
    assert (~keep).any(axis=(1, 2)).all()
    with torch.no_grad():
        expected = ae.encode(frames_to_tensor(pixels[0] * keep[..., None]))
    assert torch.allclose(batch["degraded"][0], expected, atol=1e-6)
    assert not torch.allclose(batch["degraded"][0], latents[0])
