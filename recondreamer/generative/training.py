"""Training jobs: autoencoder, world-model pretraining, restorer fine-tuning, pixel refiner.

Every job runs in the project's one resumable loop (``recondreamer.training_loop``): it writes
``OUT.resume.pt`` every ``checkpoint_every`` steps, continues from it when started again with the
same configuration, and deletes it once the final checkpoint is written.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import math
import os
import time
from pathlib import Path

import numpy as np
import torch

from recondreamer.errors import CheckpointError, RecondreamerError
from recondreamer.configs import to_dict
from recondreamer.evaluation.image_metrics import psnr
from recondreamer.generative.autoencoder import Autoencoder, frames_to_tensor
from recondreamer.generative.checkpoint import load_checkpoint, save_checkpoint
from recondreamer.generative.config import (
    AutoencoderConfig,
    DiffusionConfig,
    MaskConfig,
    RefinerConfig,
    RestoreConfig,
    TrainConfig,
    UNetConfig,
    unet_config_from_dict,
)
from recondreamer.generative.data import (
    Sequence,
    autoencoder_digest,
    hash_weights,
    load_pairs_file,
    mapped_pair_arrays,
    restored_pair_frames,
    structure_from_uint8,
)
from recondreamer.device import module_device
from recondreamer.generative.diffusion import NoiseSchedule, diffusion_loss_and_estimate
from recondreamer.generative.masks import sample_clip_masks
from recondreamer.generative.models import (
    GenerativeModel,
    autoencoder_payload,
    count_parameters,
    load_grown_state,
    model_config_dict,
    model_from_payload,
    restorer_unet_from_world_model,
)
from recondreamer.generative.refiner import PixelRefiner, neighbour_stack
from recondreamer.generative.unet import LatentUNet
from recondreamer.training_loop import finish_job, run_training_loop

LOG = logging.getLogger(__name__)


# ----------------------------------------------------------------------------------------------
# Autoencoder
# ----------------------------------------------------------------------------------------------


def split_heldout(scene_frames: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Training and held-out frames: the last scene is held out when there are several,
    otherwise every 8th frame."""
    if len(scene_frames) >= 2:
        return np.concatenate(scene_frames[:-1]), scene_frames[-1]
    frames = scene_frames[0]
    held = np.zeros(len(frames), dtype=bool)
    held[::8] = True
    return frames[~held], frames[held]


def train_autoencoder(
    scene_frames: list[np.ndarray], out: str | os.PathLike, config: AutoencoderConfig, seed: int = 0, device: torch.device | str = "cpu"
) -> dict:
    """Train on random crops of corpus frames (L1 + small SSIM term) on ``device``; report held-out PSNR."""
    import kornia

    train_frames, heldout = split_heldout(scene_frames)
    height, width = train_frames.shape[1:3]
    f = config.downsample_factor
    if height % f or width % f or min(height, width) < config.crop_size:
        raise RecondreamerError(f"corpus frame size {width}x{height} must be divisible by {f} and at least {config.crop_size} px")
    torch.manual_seed(seed)
    model = Autoencoder(config).to(device)
    LOG.info("autoencoder: %d parameters, %d training and %d held-out frames", count_parameters(model), len(train_frames), len(heldout))

    def loss_fn(rng: np.random.Generator, generator: torch.Generator) -> torch.Tensor:
        index = rng.integers(len(train_frames), size=config.batch_size)
        top = rng.integers(0, height - config.crop_size + 1, size=config.batch_size)
        left = rng.integers(0, width - config.crop_size + 1, size=config.batch_size)
        crops = np.stack([train_frames[i, y : y + config.crop_size, x : x + config.crop_size] for i, y, x in zip(index, top, left)])
        images = frames_to_tensor(crops).to(device)
        recon = model(images)
        l1 = torch.mean(torch.abs(recon - images))
        ssim = kornia.losses.ssim_loss((recon + 1) / 2, (images + 1) / 2, window_size=7)
        return l1 + config.ssim_weight * ssim

    identity = {"kind": "autoencoder", "config": to_dict(config), "seed": seed}
    stats = run_training_loop(
        "autoencoder", model, loss_fn, config.steps, config.learning_rate, 50, out, identity,
        checkpoint_every=200, log_every=50, seed=seed,
    )
    sample = train_frames[np.random.default_rng(seed).choice(len(train_frames), size=min(64, len(train_frames)), replace=False)]
    model.set_latent_statistics(frames_to_tensor(sample).to(device))
    heldout_psnr = autoencoder_psnr(model, heldout)
    LOG.info("autoencoder: held-out reconstruction PSNR %.2f dB", heldout_psnr)
    metrics = dict(stats, heldout_psnr=heldout_psnr, frame_size=[height, width])
    save_checkpoint(out, "autoencoder", "autoencoder", to_dict(config), model.state_dict(), metrics=metrics)
    finish_job(out)
    return metrics


