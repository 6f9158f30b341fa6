"""Sub-commands of the generative stack: autoencoder, world models, pairs, DriveRestorer, DD4D."""

from __future__ import annotations

import argparse
import dataclasses
import logging
import time
from pathlib import Path

from recondreamer.cli_options import add_config_options, apply_options
from recondreamer.errors import RecondreamerError
from recondreamer.generative.config import (
    ARCHS,
    RESTORER_RESTORE,
    RESTORER_TIMESTEP_POWER,
    WORLD_MODEL_ARCHS,
    AutoencoderConfig,
    MaskConfig,
    RefinerConfig,
    RestoreConfig,
    TrainConfig,
)
from recondreamer.recon.commands import TRAIN_OPTIONS as RECON_TRAIN_OPTIONS
from recondreamer.recon.config import MODEL_TYPES, PRESETS, ReconConfig, make_config

LOG = logging.getLogger(__name__)

AUTOENCODER_OPTIONS = ("steps", "latent_channels")
TRAIN_OPTIONS = ("steps", "batch_size", "window", "crop", "learning_rate", "timestep_power", "ema_decay", "seed")
RESTORER_TRAIN_OPTIONS = TRAIN_OPTIONS + ("pixel_loss_weight",)
RESTORE_OPTIONS = ("sample_steps", "strength", "samples", "residual_decoding")
MASK_OPTIONS = ("probability",)
# Sampling flags of restore and dd4d-generate, generated from RestoreConfig over the checkpoint's values.
GENERATE_OPTIONS = ("sample_steps", "overlap", "seed")
RESTORE_CLIP_OPTIONS = GENERATE_OPTIONS + ("strength", "samples")
REFINER_OPTIONS = ("steps", "batch_size", "crop", "width", "temporal_neighbours", "learning_rate", "ema_decay", "seed",
                   "use_structure", "output_norm", "max_correction")


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("train-autoencoder", help="train the latent autoencoder on corpus frames")
    p.add_argument("--corpus", required=True, help="corpus directory (scene directories below it) or one scene directory")
    p.add_argument("--out", required=True, help="autoencoder checkpoint to write")
    p.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    add_config_options(p, AutoencoderConfig, AUTOENCODER_OPTIONS)
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
    add_config_options(p, TrainConfig, TRAIN_OPTIONS, title="training (TrainConfig)")
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

    p = subparsers.add_parser(
        "make-cycle-pairs",
        help="cycle pairs: a second reconstruction trained on a run's renders of a lateral drive renders the recorded trajectory",
        description="Run A (--run) renders the lateral drive --trajectory; run B (--cycle-run, resumed if present) trains on "
        "those renders alone, with the drive's LiDAR depth, and renders the recorded trajectory from its snapshot at half "
        "its iterations and its final model; the renders pair with the recorded frames in OUT/<scene>__<cycle-run name>.npz "
        "(make-pairs format, with cycle_from and, as reference views, A's renders). No novel-view truth is read.",
    )
    p.add_argument("--run", required=True, help="run A: a reconstruction run directory with model.pt")
    p.add_argument("--trajectory", required=True, help="the lateral drive run A renders and run B trains on (e.g. shift@3)")
    p.add_argument("--cycle-run", required=True, help="run B's run directory (created, or resumed after a kill)")
    p.add_argument("--out", required=True, help="directory receiving the pairs file")
    p.add_argument("--scene", default=None, help="scene directory (default: the scene named in run A's run.json)")
    p.add_argument("--preset", default="default", choices=PRESETS, help="run B's size preset (its backbone is run A's)")
    add_config_options(p, ReconConfig, RECON_TRAIN_OPTIONS, defaults=make_config(MODEL_TYPES[0], "default"),
                       title="run B's training (ReconConfig; defaults shown for --preset default)")
    _add_threads_option(p)
    p.set_defaults(func=run_make_cycle_pairs)

    p = subparsers.add_parser("train-restorer", help="fine-tune a world model into DriveRestorer on restoration pairs")
    p.add_argument("--arch", required=True, choices=ARCHS, help="restorer backbone (dd2_mask fine-tunes a dd2 world model with masks)")
    p.add_argument("--world-model", required=True, help="pretrained world-model checkpoint of the matching arch")
    p.add_argument("--pairs", required=True, nargs="+", help="restoration-pairs directories or .npz files")
    p.add_argument("--out", required=True, help="restorer checkpoint to write")
    add_config_options(p, MaskConfig, MASK_OPTIONS, prefix="mask-", title="dd2_mask training masks (MaskConfig)")
    add_config_options(p, RestoreConfig, RESTORE_OPTIONS, defaults=RESTORER_RESTORE, title="restore settings stored in the checkpoint (RestoreConfig)")
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
        "--view-condition", action="store_true",
        help="beyond the paper: also condition on each frame's reference view (the view the reconstruction was trained on at "
        "the same timestamp), from the pairs files' 'view' arrays (novel-trajectory pairs hold the recorded frames; pairs "
        "without views count as having none)",
    )
    add_config_options(
        p, TrainConfig, RESTORER_TRAIN_OPTIONS, title="training (TrainConfig)",
        defaults={"*": "the world model's", "timestep_power": f"{RESTORER_TIMESTEP_POWER:g}", "pixel_loss_weight": "0"},
    )
    _add_threads_option(p)
    _add_device_option(p)
    p.set_defaults(func=run_train_restorer)

    p = subparsers.add_parser(
        "train-refiner", help="train DriveRestorer's pixel refiner on the restorer's outputs for restoration pairs (docs/generative.md)"
    )
    p.add_argument("--restorer", required=True, help="restorer checkpoint (train-restorer output) whose outputs the refiner corrects")
    p.add_argument("--pairs", required=True, nargs="+", help="restoration-pairs directories or .npz files (e.g. the restorer's own)")
    p.add_argument("--out", required=True, help="checkpoint to write: the restorer with its refiner")
    p.add_argument(
        "--samples", type=int, default=None,
        help="noise draws the restorer averages per window, for the outputs the refiner learns from and in the written "
        "checkpoint (default: the restorer's own)",
    )
    add_config_options(p, RefinerConfig, REFINER_OPTIONS)
    _add_threads_option(p)
    _add_device_option(p)
    p.set_defaults(func=run_train_refiner)

    p = subparsers.add_parser("restore", help="restore a rendered clip with DriveRestorer")
    p.add_argument("--restorer", required=True, help="restorer checkpoint (train-restorer output)")
    p.add_argument("--scene", required=True, help="scene directory (boxes and HD map for the structure maps; frame size check)")
    p.add_argument("--renders", required=True, help="rendered clip: folder of frames (or with a sub-folder named after the trajectory) or a .npy")
    p.add_argument("--trajectory", required=True, help="trajectory the renders were made along (original, shift@Y, lane_change, file:PATH)")
    p.add_argument("--out", required=True, help="output folder of restored frames {t:03d}.png")
    _add_sampling_options(p, RESTORE_CLIP_OPTIONS)
    _add_threads_option(p)
    _add_device_option(p)
    p.set_defaults(func=run_restore)

    p = subparsers.add_parser("dd4d-generate", help="DriveDreamer4D: generate a novel-trajectory video with the pretrained dd2 world model")
    p.add_argument("--world-model", required=True, help="pretrained dd2 world-model checkpoint (not fine-tuned on pairs)")
    p.add_argument("--scene", required=True, help="scene directory (original frames as reference, boxes and map)")
    p.add_argument("--trajectory", required=True, help="novel trajectory (shift@Y, lane_change, file:PATH)")
    p.add_argument("--out", required=True, help="output folder of generated frames {t:03d}.png")
    _add_sampling_options(p, GENERATE_OPTIONS)
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
    from recondreamer.device import resolve_device

    return resolve_device(args.device, "--device")


