"""Sub-commands of the generative stack: autoencoder, world models, pairs, DriveRestorer, DD4D."""

from __future__ import annotations

import argparse
import dataclasses
import logging
import time

from recondreamer.restorer.config import ARCHS, WORLD_MODEL_ARCHS

LOG = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("train-autoencoder", help="train the latent autoencoder on corpus frames")
    p.add_argument("--corpus", required=True, help="corpus directory (scene directories below it) or one scene directory")
    p.add_argument("--out", required=True, help="autoencoder checkpoint to write")
    p.add_argument("--steps", type=int, default=None, help="training steps (default from AutoencoderConfig)")
    p.add_argument("--latent-channels", type=int, default=None, help="latent channels (default 4)")
    p.add_argument("--seed", type=int, default=0, help="random seed")
    _add_threads_option(p)
    _add_device_option(p)
    p.set_defaults(func=run_train_autoencoder)

    p = subparsers.add_parser("pretrain-world-model", help="pretrain an sd/svd/dd2 world model on corpus clips")
    p.add_argument("--arch", required=True, choices=WORLD_MODEL_ARCHS, help="backbone: sd (image), svd (video), dd2 (video + structure)")
    p.add_argument("--corpus", required=True, help="corpus directory (scene directories below it)")
    p.add_argument("--autoencoder", required=True, help="autoencoder checkpoint (train-autoencoder output)")
    p.add_argument("--out", required=True, help="world-model checkpoint to write")
    p.add_argument(
        "--channels", type=int, nargs="+", default=None, metavar="C",
        help="UNet channels per resolution level, finest first (default 32 64 64 from UNetConfig); spatial attention "
        "on the coarsest level only, temporal attention on every level",
    )
    _add_train_options(p)
    _add_threads_option(p)
    _add_device_option(p)
    p.set_defaults(func=run_pretrain_world_model)

    p = subparsers.add_parser("make-pairs", help="render restoration pairs from reconstruction snapshots (paper Fig. 3)")
    p.add_argument("--run", required=True, nargs="+", help="reconstruction run directories (with snapshots/step_*.pt)")
    p.add_argument("--out", required=True, help="directory receiving one <scene>__<run>.npz per run")
    p.add_argument("--stages", type=int, default=4, help="training stages (snapshots) sampled per run (default 4)")
    p.add_argument("--scene", default=None, help="scene directory of every run (default: the scene named in each run.json)")
    p.add_argument(
        "--trajectories", nargs="+", default=["original"],
        help="trajectories to render (default: original); novel ones (shift@Y, lane_change) need the scene's true "
        "novel views and are also rendered from the final model.pt",
    )
    _add_threads_option(p)
    p.set_defaults(func=run_make_pairs)

    p = subparsers.add_parser("train-restorer", help="fine-tune a world model into DriveRestorer on restoration pairs")
    p.add_argument("--arch", required=True, choices=ARCHS, help="restorer backbone (dd2_mask fine-tunes a dd2 world model with masks)")
    p.add_argument("--world-model", required=True, help="pretrained world-model checkpoint of the matching arch")
    p.add_argument("--pairs", required=True, nargs="+", help="restoration-pairs directories or .npz files")
    p.add_argument("--out", required=True, help="restorer checkpoint to write")
    p.add_argument("--mask-probability", type=float, default=None, help="dd2_mask: probability that a frame is masked (default from MaskConfig)")
    p.add_argument("--sample-steps", type=int, default=None, help="default DDIM steps stored for restoring (default 1)")
    p.add_argument("--strength", type=float, default=None, help="default restore strength stored in the checkpoint (default from RestoreConfig)")
    p.add_argument(
        "--samples", type=int, default=None,
        help="default noise draws averaged per restored window, stored in the checkpoint (default 4)",
    )
    p.add_argument(
        "--residual-decoding", choices=["on", "off"], default=None,
        help="store whether restoring decodes only the change and adds it to the input (default on)",
    )
    p.add_argument(
        "--target-space", choices=["residual", "clean"], default="residual",
        help="what the restorer diffuses: residual = (clean - degraded) latents, so a zero output is the identity "
        "(default); clean = clean latents, as the world model",
    )
    p.add_argument(
        "--init-restorer", default=None, metavar="CKPT",
        help="start from this restorer's weights instead of the world model's, to train it further (same arch, UNet "
        "and autoencoder; default: the world model)",
    )
    p.add_argument(
        "--blocks-per-level", type=int, default=None, metavar="N",
        help="residual blocks per UNet level, down and up (default: the --init-restorer's, else the world model's: 1); blocks past those "
        "start as the identity, so a deeper restorer can be grown from a trained one",
    )
    p.add_argument(
        "--pixel-loss-weight", type=float, default=None,
        help="weight of an image-space loss (MSE of the decoded one-step sample against ground truth, [-1,1] pixel "
        "units) added to the diffusion loss; 0 = diffusion loss only (default 0)",
    )
    _add_train_options(p)
    _add_threads_option(p)
    _add_device_option(p)
    p.set_defaults(func=run_train_restorer)

    p = subparsers.add_parser(
        "train-refiner", help="train DriveRestorer's pixel refiner on the restorer's outputs for restoration pairs (docs/restorer.md)"
    )
    p.add_argument("--restorer", required=True, help="restorer checkpoint (train-restorer output) whose outputs the refiner corrects")
    p.add_argument("--pairs", required=True, nargs="+", help="restoration-pairs directories or .npz files (e.g. the restorer's own)")
    p.add_argument("--out", required=True, help="checkpoint to write: the restorer with its refiner")
    p.add_argument(
        "--samples", type=int, default=None,
        help="noise draws the restorer averages per window, for the outputs the refiner learns from and in the written "
        "checkpoint (default: the restorer's own)",
    )
    p.add_argument("--steps", type=int, default=None, help="training steps (default from RefinerConfig: 3000)")
    p.add_argument("--batch-size", type=int, default=None, help="pixel crops per step (default 8)")
    p.add_argument("--crop", type=int, default=None, help="side of the square training crops in pixels (default 64)")
    p.add_argument("--width", type=int, default=None, help="refiner channels at full resolution (default 24)")
    p.add_argument("--temporal-neighbours", type=int, default=None,
                   help="also show the refiner this many restored and degraded frames before and after each one (default 0)")
    p.add_argument("--learning-rate", type=float, default=None, help="AdamW learning rate (default 5e-4)")
    p.add_argument("--ema-decay", type=float, default=None, help="EMA of the weights saved instead of the last ones (default 0: off)")
    p.add_argument("--seed", type=int, default=None, help="random seed (default 0)")
    p.add_argument("--no-structure", action="store_true", help="do not show the refiner the structure maps (dd2 archs)")
    p.add_argument("--no-output-norm", action="store_true",
                   help="build the refiner without the channel norm before its last conv (as checkpoints without an output_norm entry load)")
    p.add_argument("--max-correction", type=float, default=None,
                   help="largest change the refiner may make to a pixel, in grey levels of 255 (default 12; 0: unbounded)")
    _add_threads_option(p)
    _add_device_option(p)
    p.set_defaults(func=run_train_refiner)

    p = subparsers.add_parser("restore", help="restore a rendered clip with DriveRestorer")
    p.add_argument("--restorer", required=True, help="restorer checkpoint (train-restorer output)")
    p.add_argument("--scene", required=True, help="scene directory (boxes and HD map for the structure maps; frame size check)")
    p.add_argument("--renders", required=True, help="rendered clip: folder of frames (or with a sub-folder named after the trajectory) or a .npy")
    p.add_argument("--trajectory", required=True, help="trajectory the renders were made along (original, shift@Y, lane_change, file:PATH)")
    p.add_argument("--out", required=True, help="output folder of restored frames {t:03d}.png")
    _add_sampling_options(p)
    p.add_argument("--strength", type=float, default=None, help="1 = start from noise; < 1 starts from the noised render (default from the checkpoint)")
    p.add_argument("--samples", type=int, default=None, help="noise draws averaged per window (default from the checkpoint)")
    _add_threads_option(p)
    _add_device_option(p)
    p.set_defaults(func=run_restore)

    p = subparsers.add_parser("dd4d-generate", help="DriveDreamer4D: generate a novel-trajectory video with the pretrained dd2 world model")
    p.add_argument("--world-model", required=True, help="pretrained dd2 world-model checkpoint (not fine-tuned on pairs)")
    p.add_argument("--scene", required=True, help="scene directory (original frames as reference, boxes and map)")
    p.add_argument("--trajectory", required=True, help="novel trajectory (shift@Y, lane_change, file:PATH)")
    p.add_argument("--out", required=True, help="output folder of generated frames {t:03d}.png")
    _add_sampling_options(p)
    _add_threads_option(p)
    _add_device_option(p)
    p.set_defaults(func=run_dd4d_generate)