@torch.no_grad()
def autoencoder_psnr(model: Autoencoder, frames: np.ndarray) -> float:
    """Mean per-frame PSNR of decode(encode(frames)) against frames (N,H,W,3) uint8."""
    from recondreamer.generative.autoencoder import decode_latents, encode_frames

    recon = decode_latents(model, encode_frames(model, frames))
    return float(np.mean([psnr(a, b) for a, b in zip(recon, frames)]))


# ----------------------------------------------------------------------------------------------
# Diffusion batches
# ----------------------------------------------------------------------------------------------


def sample_batch(
    sequences: list[Sequence],
    rng: np.random.Generator,
    train: TrainConfig,
    downsample_factor: int,
    with_structure: bool,
    with_degraded: bool,
    masks: MaskConfig | None = None,
    autoencoder: Autoencoder | None = None,
    with_pixels: bool = False,
    with_view: bool = False,
) -> dict:
    """A batch of random clips, randomly cropped in latent space.

    Returns target (B,T,c,h,w), reference (B,c,h,w), structure (B,T,S,h*f,w*f) or None,
    degraded (B,T,c,h,w) or None. The reference is the original frame at the clip start for world
    models, and the degraded frame at the clip start for restorers: a restorer must not see the
    ground truth it is asked to produce, and at inference its input is all it has. With
    ``masks``, the degraded frames are masked in pixel space and re-encoded (``z = E(V * M)``).
    With ``with_pixels`` (restorers), also target_pixels and degraded_pixels (B,T,3,h*f,w*f) in
    [-1,1]: the same crop in pixels, the degraded one as encoded (masked where masks fell).
    With ``with_view`` (view-conditioned restorers), also view (B,T,c,h,w): the crop of the
    sequence's reference-view latents, zeros for a sequence without them.
    """
    window = min(train.window, min(s.num_frames for s in sequences))
    latent_h, latent_w = sequences[0].target.shape[-2:]
    crop_h = min(train.crop[0] or latent_h, latent_h)
    crop_w = min(train.crop[1] or latent_w, latent_w)
    f = downsample_factor
    if with_pixels and any(s.target_frames is None or s.degraded_frames is None for s in sequences):
        raise RecondreamerError("an image-space loss needs the pairs' pixels: load the pairs with keep_frames=True")
    targets, references, structures, degraded, views = [], [], [], [], []
    target_pixels, degraded_pixels = [], []
    for _ in range(train.batch_size):
        seq = sequences[rng.integers(len(sequences))]
        start = int(rng.integers(0, seq.num_frames - window + 1))
        frames = slice(start, start + window)
        y, x = int(rng.integers(0, latent_h - crop_h + 1)), int(rng.integers(0, latent_w - crop_w + 1))
        rows, cols = slice(y, y + crop_h), slice(x, x + crop_w)
        pixel_rows, pixel_cols = slice(y * f, (y + crop_h) * f), slice(x * f, (x + crop_w) * f)
        targets.append(seq.target[frames, :, rows, cols])
        if not with_degraded:
            references.append(seq.reference[start, :, rows, cols])
        if with_structure:
            structures.append(torch.from_numpy(seq.structure[frames, :, pixel_rows, pixel_cols]))
        if with_degraded:
            stage = int(rng.integers(seq.degraded.shape[0]))
            latents = seq.degraded[stage, frames]  # (T,c,H/f,W/f)
            pixels = None if seq.degraded_frames is None else seq.degraded_frames[stage, frames]  # (T,H,W,3)
            if masks is not None:
                keep = sample_clip_masks(
                    window, pixels.shape[1], pixels.shape[2], masks, rng, seq.vanishing[frames],
                    None if seq.sky_masks is None else seq.sky_masks[frames],
                )
                masked = np.flatnonzero(~keep.all(axis=(1, 2)))  # frames with a mask: re-encode only those
                if masked.size:
                    pixels = pixels.copy()
                    pixels[masked] = pixels[masked] * keep[masked, ..., None]
                    latents = latents.clone()
                    with torch.no_grad():
                        latents[masked] = autoencoder.encode(frames_to_tensor(pixels[masked]).to(module_device(autoencoder))).cpu()
            degraded.append(latents[:, :, rows, cols])
            references.append(degraded[-1][0])
            if with_view:
                views.append(torch.zeros_like(degraded[-1]) if seq.view is None else seq.view[frames, :, rows, cols])
            if with_pixels:
                target_pixels.append(frames_to_tensor(seq.target_frames[frames, pixel_rows, pixel_cols]))
                degraded_pixels.append(frames_to_tensor(pixels[:, pixel_rows, pixel_cols]))
    batch = {
        "target": torch.stack(targets),
        "reference": torch.stack(references),
        "structure": torch.stack(structures).float() / 255.0 if with_structure else None,
        "degraded": torch.stack(degraded) if with_degraded else None,
        "view": torch.stack(views) if with_view and with_degraded else None,
    }
    if with_pixels:
        batch["target_pixels"], batch["degraded_pixels"] = torch.stack(target_pixels), torch.stack(degraded_pixels)
    return batch