def _add_sampling_options(p: argparse.ArgumentParser, names: tuple[str, ...]) -> None:
    add_config_options(p, RestoreConfig, names, defaults={"*": "the checkpoint's"}, title="sampling (RestoreConfig)")


def run_train_autoencoder(args: argparse.Namespace) -> int:
    from recondreamer.generative.data import load_corpus_frames
    from recondreamer.generative.training import train_autoencoder

    config = apply_options(args, AutoencoderConfig(), AUTOENCODER_OPTIONS)
    _set_threads(args)
    device = _device(args)
    scene_ids, frames = load_corpus_frames(args.corpus)
    LOG.info("autoencoder corpus: %d scenes (%s)", len(scene_ids), ", ".join(scene_ids))
    metrics = train_autoencoder(frames, args.out, config, seed=args.seed, device=device)
    LOG.info("wrote %s: held-out PSNR %.2f dB, %.0f ms/step", args.out, metrics["heldout_psnr"], metrics["ms_per_step"])
    return 0


def run_pretrain_world_model(args: argparse.Namespace) -> int:
    from recondreamer.generative.config import DiffusionConfig, UNetConfig
    from recondreamer.generative.data import (
        load_corpus_sequences,
        structure_channel_names,
    )
    from recondreamer.generative.models import load_autoencoder
    from recondreamer.generative.training import pretrain_world_model

    train = apply_options(args, TrainConfig(), TRAIN_OPTIONS)
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
        sequences, autoencoder, unet_config, DiffusionConfig(), train, names, frame_size, args.out, device
    )
    LOG.info("wrote %s: final loss %.4f, %.0f ms/step", args.out, stats["final_loss"], stats["ms_per_step"])
    return 0