def _add_threads_option(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--threads", type=int, default=1,
        help="torch CPU threads (default 1: jobs run side by side, and OpenMP threads on a busy "
        "machine stall each other far more than they help)",
    )


def _set_threads(args: argparse.Namespace) -> None:
    import torch

    torch.set_num_threads(args.threads)  # positive: checked by the command line


def _add_device_option(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--device", default="cpu",
        help="torch device of the models: cpu (default) or cuda / cuda:N; checkpoints are written with CPU tensors "
        "and load on any device",
    )


def _device(args: argparse.Namespace):
    from recondreamer.restorer.device import resolve_device

    return resolve_device(args.device, "--device")


def _add_train_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--steps", type=int, default=None, help="training steps (default from TrainConfig)")
    p.add_argument("--batch-size", type=int, default=None, help="clips per step (default from TrainConfig)")
    p.add_argument("--window", type=int, default=None, help="frames per clip (default from TrainConfig)")
    p.add_argument("--learning-rate", type=float, default=None, help="AdamW learning rate (default from TrainConfig)")
    p.add_argument("--seed", type=int, default=None, help="random seed (default 0)")
    p.add_argument(
        "--crop", type=int, nargs=2, default=None, metavar=("H", "W"),
        help="latent crop (h w) of training clips; 0 0 = whole latents (default from TrainConfig)",
    )
    p.add_argument(
        "--ema-decay", type=float, default=None,
        help="keep an exponential moving average of the weights with this decay and save it (0 = the last weights; "
        "default from TrainConfig: 0); pick it so that decay^steps is small, e.g. 0.995 for 1000 steps",
    )
    p.add_argument(
        "--timestep-power", type=float, default=None,
        help="training timesteps drawn with density ~ t^(power-1): 1 = uniform, > 1 favours the noisy steps a "
        "few-step sampler visits (default 1 for world models, 50 for restorers: almost only the t = 999 of 1-step restoring)",
    )