def _batch_on(batch: dict, device: torch.device) -> dict:
    return {name: None if value is None else value.to(device) for name, value in batch.items()}


def unet_loss(
    unet: LatentUNet, schedule: NoiseSchedule, batch: dict, generator: torch.Generator, timestep_power: float = 1.0
) -> torch.Tensor:
    """The diffusion loss (MSE to the schedule's prediction target at a random step per clip) of
    one batch, in the schedule's target space (residual restorers: relative to the degraded clip).
    The batch (built on the CPU) is moved to the UNet's device."""
    return unet_loss_and_estimate(unet, schedule, batch, generator, timestep_power)[0]


def unet_loss_and_estimate(
    unet: LatentUNet, schedule: NoiseSchedule, batch: dict, generator: torch.Generator, timestep_power: float = 1.0
) -> tuple[torch.Tensor, torch.Tensor]:  # loss (), x0 estimate (B,T,c,h,w) in the target space
    """``unet_loss`` and the x0 estimate of the drawn steps (``diffusion_loss_and_estimate``)."""
    batch = _batch_on(batch, module_device(unet))

    def model_fn(noisy: torch.Tensor, timesteps: torch.Tensor) -> torch.Tensor:
        return unet(noisy, timesteps, batch["reference"], structure=batch["structure"], degraded=batch["degraded"], view=batch.get("view"))

    x0 = schedule.to_diffusion_space(batch["target"], batch["degraded"])
    return diffusion_loss_and_estimate(model_fn, schedule, x0, generator, timestep_power)


