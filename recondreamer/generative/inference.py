"""Sampling clips of any length: DriveRestorer restoration and DriveDreamer4D-style generation.

A clip longer than the model's window is cut into windows that overlap by ``overlap`` frames
(the last window is aligned to the clip's end). Each window is sampled with DDIM from the
clip's per-frame noise (drawn once from the seed, so frames shared by two windows start from the
same noise), and the windows' clean latents are cross-faded linearly over each overlap before
decoding. With ``overlap = 0`` every frame comes from exactly one window, identical to sampling
that window alone.

A restorer can average several samples (``samples``, default from its restore config): each window
is sampled from that many noise draws in one batch and their clean latents are averaged. The mean
of samples estimates the mean of the restorer's output distribution, the output that minimises the
expected squared error; a single sample carries that distribution's spread as well. The first
noise draw is the one a single-sample restoration uses.
"""

from __future__ import annotations

import os
from collections.abc import Callable

import numpy as np
import torch

from recondreamer.errors import RecondreamerError
from recondreamer.generative.autoencoder import Autoencoder, decode_latents, encode_frames
from recondreamer.generative.data import structure_from_uint8, structure_to_uint8
from recondreamer.generative.diffusion import ddim_sample
from recondreamer.generative.models import GenerativeModel, load_generative_model
from recondreamer.generative.refiner import refine_frames


def load_restorer(path: str | os.PathLike, device: torch.device | str = "cpu") -> GenerativeModel:
    """A DriveRestorer checkpoint (``train-restorer`` output) on ``device``."""
    return load_generative_model(path, "restorer", device)


def load_world_model(path: str | os.PathLike, device: torch.device | str = "cpu") -> GenerativeModel:
    """A pretrained world model checkpoint (``pretrain-world-model`` output) on ``device``."""
    return load_generative_model(path, "world_model", device)


def window_starts(num_frames: int, window: int, overlap: int) -> list[int]:
    """Start frames of the windows covering ``num_frames`` frames (the last one ends the clip)."""
    if window < 1 or not 0 <= overlap < window:
        raise ValueError(f"need window >= 1 and 0 <= overlap < window, got window {window}, overlap {overlap}")
    if num_frames <= window:
        return [0]
    starts = list(range(0, num_frames - window, window - overlap))
    starts.append(num_frames - window)
    return starts


def blend_windows(
    num_frames: int,
    window: int,
    overlap: int,
    sample_window: Callable[[int, int], torch.Tensor],  # (start, end) -> (end-start, ...) latents
) -> torch.Tensor:  # (T, ...)
    """Sample every window and cross-fade linearly where consecutive windows overlap."""
    starts = window_starts(num_frames, window, overlap)
    total = None
    weight_sum = torch.zeros(num_frames)
    for index, start in enumerate(starts):
        end = min(start + window, num_frames)
        latents = sample_window(start, end)
        weights = torch.ones(end - start)
        if index > 0:
            shared = min(starts[index - 1] + window, num_frames) - start
            weights[:shared] = torch.arange(1, shared + 1, dtype=torch.float32) / (shared + 1)
        if index + 1 < len(starts):
            shared = end - starts[index + 1]
            weights[end - start - shared :] = weights[end - start - shared :] * torch.arange(shared, 0, -1, dtype=torch.float32) / (shared + 1)
        if total is None:
            total = torch.zeros((num_frames, *latents.shape[1:]), device=latents.device)
            weight_sum = weight_sum.to(latents.device)
        total[start:end] += weights.to(latents.device).reshape(-1, *([1] * (latents.dim() - 1))) * latents
        weight_sum[start:end] += weights.to(latents.device)
    return total / weight_sum.reshape(-1, *([1] * (total.dim() - 1)))


def _check_frames(model: GenerativeModel, frames: np.ndarray, what: str) -> None:
    if not isinstance(frames, np.ndarray) or frames.dtype != np.uint8 or frames.ndim != 4 or frames.shape[-1] != 3:
        shape = getattr(frames, "shape", None)
        raise RecondreamerError(f"{what} must be a (T,H,W,3) uint8 array, got {type(frames).__name__} {shape}")
    f = model.autoencoder.config.downsample_factor
    height, width = frames.shape[1:3]
    if height % f or width % f:
        raise RecondreamerError(f"{what}: frame size {width}x{height} is not divisible by the autoencoder factor {f}")