def run_make_pairs(args: argparse.Namespace) -> int:
    from recondreamer.generative.pairs import make_pairs_for_run

    _set_threads(args)
    for run in args.run:
        for out in make_pairs_for_run(run, args.out, args.stages, args.scene, tuple(args.trajectories)):
            LOG.info("wrote %s", out)
    return 0


def run_make_cycle_pairs(args: argparse.Namespace) -> int:
    from recondreamer.device import resolve_device
    from recondreamer.generative.cycle import make_cycle_pairs
    from recondreamer.generative.pairs import run_scene_path
    from recondreamer.recon.checkpoint import read_record, resolve_model_path

    _set_threads(args)
    source = Path(args.run)
    if not (source / "model.pt").is_file():
        raise RecondreamerError(f"--run {source}: no final model {source / 'model.pt'} (train run A first)")
    backbone = read_record(resolve_model_path(source / "model.pt"))["model_type"]
    config = apply_options(args, make_config(backbone, args.preset), RECON_TRAIN_OPTIONS)
    resolve_device(config.device, "--device")
    scene = args.scene if args.scene is not None else run_scene_path(source)
    LOG.info("wrote %s", make_cycle_pairs(source, scene, args.trajectory, args.cycle_run, args.out, config))
    return 0


def run_train_restorer(args: argparse.Namespace) -> int:
    from recondreamer.generative.data import find_pairs_files, load_pair_sequences
    from recondreamer.generative.inference import load_world_model
    from recondreamer.generative.training import train_restorer

    if args.blocks_per_level is not None and args.blocks_per_level < 1:
        raise RecondreamerError(f"--blocks-per-level must be >= 1, got {args.blocks_per_level}")
    masks = apply_options(args, MaskConfig(), MASK_OPTIONS, prefix="mask-") if args.arch == "dd2_mask" else None
    restore = apply_options(args, RESTORER_RESTORE, RESTORE_OPTIONS)
    apply_options(args, TrainConfig(), RESTORER_TRAIN_OPTIONS)  # the options' ranges, before any model is loaded
    _set_threads(args)
    device = _device(args)
    world = load_world_model(args.world_model, device)
    restorer_recipe = dataclasses.replace(world.train_config, timestep_power=RESTORER_TIMESTEP_POWER, pixel_loss_weight=0.0)
    train = apply_options(args, restorer_recipe, RESTORER_TRAIN_OPTIONS)
    files = find_pairs_files(args.pairs)
    keep_frames = masks is not None or train.pixel_loss_weight > 0.0
    sequences = load_pair_sequences(files, world.autoencoder, world.unet_config.uses_structure, keep_frames=keep_frames)
    stats = train_restorer(
        world, args.arch, sequences, train, masks, restore, args.out, args.world_model, args.target_space, device, args.init_restorer,
        args.blocks_per_level, args.view_condition,
    )
    LOG.info("wrote %s: final loss %.4f, %.0f ms/step", args.out, stats["final_loss"], stats["ms_per_step"])
    return 0


