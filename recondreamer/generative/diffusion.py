"""Noise schedule, training loss and deterministic DDIM sampling.

Notation: ``alpha_bar[t]`` is the cumulative signal level of step t, ``a = sqrt(alpha_bar)`` and
``s = sqrt(1 - alpha_bar)`` (so ``a^2 + s^2 = 1``), and the forward process is

    x_t = a * x0 + s * eps,        eps ~ N(0, I).

The network can be trained to predict one of three equivalent targets (``prediction``):

- ``epsilon``: eps (DDPM, Stable Diffusion);
- ``v``: v = a * eps - s * x0 (Salimans & Ho 2022, Stable Video Diffusion);
- ``x0``: the clean latent itself.

Given x_t and the prediction, the sampler needs both x0 and eps:

- from eps:  x0 = (x_t - s * eps) / a;
- from v:    x0 = a * x_t - s * v  and  eps = s * x_t + a * v
  (substitute x_t and v: a^2 x0 + a s eps - s a eps + s^2 x0 = x0, and likewise for eps);
- from x0:   eps = (x_t - a * x0) / s.

Why it matters here: on Stable Diffusion's scaled-linear schedule the noisiest step has
alpha_bar ~ 0.005, so recovering x0 from an eps prediction divides its error by a ~ 0.07 (a
~15x amplification). A small, briefly trained model then lands far from the data at the first
DDIM step. With v (or x0) prediction the first step's x0 estimate is the network's own output,
the conditional mean of the clean latent given the conditions (for a restorer: the degraded
video), with no amplification.

Target space (``DiffusionConfig.target_space``). World models diffuse clean latents. A restorer
can instead diffuse the *residual* ``r = (clean - degraded) / residual_scale`` and return
``degraded + residual_scale * r``: its output is the degraded latent plus a correction, so a
network that outputs r = 0 (or has not learned anything yet) returns its input unchanged instead
of an unrelated sample, and the model only has to learn what the render got wrong (as in
ResShift-style restoration diffusion, which diffuses the residual between the two images).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch

from recondreamer.generative.config import DiffusionConfig

PREDICTIONS = ("epsilon", "v", "x0")
TARGET_SPACES = ("clean", "residual")


class NoiseSchedule:
    """Cumulative signal levels ``alpha_bar[t]`` of a linear (SD scaled-linear) or cosine schedule,
    and the conversions between the network's prediction and (x0, eps)."""

    def __init__(self, config: DiffusionConfig):
        self.config = config
        if config.prediction not in PREDICTIONS:
            raise ValueError(f"unknown prediction target {config.prediction!r} (expected one of {', '.join(PREDICTIONS)})")
        if config.target_space not in TARGET_SPACES:
            raise ValueError(f"unknown target space {config.target_space!r} (expected one of {', '.join(TARGET_SPACES)})")
        if not config.residual_scale > 0.0:
            raise ValueError(f"residual scale must be positive, got {config.residual_scale}")
        n = config.train_timesteps
        if config.schedule == "linear":
            betas = torch.linspace(config.beta_start**0.5, config.beta_end**0.5, n, dtype=torch.float64) ** 2
            self.alpha_bar = torch.cumprod(1.0 - betas, dim=0).float()  # (n,)
        elif config.schedule == "cosine":
            steps = torch.arange(n + 1, dtype=torch.float64) / n
            f = torch.cos((steps + 0.008) / 1.008 * math.pi / 2) ** 2
            betas = (1.0 - f[1:] / f[:-1]).clamp(max=0.999)
            self.alpha_bar = torch.cumprod(1.0 - betas, dim=0).float()
        else:
            raise ValueError(f"unknown noise schedule {config.schedule!r} (expected 'linear' or 'cosine')")

    @property
    def num_timesteps(self) -> int:
        return self.config.train_timesteps

    @property
    def prediction(self) -> str:
        return self.config.prediction

    def to_diffusion_space(self, clean: torch.Tensor, base: torch.Tensor | None) -> torch.Tensor:
        """The latent the diffusion generates for a clean latent: itself, or the scaled residual
        to ``base`` (the degraded latent the restorer is conditioned on), same shape."""
        if self.config.target_space == "clean":
            return clean
        return (clean - base) / self.config.residual_scale

    def from_diffusion_space(self, sample: torch.Tensor, base: torch.Tensor | None) -> torch.Tensor:
        """Inverse of ``to_diffusion_space``: a sample of the diffusion back to a clean latent."""
        if self.config.target_space == "clean":
            return sample
        return base + self.config.residual_scale * sample

    def sample_timesteps(self, batch: int, power: float = 1.0, generator: torch.Generator | None = None) -> torch.Tensor:
        """Random training steps (B,) with density proportional to t^(power - 1) on [0, N):
        uniform for power 1; power 3 puts 70% of the steps above 2N/3."""
        if not power > 0.0:
            raise ValueError(f"timestep power must be positive, got {power}")
        u = torch.rand(batch, generator=generator, dtype=torch.float64)
        return (u ** (1.0 / power) * self.num_timesteps).long().clamp(max=self.num_timesteps - 1)

    def _levels(self, timesteps: torch.Tensor, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(a, s) of each batch element, shaped to broadcast against ``like`` (B,...)."""
        alpha_bar = self.alpha_bar.to(like.device)[timesteps].reshape(-1, *([1] * (like.dim() - 1)))
        return alpha_bar.sqrt(), (1.0 - alpha_bar).sqrt()

    def add_noise(self, x0: torch.Tensor, noise: torch.Tensor, timesteps: torch.Tensor) -> torch.Tensor:
        """q(x_t | x_0) for a batch: x0, noise (B,...), timesteps (B,)."""
        a, s = self._levels(timesteps, x0)
        return a * x0 + s * noise

    def training_target(self, x0: torch.Tensor, noise: torch.Tensor, timesteps: torch.Tensor) -> torch.Tensor:
        """What the network learns to output for x_t = add_noise(x0, noise, timesteps)."""
        if self.prediction == "epsilon":
            return noise
        if self.prediction == "x0":
            return x0
        a, s = self._levels(timesteps, x0)
        return a * noise - s * x0

    def split_prediction(
        self, x_t: torch.Tensor, output: torch.Tensor, timesteps: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The (x0, eps) estimates implied by the network's ``output`` at x_t (module docstring)."""
        a, s = self._levels(timesteps, x_t)
        if self.prediction == "epsilon":
            return (x_t - s * output) / a, output
        if self.prediction == "x0":
            return output, (x_t - a * output) / s
        return a * x_t - s * output, s * x_t + a * output

    def sampling_timesteps(self, num_steps: int, strength: float = 1.0) -> list[int]:
        """Evenly spaced decreasing steps; ``strength`` < 1 starts part-way (SDEdit-style)."""
        if num_steps < 1:
            raise ValueError(f"number of sampling steps must be >= 1, got {num_steps}")
        if not 0.0 < strength <= 1.0:
            raise ValueError(f"strength must be in (0, 1], got {strength}")
        start = round(strength * (self.num_timesteps - 1))
        steps = torch.linspace(start, 0, num_steps).round().long().tolist()
        return sorted(set(steps), reverse=True)


def diffusion_loss_and_estimate(
    model_fn: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
    schedule: NoiseSchedule,
    x0: torch.Tensor,  # (B,...) in the schedule's target space
    generator: torch.Generator | None = None,
    timestep_power: float = 1.0,
) -> tuple[torch.Tensor, torch.Tensor]:  # loss (), x0 estimate (B,...) differentiable
    """Mean squared error between the network's output and its target at random steps (density
    of the steps proportional to t^(timestep_power - 1)), and the x0 estimate the output implies
    at those steps: what a one-step sampler would return, for losses on the sample itself
    (image-space terms)."""
    b = x0.shape[0]
    if timestep_power == 1.0:  # the integer sampler of earlier checkpoints, so their runs reproduce
        timesteps = torch.randint(0, schedule.num_timesteps, (b,), generator=generator)
    else:
        timesteps = schedule.sample_timesteps(b, timestep_power, generator)
    # Drawn on the (CPU) generator and moved: the same draws on any device.
    timesteps = timesteps.to(x0.device)
    noise = torch.randn(x0.shape, generator=generator).to(x0.device)
    noisy = schedule.add_noise(x0, noise, timesteps)
    output = model_fn(noisy, timesteps)
    loss = torch.mean((output - schedule.training_target(x0, noise, timesteps)) ** 2)
    return loss, schedule.split_prediction(noisy, output, timesteps)[0]


@torch.no_grad()
def ddim_sample(
    model_fn: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
    schedule: NoiseSchedule,
    noise: torch.Tensor,  # (B,...) standard normal start
    num_steps: int,
    eta: float = 0.0,
    start_latent: torch.Tensor | None = None,  # (B,...) noised to the first step when strength < 1
    strength: float = 1.0,
    generator: torch.Generator | None = None,
    clip_x0: float | None = 6.0,
) -> torch.Tensor:
    """DDIM (Song et al.): deterministic for eta = 0; ``model_fn(x_t, t (B,))`` returns the
    schedule's prediction target. The last step returns the x0 estimate itself."""
    steps = schedule.sampling_timesteps(num_steps, strength)
    alpha_bar = schedule.alpha_bar
    b = noise.shape[0]
    if strength < 1.0:
        if start_latent is None:
            raise ValueError("strength < 1 needs a start latent to noise")
        x = schedule.add_noise(start_latent, noise, torch.full((b,), steps[0], dtype=torch.long, device=noise.device))
    else:
        x = noise
    for index, step in enumerate(steps):
        a_t = alpha_bar[step]
        a_prev = alpha_bar[steps[index + 1]] if index + 1 < len(steps) else torch.tensor(1.0)
        timesteps = torch.full((b,), step, dtype=torch.long, device=noise.device)
        x0, eps = schedule.split_prediction(x, model_fn(x, timesteps), timesteps)
        if clip_x0 is not None:
            # Latents are normalised to unit variance; clipping the x0 estimate keeps the
            # first, noisiest steps from throwing the sample far off the data range.
            x0 = x0.clamp(-clip_x0, clip_x0)
            eps = (x - a_t.sqrt() * x0) / (1.0 - a_t).sqrt()
        sigma = eta * ((1.0 - a_prev) / (1.0 - a_t) * (1.0 - a_t / a_prev)).clamp(min=0.0).sqrt()
        direction = (1.0 - a_prev - sigma**2).clamp(min=0.0).sqrt() * eps
        x = a_prev.sqrt() * x0 + direction
        if eta > 0.0 and index + 1 < len(steps):
            x = x + sigma * torch.randn(x.shape, generator=generator).to(x.device)
    return x