def image_space_loss(
    autoencoder: Autoencoder,
    schedule: NoiseSchedule,
    estimate: torch.Tensor,  # (B,T,c,h,w) x0 estimate in the schedule's target space
    batch: dict,  # from sample_batch(..., with_pixels=True)
    residual_decoding: bool,
) -> torch.Tensor:
    """Mean squared error, in [-1,1] pixel units, between ground truth and the frames a restorer
    returns for this estimate: the decoded latent, or with residual decoding the degraded pixels
    plus the decoded change ``D(z) - D(E(degraded))`` (what ``inference.restore_clip`` outputs).

    The diffusion loss weighs every latent channel alike; this term weighs the latent error by
    what the (frozen) decoder makes of it, i.e. by its effect on the restored frames' PSNR.
    Gradients flow through the decoder into the estimate only.
    """
    batch = _batch_on(batch, estimate.device)
    latents = schedule.from_diffusion_space(estimate, batch["degraded"]).flatten(0, 1)  # (B*T,c,h,w)
    decoded = autoencoder.decode(latents)  # (B*T,3,H,W)
    if residual_decoding:
        with torch.no_grad():
            base = autoencoder.decode(batch["degraded"].flatten(0, 1))
        decoded = batch["degraded_pixels"].flatten(0, 1) + decoded - base
    return torch.mean((decoded - batch["target_pixels"].flatten(0, 1)) ** 2)


def training_totals(metrics: dict) -> tuple[int, float]:
    """(steps, CPU minutes) of a checkpoint's training, summed over every job of a restorer trained
    further with ``init_from``; a single job's own figures where no totals are recorded."""
    steps = metrics.get("steps", 0)
    return metrics.get("total_steps", steps), metrics.get("total_cpu_minutes", metrics.get("cpu_ms_per_step", float("nan")) * steps / 60000.0)


def check_initial_restorer(
    path: str | os.PathLike, payload: dict, arch: str, unet_config: UNetConfig, autoencoder: Autoencoder, target_space: str
) -> None:
    """A restorer checkpoint a fine-tuning starts from must fit the job: same arch and UNet shape
    (or the same with more residual blocks per level), built on the same autoencoder (its latents
    are the job's) and the same target space; else a CheckpointError naming ``path``."""
    from recondreamer.generative.data import autoencoder_digest
    from recondreamer.generative.models import model_from_payload

    initial = model_from_payload(payload)
    # A job may grow the UNet by residual blocks (they start as the identity), nothing else.
    grown = dataclasses.replace(initial.unet_config, blocks_per_level=unet_config.blocks_per_level)
    if initial.arch != arch or grown != unet_config or unet_config.blocks_per_level < initial.unet_config.blocks_per_level:
        raise CheckpointError(f"{path}: a {initial.arch} restorer of UNet {initial.unet_config} cannot start a {arch} restorer of UNet {unet_config}")
    if autoencoder_digest(initial.autoencoder) != autoencoder_digest(autoencoder):
        raise CheckpointError(f"{path}: restorer built on another autoencoder than the world model's")
    if initial.diffusion_config.target_space != target_space:
        raise CheckpointError(f"{path}: restorer diffuses in the {initial.diffusion_config.target_space} space, this job in the {target_space} space")


def residual_scale(sequences: list[Sequence]) -> float:
    """Standard deviation of (clean - degraded) latents over every stage of every pair sequence."""
    squares = sum(float(((seq.degraded - seq.target[None]) ** 2).sum()) for seq in sequences)
    count = sum(seq.degraded.numel() for seq in sequences)
    return math.sqrt(squares / count)


# ----------------------------------------------------------------------------------------------
# World models and restorers
# ----------------------------------------------------------------------------------------------