def _add_sampling_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--steps", type=int, default=None, help="DDIM steps (default from the checkpoint)")
    p.add_argument("--overlap", type=int, default=None, help="frames shared by consecutive windows (default from the checkpoint)")
    p.add_argument("--seed", type=int, default=None, help="sampling seed (default from the checkpoint)")


def _check_train_options(args: argparse.Namespace) -> None:
    """Reject bad training options before any model or data is loaded."""
    from recondreamer.errors import RecondreamerError

    if args.ema_decay is not None and not 0.0 <= args.ema_decay < 1.0:
        raise RecondreamerError(f"--ema-decay must be in [0, 1), got {args.ema_decay}")
    pixel_loss_weight = getattr(args, "pixel_loss_weight", None)  # train-restorer only
    if pixel_loss_weight is not None and pixel_loss_weight < 0.0:
        raise RecondreamerError(f"--pixel-loss-weight must be >= 0, got {pixel_loss_weight}")
    blocks_per_level = getattr(args, "blocks_per_level", None)  # train-restorer only
    if blocks_per_level is not None and blocks_per_level < 1:
        raise RecondreamerError(f"--blocks-per-level must be >= 1, got {blocks_per_level}")


def _train_config(args: argparse.Namespace, base=None):
    from recondreamer.restorer.config import TrainConfig

    overrides = {
        "steps": args.steps, "batch_size": args.batch_size, "window": args.window,
        "learning_rate": args.learning_rate, "seed": args.seed, "timestep_power": args.timestep_power,
        "crop": None if args.crop is None else tuple(args.crop), "ema_decay": args.ema_decay,
    }
    return dataclasses.replace(base or TrainConfig(), **{k: v for k, v in overrides.items() if v is not None})