def _prepare_structure(model: GenerativeModel, structure: np.ndarray | None, frames_shape: tuple[int, ...]) -> torch.Tensor | None:
    if not model.unet_config.uses_structure:
        return None
    t, height, width = frames_shape[:3]
    expected = (t, len(model.structure_channels), height, width)
    if structure is None:
        raise RecondreamerError(f"arch {model.arch!r} needs structure conditions of shape {expected} (channels {', '.join(model.structure_channels)})")
    if tuple(structure.shape) != expected:
        raise RecondreamerError(f"structure conditions have shape {tuple(structure.shape)}, expected {expected} (T,C,H,W) matching the frames")
    # Quantised exactly as in training (pairs and corpus store structure maps as uint8).
    if structure.dtype != np.uint8:
        structure = structure_to_uint8(np.asarray(structure, dtype=np.float32))
    return structure_from_uint8(structure)


@torch.no_grad()
def _sample_clip(
    model: GenerativeModel,
    reference_latents: torch.Tensor,  # (T,c,h,w)
    structure: torch.Tensor | None,  # (T,S,H,W)
    degraded_latents: torch.Tensor | None,  # (T,c,h,w)
    num_steps: int,
    window: int,
    overlap: int,
    strength: float,
    noise: torch.Tensor,  # (K,T,c,h,w) one clip of noise per sample (clip_noise)
    view_latents: torch.Tensor | None = None,  # (T,c,h,w) reference views (view-conditioned restorers)
) -> torch.Tensor:  # (T,c,h,w) the mean of the K samples
    num_frames, samples = reference_latents.shape[0], noise.shape[0]
    # Conditions and noise go to the model's device.
    device = model.device
    noise = noise.to(device)
    reference_latents = reference_latents.to(device)
    structure = None if structure is None else structure.to(device)
    degraded_latents = None if degraded_latents is None else degraded_latents.to(device)
    view_latents = None if view_latents is None else view_latents.to(device)
    unet = model.unet.eval()

    def sample_window(start: int, end: int) -> torch.Tensor:
        # The window's conditions, repeated for the batch of samples (structure features once, then repeated).
        length = end - start
        reference = reference_latents[start][None].expand(samples, *reference_latents.shape[1:])
        degraded = None if degraded_latents is None else degraded_latents[start:end][None].expand(samples, length, *degraded_latents.shape[1:])
        view = None if view_latents is None else view_latents[start:end][None].expand(samples, length, *view_latents.shape[1:])
        features = None
        if structure is not None:
            features = unet.encode_structure(structure[start:end][None], (1, length, *noise.shape[2:])).repeat(samples, 1, 1, 1)

        def model_fn(x: torch.Tensor, timesteps: torch.Tensor) -> torch.Tensor:
            return unet(x, timesteps, reference, degraded=degraded, structure_features=features, view=view)

        # A residual restorer samples the correction to the degraded clip; its SDEdit start
        # (strength < 1) is then the zero correction, i.e. the degraded clip itself.
        start_latent = None if degraded is None else model.schedule.to_diffusion_space(degraded, degraded)
        sample = ddim_sample(
            model_fn, model.schedule, noise[:, start:end], num_steps, eta=0.0,
            start_latent=start_latent, strength=strength,
        )
        return model.schedule.from_diffusion_space(sample, degraded).mean(dim=0)

    return blend_windows(num_frames, window, overlap, sample_window)


def clip_noise(latents: torch.Tensor, samples: int, seed: int) -> torch.Tensor:  # (T,c,h,w) -> (K,T,c,h,w)
    """Noise for ``samples`` samples of a clip, drawn on a CPU generator (the same on any device);
    the first sample's is what a single-sample draw with that seed gives."""
    if samples < 1:
        raise RecondreamerError(f"samples must be >= 1, got {samples}")
    return torch.randn((samples, *latents.shape), generator=torch.Generator().manual_seed(seed))


def _encode_conditions(
    model: GenerativeModel,
    frames: np.ndarray,  # (T,H,W,3) uint8
    structure: np.ndarray | None,  # (T,C,H,W) structure maps (dd2 archs)
    what: str,
) -> tuple[torch.Tensor, torch.Tensor | None]:  # (T,c,h,w) latents, structure (T,C,H,W) or None
    """Checked frames -> (latents, structure tensor or None): the conditions every sampler starts from."""
    _check_frames(model, frames, what)
    structure_tensor = _prepare_structure(model, structure, frames.shape)
    return encode_frames(model.autoencoder, frames), structure_tensor


