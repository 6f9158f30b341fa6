"""Sub-commands of the reconstruction stage: ``train-recon`` and ``render``."""

from __future__ import annotations

import argparse
import logging

from recondreamer.cli_options import add_config_options, apply_options
from recondreamer.recon.config import MODEL_TYPES, PRESETS, ReconConfig, make_config

TRAIN_OPTIONS = ("iterations", "seed", "backend", "device")  # ReconConfig fields train-recon sets from flags

log = logging.getLogger(__name__)


def add_training_options(parser: argparse.ArgumentParser) -> None:
    """The options of every command that trains a reconstruction (train-recon, train-recondreamer, train-dd4d)."""
    parser.add_argument("--scene", required=True, metavar="DIR", help="scene directory (docs/scene-format.md)")
    parser.add_argument("--model", required=True, choices=MODEL_TYPES, help="reconstruction backbone")
    parser.add_argument("--out", required=True, metavar="RUN", help="run directory to create or resume")
    parser.add_argument("--preset", default="default", choices=PRESETS,
                        help="size preset: quick (tests), default (CPU, synthetic scenes), paper (GPU, 50k iterations)")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    parser.add_argument("--deterministic", action="store_true",
                        help="turn on torch.use_deterministic_algorithms (warn-only), for CUDA runs: CPU runs are "
                        "bit-identical run to run without it, and CUDA runs are not even with it (gsplat's backward "
                        "pass adds gradients atomically); run.json says what a run promises")
    add_config_options(parser, ReconConfig, TRAIN_OPTIONS, defaults=make_config(MODEL_TYPES[0], "default"),
                       title="training (ReconConfig; defaults shown for --preset default)")


def training_config(args: argparse.Namespace) -> ReconConfig:
    """The reconstruction config the options of ``add_training_options`` ask for, its device checked
    (a clear error before any work when CUDA is missing); sets the torch thread count and, with
    ``--deterministic``, torch's deterministic mode."""
    import torch

    from recondreamer.device import resolve_device
    from recondreamer.recon.reproducibility import use_deterministic_algorithms

    if args.threads:
        torch.set_num_threads(args.threads)
    if args.deterministic:
        use_deterministic_algorithms()
    config = apply_options(args, make_config(args.model, args.preset), TRAIN_OPTIONS)
    resolve_device(config.device, "--device")
    return config


def register(subparsers: argparse._SubParsersAction) -> None:
    train = subparsers.add_parser(
        "train-recon",
        help="train a Gaussian-splatting reconstruction (street, pvg, deformable, s3) of one scene",
        description="Train one reconstruction backbone on a scene directory. The run directory gets "
        "checkpoint.pt (resume), model.pt (final), snapshots/step_N.pt, train.log and run.json; "
        "re-running the same command after a kill resumes from the last checkpoint.",
    )
    add_training_options(train)
    train.set_defaults(func=run_train)

    render = subparsers.add_parser(
        "render",
        help="render a trained reconstruction along a trajectory",
        description="Render every frame of a trajectory (camera of frame t at the time of frame t) "
        "into DIR/{t:03d}.png and DIR/{t:03d}_depth.npy (expected depth, metres); DIR is written "
        "atomically.",
    )
    render.add_argument(
        "--run", required=True, metavar="RUN", help="run directory of train-recon"
    )
    render.add_argument(
        "--trajectory",
        default="original",
        help="original, shift@Y (Y metres to the left), lane_change or file:PATH (T,4,4 poses)",
    )
    render.add_argument(
        "--out", required=True, metavar="DIR", help="output directory of the frames"
    )
    render.add_argument(
        "--checkpoint",
        default=None,
        metavar="FILE",
        help="model file to render instead of RUN/model.pt (a snapshot or checkpoint)",
    )
    render.add_argument(
        "--scene",
        default=None,
        metavar="DIR",
        help="scene directory (default: the one recorded in the run)",
    )
    render.add_argument(
        "--device",
        default="cpu",
        help="torch device to render on, e.g. cpu or cuda (cuda uses the gsplat backend; default cpu)",
    )
    render.add_argument(
        "--threads",
        type=int,
        default=None,
        help="torch CPU threads (default: torch's choice)",
    )
    render.set_defaults(func=run_render)


def run_train(args: argparse.Namespace) -> int:
    from recondreamer.recon.trainer import train_scene
    from recondreamer.scene import load_scene

    config = training_config(args)
    scene = load_scene(args.scene)
    model = train_scene(scene, config, args.out)
    log.info(
        "done: %s with %d Gaussians in %s", args.model, len(model.gaussians), args.out
    )
    return 0


def run_render(args: argparse.Namespace) -> int:
    import json
    from pathlib import Path

    import torch

    from recondreamer.errors import RecondreamerError
    from recondreamer.io import check_replaceable
    from recondreamer.recon.checkpoint import RUN_JSON, load_model
    from recondreamer.recon.render import render_to_directories
    from recondreamer.device import resolve_device
    from recondreamer.scene import load_scene

    check_replaceable(args.out, "renders")
    if args.threads:
        torch.set_num_threads(args.threads)
    device = resolve_device(args.device, "--device")
    model = load_model(args.checkpoint or args.run).to(device)
    scene_dir = args.scene
    if scene_dir is None:
        run_json = Path(args.run) / RUN_JSON
        if not run_json.is_file():
            raise RecondreamerError(f"{run_json}: missing; pass --scene DIR")
        scene_dir = json.loads(run_json.read_text()).get("scene_path")
        if not scene_dir:
            raise RecondreamerError(
                f"{run_json}: records no scene path; pass --scene DIR"
            )
    render_to_directories(model, load_scene(scene_dir), [(args.trajectory, args.out)])
    return 0