def run_train_autoencoder(args: argparse.Namespace) -> int:
    from recondreamer.restorer.config import AutoencoderConfig
    from recondreamer.restorer.data import load_corpus_frames
    from recondreamer.restorer.training import train_autoencoder

    _set_threads(args)
    device = _device(args)
    config = AutoencoderConfig()
    if args.steps is not None:
        config = dataclasses.replace(config, steps=args.steps)
    if args.latent_channels is not None:
        config = dataclasses.replace(config, latent_channels=args.latent_channels)
    scene_ids, frames = load_corpus_frames(args.corpus)
    LOG.info("autoencoder corpus: %d scenes (%s)", len(scene_ids), ", ".join(scene_ids))
    metrics = train_autoencoder(frames, args.out, config, seed=args.seed, device=device)
    LOG.info("wrote %s: held-out PSNR %.2f dB, %.0f ms/step", args.out, metrics["heldout_psnr"], metrics["ms_per_step"])
    return 0


def run_pretrain_world_model(args: argparse.Namespace) -> int:
    from recondreamer.errors import RecondreamerError
    from recondreamer.restorer.config import DiffusionConfig, UNetConfig
    from recondreamer.restorer.data import (
        load_corpus_sequences,
        structure_channel_names,
    )
    from recondreamer.restorer.models import load_autoencoder
    from recondreamer.restorer.training import pretrain_world_model

    _check_train_options(args)
    _set_threads(args)
    device = _device(args)
    autoencoder, _ = load_autoencoder(args.autoencoder, device)
    uses_structure = args.arch == "dd2"
    names = structure_channel_names() if uses_structure else ()
    unet_config = UNetConfig(
        arch=args.arch, latent_channels=autoencoder.config.latent_channels, structure_channels=len(names),
        downsample_factor=autoencoder.config.downsample_factor,
    )
    if args.channels is not None:
        levels = len(args.channels)
        if levels < 2 or any(c < 8 or c % 8 for c in args.channels):
            raise RecondreamerError(
                f"--channels {' '.join(map(str, args.channels))}: give at least 2 levels, each a positive multiple of 8 "
                "(8 group-norm groups, 4 attention heads)"
            )
        unet_config = dataclasses.replace(
            unet_config, channels=tuple(args.channels), attention_levels=(False,) * (levels - 1) + (True,), temporal_levels=(True,) * levels
        )
    sequences = load_corpus_sequences(args.corpus, autoencoder, uses_structure)
    f = autoencoder.config.downsample_factor
    frame_size = (sequences[0].target.shape[-2] * f, sequences[0].target.shape[-1] * f)
    stats = pretrain_world_model(
        sequences, autoencoder, unet_config, DiffusionConfig(), _train_config(args), names, frame_size, args.out, device
    )
    LOG.info("wrote %s: final loss %.4f, %.0f ms/step", args.out, stats["final_loss"], stats["ms_per_step"])
    return 0


def run_make_pairs(args: argparse.Namespace) -> int:
    from recondreamer.restorer.pairs import make_pairs_for_run

    _set_threads(args)
    for run in args.run:
        for out in make_pairs_for_run(run, args.out, args.stages, args.scene, tuple(args.trajectories)):
            LOG.info("wrote %s", out)
    return 0