def pretrain_world_model(
    sequences: list[Sequence],
    autoencoder: Autoencoder,
    unet_config: UNetConfig,
    diffusion_config: DiffusionConfig,
    train: TrainConfig,
    structure_channels: tuple[str, ...],
    frame_size: tuple[int, int],
    out: str | os.PathLike,
    device: torch.device | str = "cpu",
) -> dict:
    """Learn to generate corpus clips from a reference frame (and structure maps for dd2) on ``device``."""
    torch.manual_seed(train.seed)
    unet = LatentUNet(unet_config).to(device)  # initialised on the CPU: the same weights on any device
    schedule = NoiseSchedule(diffusion_config)
    LOG.info("world model %s: %d parameters, %d sequences", unet_config.arch, count_parameters(unet), len(sequences))
    model = GenerativeModel(
        kind="world_model", arch=unet_config.arch, unet=unet, autoencoder=autoencoder, schedule=schedule,
        unet_config=unet_config, diffusion_config=diffusion_config, train_config=train,
        structure_channels=structure_channels, frame_size=frame_size,
    )
    config = model_config_dict(model)

    def loss_fn(rng: np.random.Generator, generator: torch.Generator) -> torch.Tensor:
        batch = sample_batch(sequences, rng, train, unet_config.downsample_factor, unet_config.uses_structure, False)
        return unet_loss(unet, schedule, batch, generator, train.timestep_power)

    stats = run_training_loop(
        f"pretrain {unet_config.arch}", unet, loss_fn, train.steps, train.learning_rate, train.warmup_steps, out,
        {"kind": "world_model", "arch": unet_config.arch, **config}, train.checkpoint_every, train.log_every, train.seed, train.weight_decay,
        train.ema_decay,
    )
    save_checkpoint(out, "world_model", unet_config.arch, config, unet.state_dict(), autoencoder=autoencoder_payload(autoencoder), metrics=stats)
    finish_job(out)
    return stats


def train_restorer(
    world: GenerativeModel,
    arch: str,
    sequences: list[Sequence],
    train: TrainConfig,
    masks: MaskConfig | None,
    restore: RestoreConfig,
    out: str | os.PathLike,
    world_model_path: str,
    target_space: str = "residual",
    device: torch.device | str = "cpu",
    init_from: str | os.PathLike | None = None,
    blocks_per_level: int | None = None,
    view_condition: bool = False,
) -> dict:
    """Fine-tune a world model with the (masked, for dd2_mask) degraded video as extra condition.

    ``target_space`` "residual" diffuses (clean - degraded) / scale with the scale measured on
    the pairs (``diffusion.py``); "clean" diffuses clean latents as the world model does.
    Trains on ``device``, where ``world`` (whose autoencoder re-encodes masked frames) is moved.
    ``init_from`` starts from a restorer checkpoint's weights instead of the world model's (to
    train a restorer further, e.g. with other crops or losses); the metrics then also hold the
    total steps and CPU minutes of both jobs. ``blocks_per_level`` (default: ``init_from``'s, else the world model's)
    deepens the UNet by residual blocks that start as the identity, so a restorer can be grown
    from a shallower one (``init_from``) without losing what it learned. ``view_condition`` adds the
    reference-view input (beyond the paper, ``unet.LatentUNet``); it learns from the pairs files
    that hold reference views and sees zeros for the others.
    """
    torch.manual_seed(train.seed)
    world.to(device)
    initial = None if init_from is None else load_checkpoint(init_from, "restorer")  # the restorer this job starts from
    if blocks_per_level is None and initial is not None:
        blocks_per_level = unet_config_from_dict(initial["config"]["unet"]).blocks_per_level
    if view_condition and not any(seq.view is not None for seq in sequences):
        raise RecondreamerError("a view-conditioned restorer needs pairs files with reference views (array 'view'); none of the pairs has one")
    unet = restorer_unet_from_world_model(world, arch, blocks_per_level, view_condition)
    if initial is not None:
        check_initial_restorer(init_from, initial, arch, unet.config, world.autoencoder, target_space)
        load_grown_state(unet, initial["state"], allowed_missing=(), source=str(init_from))
    unet = unet.to(device)
    scale = residual_scale(sequences) if target_space == "residual" else 1.0
    diffusion_config = dataclasses.replace(world.diffusion_config, target_space=target_space, residual_scale=scale)
    schedule = NoiseSchedule(diffusion_config)
    model = GenerativeModel(
        kind="restorer", arch=arch, unet=unet, autoencoder=world.autoencoder, schedule=schedule,
        unet_config=unet.config, diffusion_config=diffusion_config, train_config=train,
        structure_channels=world.structure_channels, frame_size=world.frame_size, mask_config=masks, restore_config=restore,
    )
    config = model_config_dict(model)
    LOG.info(
        "restorer %s: %d parameters, %d pair sequences, target space %s (residual scale %.3f), masks %s",
        arch, count_parameters(unet), len(sequences), target_space, scale, masks,
    )

    image_weight = train.pixel_loss_weight
    world.autoencoder.requires_grad_(False)  # frozen: the image-space loss differentiates through its decoder only

    def loss_fn(rng: np.random.Generator, generator: torch.Generator) -> torch.Tensor:
        batch = sample_batch(
            sequences, rng, train, unet.config.downsample_factor, unet.config.uses_structure, True, masks, world.autoencoder,
            with_pixels=image_weight > 0.0, with_view=view_condition,
        )
        loss, estimate = unet_loss_and_estimate(unet, schedule, batch, generator, train.timestep_power)
        if image_weight > 0.0:
            loss = loss + image_weight * image_space_loss(world.autoencoder, schedule, estimate, batch, restore.residual_decoding)
        return loss

    identity = {"kind": "restorer", "arch": arch, **config}
    if init_from is not None:
        identity["init_from"] = str(init_from)
    stats = run_training_loop(
        f"restorer {arch}", unet, loss_fn, train.steps, train.learning_rate, train.warmup_steps, out,
        identity, train.checkpoint_every, train.log_every, train.seed, train.weight_decay, train.ema_decay,
    )
    stats["total_steps"], stats["total_cpu_minutes"] = training_totals(stats)
    scenes = {seq.scene_id for seq in sequences}
    kinds = {seq.pair_kind for seq in sequences if seq.pair_kind is not None}
    if initial is not None:
        initial_steps, initial_minutes = training_totals(initial.get("metrics", {}))
        stats["total_steps"] += initial_steps
        stats["total_cpu_minutes"] += initial_minutes
        scenes |= set(initial.get("training_scenes", []))
        kinds |= set(initial.get("pair_kinds", []))
    save_checkpoint(
        out, "restorer", arch, config, unet.state_dict(), autoencoder=autoencoder_payload(world.autoencoder), metrics=stats,
        world_model=str(world_model_path), training_scenes=sorted(scenes), pair_kinds=sorted(kinds),
        initialised_from=None if init_from is None else str(init_from),
    )
    finish_job(out)
    return stats


