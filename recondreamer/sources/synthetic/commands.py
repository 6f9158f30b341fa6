"""Sub-commands of the synthetic world: ``synth``, ``synth-suite`` and ``preview``."""

from __future__ import annotations

import argparse
import logging

from recondreamer.cli_options import add_config_options
from recondreamer.sources.synthetic.config import PRESETS, SyntheticConfig

log = logging.getLogger(__name__)
SIZE_OPTIONS = ("width", "height", "frames")  # SyntheticConfig fields synth takes as flags over the preset


def register(subparsers: argparse._SubParsersAction) -> None:
    synth = subparsers.add_parser(
        "synth",
        help="render one synthetic driving segment from a seed",
        description="Build the procedural driving world of SEED and render one segment with its own "
        "ray caster: RGB, depth, semantics, instances, sky masks, LiDAR, tracked boxes, HD map and the "
        "true novel views of shift@3, shift@6 and lane_change. Same seed and settings, same bytes.",
    )
    synth.add_argument("--seed", type=int, required=True, help="world seed (non-negative integer)")
    synth.add_argument("--out", required=True, help="scene directory to write (replaced atomically if it exists)")
    synth.add_argument("--preset", default="default", choices=tuple(PRESETS), help="render preset: default = 240x160, 40 frames; compact = 144x96, 24 frames; quick = 96x64, 12 frames (default: default)")
    add_config_options(synth, SyntheticConfig, SIZE_OPTIONS, defaults={"*": "the preset's"}, title="segment size (SyntheticConfig)")
    synth.add_argument("--no-novel", action="store_true", help="skip the true novel views (faster; the scene then has none)")
    synth.add_argument("--scene-id", help="scene id stored in the scene (default: synth-seed<SEED>)")
    synth.set_defaults(func=run_synth)

    suite = subparsers.add_parser(
        "synth-suite",
        help="render the default evaluation segments and the training corpus",
        description="Render every synthetic scene named in the config's 'synthetic:' section: the "
        "evaluation segments to <results_dir>/scenes/<name>/ and the corpus (seeds disjoint from "
        "the segments) to <results_dir>/corpus/<name>/. Scenes already written by this version "
        "from the same seed and preset are kept, so an interrupted run resumes.",
    )
    suite.add_argument("--config", default="config/config.yaml", help="workflow config file, layered over config/config.yaml as the workflow layers it (default: config/config.yaml)")
    suite.add_argument("--only", choices=("segments", "corpus"), help="build only the evaluation segments or only the corpus (default: both)")
    suite.add_argument("--jobs", type=int, default=1, help="scenes rendered in parallel processes (default: 1)")
    suite.add_argument("--force", action="store_true", help="rebuild scenes even when they are already current")
    suite.add_argument("--previews", action="store_true", help="also draw a contact sheet of every evaluation segment to <results_dir>/previews/<name>.png (redrawn only when missing or older than its scene)")
    suite.set_defaults(func=run_synth_suite)

    preview = subparsers.add_parser(
        "preview",
        help="draw a contact sheet of a scene",
        description="Write one picture of a scene directory: for a few frames the RGB frame, depth, "
        "semantics, the 3D boxes and map lines drawn over the frame, and each true novel view "
        "(with its boxes and lines) when the scene has them.",
    )
    preview.add_argument("scene_dir", metavar="DIR", help="scene directory")
    preview.add_argument("--out", required=True, help="image file to write (format from its suffix, e.g. sheet.png)")
    preview.add_argument("--frames", type=int, nargs="+", help="frame indices to show (default: first, middle and last)")
    preview.set_defaults(func=run_preview)


def run_synth(args: argparse.Namespace) -> int:
    from recondreamer.io import check_replaceable
    from recondreamer.scene import write_scene
    from recondreamer.sources.synthetic import generate_segment

    check_replaceable(args.out, "scene")  # before minutes of rendering
    overrides = {name: getattr(args, name) for name in SIZE_OPTIONS}
    if args.no_novel:
        overrides["novel_views"] = False
    data = generate_segment(args.seed, args.preset, scene_id=args.scene_id, **overrides)
    write_scene(args.out, data)
    meta = data.metadata["world"]
    log.info(
        "wrote %s: %d frames %dx%d, %d lanes, %d moving and %d parked vehicles, novel views: %s",
        args.out, data.num_frames, data.width, data.height, meta["num_lanes"], meta["moving_vehicles"], meta["parked_vehicles"], ", ".join(data.novel) or "none",
    )
    return 0


def run_synth_suite(args: argparse.Namespace) -> int:
    from recondreamer.sources.synthetic.suite import run_suite

    from recondreamer.sources.synthetic.suite import write_previews

    built = run_suite(args.config, only=args.only, jobs=args.jobs, force=args.force)
    log.info("synthetic suite done: %d scene(s) built", len(built))
    if args.previews:
        for sheet in write_previews(args.config):
            log.info("preview: %s", sheet)
    return 0


def run_preview(args: argparse.Namespace) -> int:
    from recondreamer.sources.synthetic.preview import contact_sheet

    out = contact_sheet(args.scene_dir, args.out, frames=args.frames)
    log.info("wrote %s", out)
    return 0