def restore_clip(
    restorer: GenerativeModel,
    frames: np.ndarray,  # (T,H,W,3) uint8 degraded renders
    structure: np.ndarray | None,  # (T,C,H,W) structure maps in the rendered cameras (dd2 archs)
    *,
    num_steps: int | None = None,
    window: int | None = None,
    overlap: int | None = None,
    strength: float | None = None,
    seed: int | None = None,
    residual_decoding: bool | None = None,
    samples: int | None = None,
    refine: bool = True,
    view: np.ndarray | None = None,  # (T,H,W,3) uint8 reference views (view-conditioned restorers)
) -> np.ndarray:  # (T,H,W,3) uint8
    """Restore a rendered clip with DriveRestorer (defaults from the checkpoint's restore config).

    Each window is conditioned on its degraded frames (its first one also as the reference
    frame, as in training) and, for dd2 archs, on the structure maps. With residual decoding
    the output is the input plus the decoded change ``D(z_restored) - D(E(input))``, where
    ``z_restored`` is the mean of ``samples`` samples (module docstring). A restorer
    with a pixel refiner (``train-refiner``) then refines that output frame by frame, unless
    ``refine`` is False (the diffusion restorer's output alone, e.g. to measure the refiner).

    A view-conditioned restorer (``UNetConfig.view_condition``, beyond the paper) also takes
    ``view``: per frame, the view the reconstruction was trained on at the same timestamp (for a
    novel-trajectory render, the recorded frame); without it its frames count as having no view
    (zero latents), as the original-trajectory pairs it trained on.
    """
    if restorer.kind != "restorer":
        raise RecondreamerError(f"restore_clip needs a restorer, got a {restorer.kind} ({restorer.arch})")
    degraded_latents, structure_tensor = _encode_conditions(restorer, frames, structure, "degraded frames")
    view_latents = None
    if restorer.unet_config.view_condition:
        if view is None:
            view_latents = torch.zeros_like(degraded_latents)
        else:
            _check_frames(restorer, view, "reference views")
            if view.shape != frames.shape:
                raise RecondreamerError(f"reference views {view.shape} do not match the degraded frames {frames.shape} (T,H,W,3)")
            view_latents = encode_frames(restorer.autoencoder, view)
    elif view is not None:
        raise RecondreamerError(f"this {restorer.arch} restorer takes no reference views (it was trained without view_condition)")
    config = restorer.restore_config
    latents = _sample_clip(
        restorer, degraded_latents, structure_tensor, degraded_latents,
        num_steps or config.sample_steps, window or config.window, config.overlap if overlap is None else overlap,
        config.strength if strength is None else strength,
        clip_noise(degraded_latents, config.samples if samples is None else samples, config.seed if seed is None else seed),
        view_latents,
    )
    if not (config.residual_decoding if residual_decoding is None else residual_decoding):
        restored = decode_latents(restorer.autoencoder, latents)
    else:
        restored = residual_decode(restorer.autoencoder, frames, latents, degraded_latents)
    if refine and restorer.refiner is not None:
        restored = refine_frames(restorer.refiner, restored, frames, structure_tensor)
    return restored


def residual_decode(
    autoencoder: Autoencoder,
    frames: np.ndarray,  # (T,H,W,3) uint8 the restorer's input
    latents: torch.Tensor,  # (T,c,h,w) restored latents
    frame_latents: torch.Tensor,  # (T,c,h,w) E(frames)
) -> np.ndarray:  # (T,H,W,3) uint8
    """The input plus the decoded change, ``frames + D(latents) - D(E(frames))``, clipped to uint8."""
    change = decode_latents(autoencoder, latents).astype(np.int16) - decode_latents(autoencoder, frame_latents).astype(np.int16)
    return np.clip(frames.astype(np.int16) + change, 0, 255).astype(np.uint8)


def generate_clip(
    world_model: GenerativeModel,
    reference: np.ndarray,  # (T,H,W,3) uint8 original-trajectory frames
    structure: np.ndarray | None,  # (T,C,H,W) structure maps in the target cameras (dd2)
    *,
    num_steps: int | None = None,
    window: int | None = None,
    overlap: int | None = None,
    seed: int = 0,
) -> np.ndarray:  # (T,H,W,3) uint8
    """Training-free novel-trajectory video from a pretrained world model (DriveDreamer4D)."""
    if world_model.kind != "world_model":
        raise RecondreamerError(f"generate_clip needs a pretrained world model, got a {world_model.kind} ({world_model.arch})")
    reference_latents, structure_tensor = _encode_conditions(world_model, reference, structure, "reference frames")
    config = world_model.restore_config
    latents = _sample_clip(
        world_model, reference_latents, structure_tensor, None,
        num_steps or world_model.diffusion_config.sample_steps, window or world_model.train_config.window,
        config.overlap if overlap is None else overlap, 1.0, clip_noise(reference_latents, 1, seed),
    )
    return decode_latents(world_model.autoencoder, latents)
