"""Sub-commands ``train-recondreamer`` (PDUS loop) and ``train-dd4d`` (DriveDreamer4D baseline)."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from recondreamer.cli_options import add_config_options, apply_options, naming_flags
from recondreamer.generative.config import RestoreConfig
from recondreamer.methods.pdus import PdusSchedule
from recondreamer.recon.commands import add_training_options, training_config

log = logging.getLogger(__name__)

TRUTH = "truth"  # --restorer value of the oracle restorer
# PdusSchedule fields train-recondreamer sets from flags; also the keyword arguments of
# PdusSchedule.for_iterations, which derives S from T when --update-every is not given.
PDUS_OPTIONS = ("stride", "update_every", "max_offset")
# RestoreConfig fields of the DriveRestorer inside the loop, as --restore-<field>; unset: the checkpoint's.
RESTORE_OPTIONS = ("sample_steps", "strength")
RESTORE_PREFIX = "restore-"


def register(subparsers: argparse._SubParsersAction) -> None:
    recon = subparsers.add_parser(
        "train-recondreamer",
        help="ReconDreamer: train a reconstruction with online DriveRestorer restoration and PDUS",
        description="Train a reconstruction on the original frames; every S steps widen the novel trajectory "
        "by --stride metres (up to --max-offset), render it with the current model, restore it with DriveRestorer "
        "and add it to the training data (Algorithm 1 weights, 50/50 original/novel, depth-free on novel frames). "
        "Writes RUN/model.pt like train-recon, RUN/updates/update_KK/{rendered,restored}/ and RUN/pdus.json; "
        "re-running after a kill resumes.",
    )
    add_training_options(recon)
    recon.add_argument("--restorer", required=True, metavar="CKPT",
                       help="DriveRestorer checkpoint (train-restorer output), or 'truth': an oracle that returns the true "
                       "views of each shifted trajectory (synthetic scenes only; the upper bound of any restorer)")
    add_config_options(recon, PdusSchedule, PDUS_OPTIONS, required=("stride",), title="PDUS schedule (PdusSchedule)",
                       defaults={"update_every": "iterations / 5, i.e. four updates", "max_offset": str(PdusSchedule.max_offset)})
    add_config_options(recon, RestoreConfig, RESTORE_OPTIONS, prefix=RESTORE_PREFIX, defaults={"*": "the restorer checkpoint's"},
                       title="DriveRestorer sampling (RestoreConfig)")
    recon.add_argument("--restorer-device", default=None,
                       help="torch device of DriveRestorer (cpu or cuda; default: the reconstruction's --device)")
    recon.set_defaults(func=run_train_recondreamer)

    dd4d = subparsers.add_parser(
        "train-dd4d",
        help="DriveDreamer4D baseline: generate novel-trajectory videos once, train on original + generated",
        description="Generate shift@3, shift@6 and lane_change videos with the pretrained dd2 world model, then train "
        "the reconstruction on original + generated frames (50/50, depth-free on generated), no updates. Writes "
        "RUN/model.pt like train-recon and RUN/generated/<trajectory>/; re-running after a kill resumes. With "
        "--generated DIR the videos are read from DIR (written once per segment by 'recondreamer dd4d-generate').",
    )
    add_training_options(dd4d)
    dd4d.add_argument("--world-model", metavar="CKPT", help="pretrained dd2 world-model checkpoint (needed unless --generated)")
    dd4d.add_argument("--generated", metavar="DIR",
                      help="read the videos from DIR/<trajectory>/ (frames written by 'recondreamer dd4d-generate' for this "
                      "scene) instead of generating them: the workflow generates once per segment for every backbone")
    dd4d.add_argument("--trajectories", default="shift@3,shift@6,lane_change",
                      help="comma-separated novel trajectories to generate (default: shift@3,shift@6,lane_change)")
    dd4d.add_argument("--generate-steps", type=int, default=None, help="DDIM steps of generation (default: the checkpoint's)")
    dd4d.add_argument("--world-model-device", default=None,
                      help="torch device of the world model while generating (cpu or cuda; default: the reconstruction's --device)")
    dd4d.set_defaults(func=run_train_dd4d)


def run_train_recondreamer(args: argparse.Namespace) -> int:
    from recondreamer.methods.loop import train_recondreamer
    from recondreamer.device import resolve_device
    from recondreamer.generative.inference import load_restorer
    from recondreamer.scene import load_scene
    from recondreamer.sources.synthetic.truth import TrueViewRenderer

    config = training_config(args)
    # Ranges checked on the defaults before anything loads; the values given go to the loop, which
    # lays them over the restorer checkpoint's own RestoreConfig.
    apply_options(args, RestoreConfig(), RESTORE_OPTIONS, prefix=RESTORE_PREFIX)
    given = {name: getattr(args, name) for name in PDUS_OPTIONS if getattr(args, name) is not None}
    with naming_flags():
        schedule = PdusSchedule.for_iterations(iterations=config.iterations, **given)
    scene = load_scene(args.scene)
    if args.restorer == TRUTH:
        restorer, restorer_path = TrueViewRenderer(scene), TRUTH
    else:
        device = resolve_device(args.restorer_device or config.device, "--restorer-device" if args.restorer_device else "--device")
        restorer, restorer_path = load_restorer(args.restorer, device), str(Path(args.restorer).resolve())
    model = train_recondreamer(scene, config, args.out, restorer, schedule, args.restore_sample_steps,
                               restorer_path=restorer_path, restore_strength=args.restore_strength)
    log.info("done: ReconDreamer %s (stride %g m) with %d Gaussians in %s", args.model, schedule.stride,
             len(model.gaussians), args.out)
    return 0


def run_train_dd4d(args: argparse.Namespace) -> int:
    from recondreamer.errors import RecondreamerError
    from recondreamer.methods.dd4d import train_dd4d
    from recondreamer.device import resolve_device
    from recondreamer.generative.inference import load_world_model
    from recondreamer.scene import load_scene

    config = training_config(args)
    trajectories = tuple(name.strip() for name in args.trajectories.split(",") if name.strip())
    if not trajectories:
        raise RecondreamerError("--trajectories: give at least one trajectory name")
    if (args.world_model is None) == (args.generated is None):
        raise RecondreamerError("train-dd4d: give exactly one of --world-model (generate here) and --generated (read videos)")
    scene = load_scene(args.scene)
    world_model = None
    if args.world_model is not None:
        device = resolve_device(args.world_model_device or config.device, "--world-model-device" if args.world_model_device else "--device")
        world_model = load_world_model(args.world_model, device)
        if world_model.arch != "dd2":
            raise RecondreamerError(f"{args.world_model}: DriveDreamer4D needs the dd2 world model, got {world_model.arch!r}")
    model = train_dd4d(scene, config, args.out, world_model, trajectories, args.generate_steps, args.generated)
    log.info("done: DriveDreamer4D %s with %d Gaussians in %s", args.model, len(model.gaussians), args.out)
    return 0