def run_train_restorer(args: argparse.Namespace) -> int:
    from recondreamer.errors import RecondreamerError
    from recondreamer.restorer.config import (
        RESTORER_RESIDUAL_DECODING,
        RESTORER_SAMPLE_STEPS,
        RESTORER_SAMPLES,
        RESTORER_TIMESTEP_POWER,
        MaskConfig,
        RestoreConfig,
    )
    from recondreamer.restorer.data import find_pairs_files, load_pair_sequences
    from recondreamer.restorer.inference import load_world_model
    from recondreamer.restorer.training import train_restorer

    _check_train_options(args)
    _set_threads(args)
    device = _device(args)
    world = load_world_model(args.world_model, device)
    masks = None
    if args.arch == "dd2_mask":
        masks = MaskConfig() if args.mask_probability is None else dataclasses.replace(MaskConfig(), probability=args.mask_probability)
    train = _train_config(args, world.train_config)
    if args.timestep_power is None:
        train = dataclasses.replace(train, timestep_power=RESTORER_TIMESTEP_POWER)
    train = dataclasses.replace(train, pixel_loss_weight=args.pixel_loss_weight or 0.0)
    files = find_pairs_files(args.pairs)
    keep_frames = masks is not None or train.pixel_loss_weight > 0.0
    sequences = load_pair_sequences(files, world.autoencoder, world.unet_config.uses_structure, keep_frames=keep_frames)
    restore = RestoreConfig(sample_steps=RESTORER_SAMPLE_STEPS, residual_decoding=RESTORER_RESIDUAL_DECODING, samples=RESTORER_SAMPLES)
    overrides = {"sample_steps": args.sample_steps, "strength": args.strength, "samples": args.samples}
    if args.residual_decoding is not None:
        overrides["residual_decoding"] = args.residual_decoding == "on"
    restore = dataclasses.replace(restore, **{k: v for k, v in overrides.items() if v is not None})
    if not 0.0 < restore.strength <= 1.0 or restore.sample_steps < 1 or restore.samples < 1:
        raise RecondreamerError(
            f"--strength must be in (0, 1], --sample-steps and --samples >= 1, got {restore.strength}, {restore.sample_steps} and {restore.samples}"
        )
    stats = train_restorer(
        world, args.arch, sequences, train, masks, restore, args.out, args.world_model, args.target_space, device, args.init_restorer,
        args.blocks_per_level,
    )
    LOG.info("wrote %s: final loss %.4f, %.0f ms/step", args.out, stats["final_loss"], stats["ms_per_step"])
    return 0


def run_train_refiner(args: argparse.Namespace) -> int:
    from recondreamer.errors import RecondreamerError
    from recondreamer.restorer.config import RefinerConfig
    from recondreamer.restorer.data import find_pairs_files
    from recondreamer.restorer.training import train_refiner

    overrides = {
        "steps": args.steps, "batch_size": args.batch_size, "crop": args.crop, "width": args.width,
        "learning_rate": args.learning_rate, "ema_decay": args.ema_decay, "seed": args.seed,
        "temporal_neighbours": args.temporal_neighbours, "max_correction": args.max_correction,
    }
    overrides = {k: v for k, v in overrides.items() if v is not None}
    config = dataclasses.replace(RefinerConfig(), use_structure=not args.no_structure, output_norm=not args.no_output_norm, **overrides)
    for name in ("steps", "batch_size", "crop", "width"):
        if getattr(config, name) < 1:
            raise RecondreamerError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(config, name)}")
    if config.temporal_neighbours < 0:
        raise RecondreamerError(f"--temporal-neighbours must be >= 0, got {config.temporal_neighbours}")
    if not 0.0 <= config.ema_decay < 1.0:
        raise RecondreamerError(f"--ema-decay must be in [0, 1), got {config.ema_decay}")
    if config.max_correction < 0:
        raise RecondreamerError(f"--max-correction must be >= 0 grey levels (0: unbounded), got {config.max_correction}")
    if args.samples is not None and args.samples < 1:
        raise RecondreamerError(f"--samples must be >= 1, got {args.samples}")
    _set_threads(args)
    stats = train_refiner(args.restorer, find_pairs_files(args.pairs), config, args.out, _device(args), args.samples)
    LOG.info("wrote %s: final loss %.5f, %.0f CPU ms/step", args.out, stats["final_loss"], stats["cpu_ms_per_step"])
    return 0


