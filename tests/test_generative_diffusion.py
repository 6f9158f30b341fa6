"""Noise schedule parameterisations (eps, v, x0) and the DDIM sampler built on them."""

from __future__ import annotations

import pytest
import torch

from recondreamer.generative.config import DiffusionConfig
from recondreamer.generative.diffusion import (
    PREDICTIONS,
    NoiseSchedule,
    ddim_sample,
    diffusion_loss_and_estimate,
)


def batch(seed: int = 0, b: int = 5) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    x0 = torch.randn(b, 3, 4, 6, generator=g)
    noise = torch.randn(b, 3, 4, 6, generator=g)
    timesteps = torch.tensor([0, 1, 400, 998, 999][:b])
    return x0, noise, timesteps


@pytest.mark.parametrize("schedule", ["linear", "cosine"])
@pytest.mark.parametrize("prediction", PREDICTIONS)
def test_the_target_of_the_true_x0_and_noise_splits_back_into_them(prediction, schedule):
    s = NoiseSchedule(DiffusionConfig(prediction=prediction, schedule=schedule))
    x0, noise, timesteps = batch()
    x_t = s.add_noise(x0, noise, timesteps)
    x0_hat, eps_hat = s.split_prediction(x_t, s.training_target(x0, noise, timesteps), timesteps)
    # x0 from eps divides by sqrt(alpha_bar): float32 rounding grows by the same factor.
    amplification = (1 / s.alpha_bar[timesteps].sqrt()).reshape(-1, 1, 1, 1) if prediction == "epsilon" else 1.0
    assert torch.all((x0_hat - x0).abs() <= 2e-4 * amplification)
    assert torch.allclose(eps_hat, noise, atol=2e-4)


def test_v_target_matches_its_definition_and_is_minus_x0_at_zero_signal():
    s = NoiseSchedule(DiffusionConfig(prediction="v"))
    x0, noise, timesteps = batch()
    alpha_bar = s.alpha_bar[timesteps].double().reshape(-1, 1, 1, 1)
    expected = alpha_bar.sqrt() * noise.double() - (1 - alpha_bar).sqrt() * x0.double()
    assert torch.allclose(s.training_target(x0, noise, timesteps).double(), expected, atol=1e-6)
    # Independent check of the geometry: v is x_t rotated by 90 degrees in the (x0, eps) plane,
    # so |x_t|^2 + |v|^2 = |x0|^2 + |eps|^2 elementwise.
    x_t = s.add_noise(x0, noise, timesteps)
    v = s.training_target(x0, noise, timesteps)
    assert torch.allclose(x_t**2 + v**2, x0**2 + noise**2, atol=1e-5)


def test_unknown_prediction_target_is_rejected():
    with pytest.raises(ValueError, match="prediction target"):
        NoiseSchedule(DiffusionConfig(prediction="score"))


@pytest.mark.parametrize("prediction", PREDICTIONS)
@pytest.mark.parametrize("num_steps", [1, 4])
def test_ddim_with_an_oracle_model_lands_on_the_data_point(prediction, num_steps):
    """For data that is a single point x*, the exact model output at x_t is the target of
    (x*, eps = (x_t - a x*) / s); DDIM then returns x* for any step count."""
    s = NoiseSchedule(DiffusionConfig(prediction=prediction))
    target_point = torch.randn(2, 3, 4, 6, generator=torch.Generator().manual_seed(3)).clamp(-2, 2)

    def oracle(x_t: torch.Tensor, timesteps: torch.Tensor) -> torch.Tensor:
        alpha_bar = s.alpha_bar[timesteps].reshape(-1, 1, 1, 1)
        eps = (x_t - alpha_bar.sqrt() * target_point) / (1 - alpha_bar).sqrt()
        return s.training_target(target_point, eps, timesteps)

    noise = torch.randn(2, 3, 4, 6, generator=torch.Generator().manual_seed(4))
    out = ddim_sample(oracle, s, noise, num_steps)
    assert torch.allclose(out, target_point, atol=1e-3)
    # Starting part-way from a noised start latent (SDEdit) also ends on the data point.
    out = ddim_sample(oracle, s, noise, num_steps, start_latent=torch.zeros_like(noise), strength=0.5)
    assert torch.allclose(out, target_point, atol=1e-3)


@pytest.mark.parametrize("prediction", PREDICTIONS)
def test_diffusion_loss_is_zero_for_the_oracle_and_positive_otherwise(prediction):
    s = NoiseSchedule(DiffusionConfig(prediction=prediction))
    x0 = torch.randn(4, 3, 4, 6, generator=torch.Generator().manual_seed(5))

    def oracle(x_t: torch.Tensor, timesteps: torch.Tensor) -> torch.Tensor:
        alpha_bar = s.alpha_bar[timesteps].reshape(-1, 1, 1, 1)
        eps = (x_t - alpha_bar.sqrt() * x0) / (1 - alpha_bar).sqrt()
        return s.training_target(x0, eps, timesteps)

    assert diffusion_loss_and_estimate(oracle, s, x0, torch.Generator().manual_seed(6))[0].item() < 1e-6
    assert diffusion_loss_and_estimate(lambda x_t, t: torch.zeros_like(x_t), s, x0, torch.Generator().manual_seed(6))[0].item() > 0.1