# ----------------------------------------------------------------------------------------------
# Pixel refiner
# ----------------------------------------------------------------------------------------------


def restorer_digest(restorer: GenerativeModel) -> str:
    """A short hash of what a restorer outputs: its UNet weights, autoencoder and restore defaults
    (names the caches of its restored pairs, ``data.restored_pair_frames``)."""
    digest = hashlib.sha1(autoencoder_digest(restorer.autoencoder).encode())
    restore = to_dict(restorer.restore_config)
    digest.update(json.dumps(restore, sort_keys=True).encode())
    hash_weights(digest, restorer.unet)
    return digest.hexdigest()[:12]


@dataclasses.dataclass
class RefinerExample:
    """The frames of one pairs file a refiner trains on (arrays memory-mapped from caches)."""

    scene_id: str
    gt: np.ndarray  # (T,H,W,3) uint8
    degraded: np.ndarray  # (K,T,H,W,3) uint8
    restored: np.ndarray  # (K,T,H,W,3) uint8: the restorer's output for each degraded stage
    structure: np.ndarray | None  # (T,S,H,W) uint8, None for a refiner without structure maps


def load_refiner_examples(files: list[Path], restorer: GenerativeModel, digest: str, with_structure: bool) -> list[RefinerExample]:
    """Every pairs file with the restorer's output for each of its stages (restored once, then cached
    under the restorer's ``digest``, ``restorer_digest``)."""
    from recondreamer.generative.inference import restore_clip

    def restore(frames: np.ndarray, structure: np.ndarray) -> np.ndarray:
        return restore_clip(restorer, frames, structure if restorer.unet_config.uses_structure else None, refine=False)

    examples = []
    started = time.process_time()
    for index, path in enumerate(files):
        content = load_pairs_file(path)
        restored = restored_pair_frames(path, content, restore, digest)
        mapped = mapped_pair_arrays(path, content)
        examples.append(RefinerExample(
            scene_id=str(content["scene_id"]), gt=mapped["gt"], degraded=mapped["degraded"], restored=restored,
            structure=mapped["structure"] if with_structure else None,
        ))
        del content
        LOG.info("refiner pairs %d/%d %s (%.1f CPU min so far)", index + 1, len(files), path.name, (time.process_time() - started) / 60.0)
    return examples


