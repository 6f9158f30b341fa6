"""Image-space loss of DriveRestorer training: pixel batches, the loss itself and its gradient (tiny sizes)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from op_tester import BaseTester
from test_generative_models import H, W, tiny_model

from recondreamer.cli import main
from recondreamer.errors import RecondreamerError
from recondreamer.generative.autoencoder import Autoencoder, encode_frames, frames_to_tensor
from recondreamer.generative.config import AutoencoderConfig, DiffusionConfig, MaskConfig, TrainConfig
from recondreamer.generative.data import Sequence
from recondreamer.generative.diffusion import NoiseSchedule, diffusion_loss_and_estimate
from recondreamer.generative.masks import sample_clip_masks
from recondreamer.generative.training import image_space_loss, sample_batch, unet_loss_and_estimate

# Small tensors: one torch thread each (tests/conftest.py).
pytestmark = pytest.mark.usefixtures("one_torch_thread")

RESIDUAL = DiffusionConfig(target_space="residual", residual_scale=0.7)


def pixel_sequence(ae: Autoencoder, frames: int = 6, stages: int = 2, seed: int = 0) -> Sequence:
    """A pairs sequence with its pixels: random ground truth, degraded = ground truth plus noise."""
    rng = np.random.default_rng(seed)
    gt = rng.integers(0, 256, size=(frames, H, W, 3), dtype=np.uint8)
    noise = rng.integers(-40, 41, size=(stages, frames, H, W, 3))
    degraded = np.clip(gt[None].astype(np.int16) + noise, 0, 255).astype(np.uint8)
    return Sequence(
        name="s", scene_id="x", target=encode_frames(ae, gt), reference=encode_frames(ae, gt), structure=None,
        degraded=torch.stack([encode_frames(ae, d) for d in degraded]), degraded_frames=degraded, target_frames=gt,
        vanishing=np.tile([W / 2, H / 2], (frames, 1)),
    )


def small_autoencoder() -> Autoencoder:
    torch.manual_seed(0)
    return Autoencoder(AutoencoderConfig(hidden_channels=(8, 8, 8))).eval()


def _pixel_batch(ae: Autoencoder) -> dict:
    train = dataclasses.replace(TrainConfig(), window=3, crop=(0, 0), batch_size=2)
    return sample_batch([pixel_sequence(ae)], np.random.default_rng(1), train, 4, False, True, with_pixels=True)


class TestDiffusionLossAndEstimate(BaseTester):
    """``diffusion_loss_and_estimate``: the clean-latent estimate behind the image-space loss."""

    @pytest.mark.parametrize("prediction", ["epsilon", "v", "x0"])
    def test_correctness_oracle_network_estimate_is_the_clean_latent(self, prediction):
        schedule = NoiseSchedule(DiffusionConfig(prediction=prediction))
        x0 = torch.randn(3, 2, 4, 5, 6, generator=torch.Generator().manual_seed(1))
        noise_draws = {}

        def oracle(x_t, t):  # the exact target, recovered from x_t and the known x0
            a = schedule.alpha_bar[t].sqrt().reshape(-1, 1, 1, 1, 1)
            s = (1.0 - schedule.alpha_bar[t]).sqrt().reshape(-1, 1, 1, 1, 1)
            noise_draws["eps"] = (x_t - a * x0) / s
            return schedule.training_target(x0, noise_draws["eps"], t)

        loss, estimate = diffusion_loss_and_estimate(oracle, schedule, x0, torch.Generator().manual_seed(2), 8.0)
        assert loss.item() < 1e-8
        # The oracle's eps and, for epsilon prediction, the estimate x0 = (x_t - s eps) / a divide
        # float32 rounding by s or a (either can be small): low tolerance.
        self.assert_close(estimate, x0, low_tolerance=True)


class TestSampleBatchPixels(BaseTester):
    """``sample_batch(..., with_pixels=True)``: the pixel crops that go with a latent batch."""

    def test_correctness_pixels_hold_the_crop_of_the_latent_batch(self):
        ae = small_autoencoder()
        seq = pixel_sequence(ae)
        train = dataclasses.replace(TrainConfig(), window=3, crop=(4, 5), batch_size=4)
        batch = sample_batch([seq], np.random.default_rng(0), train, 4, False, True, with_pixels=True)
        assert batch["target_pixels"].shape == batch["degraded_pixels"].shape == (4, 3, 3, 16, 20)
        for i in range(4):
            # Find the clip's place by its latents, then check the pixels are that place's.
            found = [
                (s, y, x) for s in range(4) for y in range(5) for x in range(8)
                if torch.equal(batch["target"][i], seq.target[s : s + 3, :, y : y + 4, x : x + 5])
            ]
            assert len(found) == 1
            s, y, x = found[0]
            expected = frames_to_tensor(seq.target_frames[s : s + 3, 4 * y : 4 * y + 16, 4 * x : 4 * x + 20])
            assert torch.equal(batch["target_pixels"][i], expected)
            stages = [k for k in range(2) if torch.equal(batch["degraded"][i], seq.degraded[k, s : s + 3, :, y : y + 4, x : x + 5])]
            assert len(stages) == 1
            degraded = frames_to_tensor(seq.degraded_frames[stages[0], s : s + 3, 4 * y : 4 * y + 16, 4 * x : 4 * x + 20])
            assert torch.equal(batch["degraded_pixels"][i], degraded)

    def test_correctness_masked_pixels_are_what_their_latents_encode(self):
        ae = small_autoencoder()
        seq = pixel_sequence(ae, frames=4, stages=1)
        train = dataclasses.replace(TrainConfig(), window=4, crop=(0, 0), batch_size=1)
        always = dataclasses.replace(MaskConfig(), probability=1.0)
        batch = sample_batch([seq], np.random.default_rng(5), train, 4, False, True, always, ae, with_pixels=True)
        replay = np.random.default_rng(5)  # the same draws: sequence, start, crop y and x, stage
        replay.integers(1), replay.integers(0, 1), replay.integers(0, 1), replay.integers(0, 1), replay.integers(1)
        keep = sample_clip_masks(4, H, W, always, replay, seq.vanishing)
        assert torch.equal(batch["degraded_pixels"][0], frames_to_tensor(seq.degraded_frames[0] * keep[..., None]))
        with torch.no_grad():
            self.assert_close(batch["degraded"][0], ae.encode(batch["degraded_pixels"][0]))
        assert torch.equal(batch["target_pixels"][0], frames_to_tensor(seq.target_frames))

    def test_exception_without_the_pairs_pixels(self):
        ae = small_autoencoder()
        seq = dataclasses.replace(pixel_sequence(ae), target_frames=None)
        with pytest.raises(RecondreamerError, match="keep_frames"):
            sample_batch([seq], np.random.default_rng(0), TrainConfig(window=3, crop=(0, 0)), 4, False, True, with_pixels=True)


class TestImageSpaceLoss(BaseTester):
    """``image_space_loss``: the decoded estimate against the ground-truth pixels."""

    def test_correctness_zero_and_full_corrections(self):
        # The zero correction scores the degraded frames, the full one their decoding.
        ae = small_autoencoder()
        schedule = NoiseSchedule(RESIDUAL)
        batch = _pixel_batch(ae)
        zero = torch.zeros_like(batch["degraded"])
        with torch.no_grad():
            # Residual decoding of "no correction" returns the degraded pixels exactly.
            kept = image_space_loss(ae, schedule, zero, batch, residual_decoding=True)
            assert kept.item() == pytest.approx(torch.mean((batch["degraded_pixels"] - batch["target_pixels"]) ** 2).item(), rel=1e-6)
            # Plain decoding returns D(E(degraded)); the true residual plainly decodes to D(E(ground truth)).
            plain = image_space_loss(ae, schedule, zero, batch, residual_decoding=False)
            decoded = ae.decode(batch["degraded"].flatten(0, 1))
            assert plain.item() == pytest.approx(torch.mean((decoded - batch["target_pixels"].flatten(0, 1)) ** 2).item(), rel=1e-6)
            truth = schedule.to_diffusion_space(batch["target"], batch["degraded"])
            ideal = image_space_loss(ae, schedule, truth, batch, residual_decoding=False)
            target_decoded = ae.decode(batch["target"].flatten(0, 1))
            assert ideal.item() == pytest.approx(torch.mean((target_decoded - batch["target_pixels"].flatten(0, 1)) ** 2).item(), rel=1e-6)

    @pytest.mark.parametrize("residual_decoding", [True, False])
    def test_gradcheck(self, residual_decoding):
        ae = small_autoencoder().double()
        schedule = NoiseSchedule(RESIDUAL)
        train = dataclasses.replace(TrainConfig(), window=2, crop=(2, 3), batch_size=1)
        batch = sample_batch([pixel_sequence(ae.float())], np.random.default_rng(2), train, 4, False, True, with_pixels=True)
        ae.double()
        batch = {k: None if v is None else v.double() for k, v in batch.items()}
        estimate = torch.randn(batch["degraded"].shape, dtype=torch.float64, generator=torch.Generator().manual_seed(3))
        self.gradcheck(lambda e: image_space_loss(ae, schedule, e, batch, residual_decoding), estimate)

    def test_trains_the_unet_and_leaves_the_frozen_decoder_alone(self):
        model = tiny_model("sd", kind="restorer")
        ae = model.autoencoder.requires_grad_(False)
        schedule = NoiseSchedule(RESIDUAL)
        batch = _pixel_batch(ae)
        # The random tiny decoder barely responds to its latents (gradient norm ~3e-4): a large step.
        optimizer = torch.optim.SGD(model.unet.parameters(), lr=100.0)

        def loss():  # the same noise and timesteps every time: a fixed batch
            _, estimate = unet_loss_and_estimate(model.unet, schedule, batch, torch.Generator().manual_seed(3), 50.0)
            return image_space_loss(ae, schedule, estimate, batch, residual_decoding=True)

        before = loss()
        optimizer.zero_grad()
        before.backward()
        assert all(p.grad is None for p in ae.parameters())
        assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in model.unet.parameters())
        optimizer.step()
        with torch.no_grad():
            assert loss().item() < before.item()

    def test_exception_negative_weight_before_any_work(self, tmp_path, capsys):
        code = main(["train-restorer", "--arch", "sd", "--world-model", str(tmp_path / "missing.pt"), "--pairs", str(tmp_path),
                     "--out", str(tmp_path / "r.pt"), "--pixel-loss-weight", "-1"])
        assert code == 1
        assert "--pixel-loss-weight must be >= 0" in capsys.readouterr().err