def _scene_conditions(scene_dir: str, trajectory: str, needs_structure: bool):
    """Original frames (reference) and structure maps of the trajectory's cameras."""
    import numpy as np

    from recondreamer.errors import RecondreamerError
    from recondreamer.restorer.data import scene_structure
    from recondreamer.scene import load_scene
    from recondreamer.scene.trajectories import trajectory_cam_to_world

    scene = load_scene(scene_dir)
    try:
        cams = trajectory_cam_to_world(scene.cam_to_world, scene.ego_to_world, trajectory)
    except ValueError as error:
        raise RecondreamerError(f"--trajectory {trajectory!r}: {error}") from error
    reference = np.stack([scene.image(t) for t in range(scene.num_frames)])
    structure = scene_structure(scene, cams) if needs_structure else None
    return scene, reference, structure


def run_restore(args: argparse.Namespace) -> int:
    from recondreamer.errors import RecondreamerError
    from recondreamer.io import check_replaceable
    from recondreamer.restorer.frames_io import read_frames, write_frames
    from recondreamer.restorer.inference import load_restorer, restore_clip

    check_replaceable(args.out, "frames")
    _set_threads(args)
    restorer = load_restorer(args.restorer, _device(args))
    renders = read_frames(args.renders, args.trajectory)
    scene, reference, structure = _scene_conditions(args.scene, args.trajectory, restorer.unet_config.uses_structure)
    if renders.shape != reference.shape:
        raise RecondreamerError(f"{args.renders}: renders {renders.shape} do not match the scene's frames {reference.shape} (T,H,W,3)")
    start = time.perf_counter()
    restored = restore_clip(
        restorer, renders, structure, num_steps=args.steps, overlap=args.overlap, strength=args.strength, seed=args.seed, samples=args.samples
    )
    seconds = time.perf_counter() - start
    LOG.info("restored %d frames with %s on %s in %.1f s", len(restored), restorer.arch, restorer.device, seconds)
    info = {"restorer": str(args.restorer), "arch": restorer.arch, "scene_id": scene.scene_id, "trajectory": args.trajectory, "seconds": seconds}
    write_frames(args.out, restored, info)
    return 0


def run_dd4d_generate(args: argparse.Namespace) -> int:
    from recondreamer.errors import RecondreamerError
    from recondreamer.io import check_replaceable
    from recondreamer.restorer.frames_io import write_frames
    from recondreamer.restorer.inference import generate_clip, load_world_model

    check_replaceable(args.out, "frames")
    _set_threads(args)
    world = load_world_model(args.world_model, _device(args))
    if world.arch != "dd2":
        raise RecondreamerError(f"{args.world_model}: DriveDreamer4D generation needs the dd2 world model, got {world.arch!r}")
    scene, reference, structure = _scene_conditions(args.scene, args.trajectory, True)
    start = time.perf_counter()
    generated = generate_clip(world, reference, structure, num_steps=args.steps, overlap=args.overlap, seed=args.seed or 0)
    seconds = time.perf_counter() - start
    LOG.info("generated %d frames along %s on %s in %.1f s", len(generated), args.trajectory, world.device, seconds)
    info = {"world_model": str(args.world_model), "scene_id": scene.scene_id, "trajectory": args.trajectory, "seconds": seconds}
    write_frames(args.out, generated, info)
    return 0