def sample_refiner_batch(examples: list[RefinerExample], rng: np.random.Generator, config: RefinerConfig) -> dict:
    """Random square crops of single frames: restored, degraded, target (B,3,c,c) in [-1,1];
    structure (B,S,c,c) in [0,1] or None; neighbours (B,2n,6,c,c) in [-1,1] (the same crop of the
    frames around, ``refiner.neighbour_stack``) or None when ``config.temporal_neighbours`` is 0."""
    restored, degraded, target, structure, neighbours = [], [], [], [], []
    for _ in range(config.batch_size):
        example = examples[rng.integers(len(examples))]
        stage, frame = int(rng.integers(example.degraded.shape[0])), int(rng.integers(example.gt.shape[0]))
        height, width = example.gt.shape[1:3]
        if config.crop > min(height, width):
            raise RecondreamerError(f"refiner crop {config.crop} is larger than the {width}x{height} frames")
        y, x = int(rng.integers(height - config.crop + 1)), int(rng.integers(width - config.crop + 1))
        rows, cols = slice(y, y + config.crop), slice(x, x + config.crop)
        restored.append(example.restored[stage, frame, rows, cols])
        degraded.append(example.degraded[stage, frame, rows, cols])
        target.append(example.gt[frame, rows, cols])
        if example.structure is not None:
            structure.append(example.structure[frame, :, rows, cols])
        if config.temporal_neighbours:
            neighbours.append(neighbour_stack(example.restored[stage], example.degraded[stage], frame, config.temporal_neighbours, rows, cols))
    return {
        "restored": frames_to_tensor(np.stack(restored)),
        "degraded": frames_to_tensor(np.stack(degraded)),
        "target": frames_to_tensor(np.stack(target)),
        "structure": structure_from_uint8(np.stack(structure)) if structure else None,
        "neighbours": torch.stack(neighbours) if neighbours else None,
    }


def refiner_loss(refiner: PixelRefiner, examples: list[RefinerExample], rng: np.random.Generator, config: RefinerConfig) -> torch.Tensor:
    """Pixel MSE ([-1,1] units) of the refined crops of one random batch against ground truth."""
    batch = _batch_on(sample_refiner_batch(examples, rng, config), module_device(refiner))
    return refined_batch_mse(refiner, batch)


def refined_batch_mse(refiner: PixelRefiner, batch: dict) -> torch.Tensor:  # scalar
    """Pixel MSE of the refiner's output for a ``sample_refiner_batch`` batch against its target."""
    refined = refiner(batch["restored"], batch["degraded"], batch["structure"], batch["neighbours"])
    return torch.mean((refined - batch["target"]) ** 2)


REFINER_CHECK_BATCHES = 16  # fixed batches on which a finished refiner is compared with the identity
# A refiner that lowers the identity's loss by less than this fraction (0.04 dB) is reported as doing
# nothing: a dead refiner (features in SiLU's flat part, correction switched off) scored 0.02% above
# the identity; refiners that gained +0.2-0.4 dB on held-out pairs had 5-9% less squared error.
REFINER_MIN_IMPROVEMENT = 0.01


@torch.no_grad()
def refiner_check_losses(refiner: PixelRefiner, examples: list[RefinerExample], config: RefinerConfig) -> tuple[float, float]:
    """(refined, identity): the pixel MSE of the refiner's output and of the restorer's output alone
    on ``REFINER_CHECK_BATCHES`` batches drawn with a fixed seed. ``train_refiner`` warns when the first is
    not ``REFINER_MIN_IMPROVEMENT`` below the second (a refiner can end with its correction switched off)."""
    rng = np.random.default_rng(config.seed + 1)
    device = module_device(refiner)
    refined, identity = [], []
    for _ in range(REFINER_CHECK_BATCHES):
        batch = _batch_on(sample_refiner_batch(examples, rng, config), device)
        refined.append(refined_batch_mse(refiner, batch).item())
        identity.append(torch.mean((batch["restored"] - batch["target"]) ** 2).item())
    return float(np.mean(refined)), float(np.mean(identity))