def run_train_refiner(args: argparse.Namespace) -> int:
    from recondreamer.generative.data import find_pairs_files
    from recondreamer.generative.training import train_refiner

    config = apply_options(args, RefinerConfig(), REFINER_OPTIONS)
    if args.samples is not None and args.samples < 1:
        raise RecondreamerError(f"--samples must be >= 1, got {args.samples}")
    _set_threads(args)
    stats = train_refiner(args.restorer, find_pairs_files(args.pairs), config, args.out, _device(args), args.samples)
    LOG.info("wrote %s: final loss %.5f, %.0f CPU ms/step", args.out, stats["final_loss"], stats["cpu_ms_per_step"])
    return 0


def _scene_conditions(scene_dir: str, trajectory: str, needs_structure: bool):
    """Original frames (reference) and structure maps of the trajectory's cameras."""
    from recondreamer.generative.data import scene_structure
    from recondreamer.scene import load_scene
    from recondreamer.scene.trajectories import trajectory_cam_to_world

    scene = load_scene(scene_dir)
    try:
        cams = trajectory_cam_to_world(scene.cam_to_world, scene.ego_to_world, trajectory)
    except ValueError as error:
        raise RecondreamerError(f"--trajectory {trajectory!r}: {error}") from error
    reference = scene.images()
    structure = scene_structure(scene, cams) if needs_structure else None
    return scene, reference, structure


def run_restore(args: argparse.Namespace) -> int:
    from recondreamer.io import check_replaceable
    from recondreamer.frames_io import read_clip, write_frames
    from recondreamer.generative.inference import load_restorer, restore_clip

    check_replaceable(args.out, "frames")
    _set_threads(args)
    restorer = load_restorer(args.restorer, _device(args))
    renders = read_clip(args.renders, args.trajectory)
    scene, reference, structure = _scene_conditions(args.scene, args.trajectory, restorer.unet_config.uses_structure)
    if renders.shape != reference.shape:
        raise RecondreamerError(f"{args.renders}: renders {renders.shape} do not match the scene's frames {reference.shape} (T,H,W,3)")
    start = time.perf_counter()
    sampling = apply_options(args, restorer.restore_config, RESTORE_CLIP_OPTIONS)
    # A view-conditioned restorer sees, on a novel trajectory, the recorded frames of the same timestamps.
    view = reference if restorer.unet_config.view_condition and args.trajectory != "original" else None
    restored = restore_clip(
        restorer, renders, structure, num_steps=sampling.sample_steps, overlap=sampling.overlap, strength=sampling.strength,
        seed=sampling.seed, samples=sampling.samples, view=view,
    )
    seconds = time.perf_counter() - start
    LOG.info("restored %d frames with %s on %s in %.1f s", len(restored), restorer.arch, restorer.device, seconds)
    info = {"restorer": str(args.restorer), "arch": restorer.arch, "scene_id": scene.scene_id, "trajectory": args.trajectory, "seconds": seconds}
    write_frames(args.out, restored, info)
    return 0


def run_dd4d_generate(args: argparse.Namespace) -> int:
    from recondreamer.io import check_replaceable
    from recondreamer.frames_io import write_frames
    from recondreamer.generative.inference import generate_clip, load_world_model

    check_replaceable(args.out, "frames")
    _set_threads(args)
    world = load_world_model(args.world_model, _device(args))
    if world.arch != "dd2":
        raise RecondreamerError(f"{args.world_model}: DriveDreamer4D generation needs the dd2 world model, got {world.arch!r}")
    scene, reference, structure = _scene_conditions(args.scene, args.trajectory, True)
    start = time.perf_counter()
    # A world model samples with its diffusion config's steps over its training window, seed 0 unless given.
    checkpoint_sampling = dataclasses.replace(world.restore_config, sample_steps=world.diffusion_config.sample_steps,
                                              window=world.train_config.window, seed=0)
    sampling = apply_options(args, checkpoint_sampling, GENERATE_OPTIONS)
    generated = generate_clip(world, reference, structure, num_steps=sampling.sample_steps, window=sampling.window,
                              overlap=sampling.overlap, seed=sampling.seed)
    seconds = time.perf_counter() - start
    LOG.info("generated %d frames along %s on %s in %.1f s", len(generated), args.trajectory, world.device, seconds)
    info = {"world_model": str(args.world_model), "scene_id": scene.scene_id, "trajectory": args.trajectory, "seconds": seconds}
    write_frames(args.out, generated, info)
    return 0