def train_refiner(
    restorer_path: str | os.PathLike,
    files: list[Path],
    config: RefinerConfig,
    out: str | os.PathLike,
    device: torch.device | str = "cpu",
    samples: int | None = None,
) -> dict:
    """Train a pixel refiner on a restorer's outputs for the given pairs and write the restorer
    with it (``out``: the restorer checkpoint plus a ``refiner`` entry; its training scenes are
    those of both). ``samples`` (default: the restorer's) sets the noise draws the restorer
    averages, for the outputs the refiner learns from and in ``out``'s restore config, so the
    refiner is used on outputs like those it learned from. Resumable like every job here."""
    payload = load_checkpoint(restorer_path, "restorer")
    if payload.get("refiner") is not None:
        raise CheckpointError(f"{restorer_path}: this restorer already has a pixel refiner; train one on the restorer it was made from")
    if samples is not None:
        payload["config"] = {**payload["config"], "restore": {**payload["config"].get("restore", {}), "samples": samples}}
    restorer = model_from_payload(payload, device)
    with_structure = config.use_structure and restorer.unet_config.uses_structure
    digest = restorer_digest(restorer)  # names the cached outputs and the resume file's job
    started = time.process_time()
    examples = load_refiner_examples(files, restorer, digest, with_structure)
    restore_minutes = (time.process_time() - started) / 60.0  # restoring the pairs (unless cached) and mapping them
    torch.manual_seed(config.seed)
    refiner = PixelRefiner(config, len(restorer.structure_channels) if with_structure else 0).to(device)
    LOG.info("pixel refiner: %d parameters, %d pairs files, structure maps %s", count_parameters(refiner), len(examples), with_structure)

    def loss_fn(rng: np.random.Generator, generator: torch.Generator) -> torch.Tensor:
        return refiner_loss(refiner, examples, rng, config)

    identity = {"kind": "refiner", "arch": payload["arch"], "restorer": digest, "refiner": to_dict(config)}
    stats = run_training_loop(
        "pixel refiner", refiner, loss_fn, config.steps, config.learning_rate, config.warmup_steps, out, identity,
        config.checkpoint_every, config.log_every, config.seed, ema_decay=config.ema_decay,
    )
    stats["pairs_cpu_minutes"] = restore_minutes
    stats["check_loss"], stats["identity_loss"] = refiner_check_losses(refiner, examples, config)
    if stats["check_loss"] > (1.0 - REFINER_MIN_IMPROVEMENT) * stats["identity_loss"]:
        LOG.warning(
            "pixel refiner: its loss on fixed batches (%.5f) is not %.0f%% below the restorer's own error there (%.5f): "
            "it does not improve the restorer's output; compare restoring with and without it before using it",
            stats["check_loss"], 100 * REFINER_MIN_IMPROVEMENT, stats["identity_loss"],
        )
    else:
        LOG.info("pixel refiner: loss on fixed batches %.5f against %.5f for the restorer alone", stats["check_loss"], stats["identity_loss"])
    scenes = sorted({example.scene_id for example in examples} | set(payload.get("training_scenes", [])))
    extra = {key: value for key, value in payload.items() if key not in ("format", "format_version", "kind", "arch", "config", "state")}
    extra.update(training_scenes=scenes, refiner={
        "config": to_dict(config), "structure_channels": refiner.structure_channels, "state": refiner.state_dict(),
        "metrics": stats, "restorer": str(restorer_path),
    })
    save_checkpoint(out, "restorer", payload["arch"], payload["config"], payload["state"], **extra)
    finish_job(out)
    return stats
