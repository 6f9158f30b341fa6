"""Sub-commands of the scene format: ``recondreamer validate DIR``."""

from __future__ import annotations

import argparse
import logging

log = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "validate",
        help="check a scene directory against the scene format",
        description="Check a scene directory (docs/scene-format.md): every file present, sizes, "
        "frame counts, finite values, rigid poses, boxes and map polylines. Exits 1 with a "
        "message naming the file and the problem; prints a short summary when the scene is valid.",
    )
    parser.add_argument("scene_dir", metavar="DIR", help="scene directory to check")
    parser.add_argument(
        "--headers-only",
        action="store_true",
        help="only run the checks of load_scene (JSON files and file headers); by default every "
        "image, depth map and LiDAR file is also decoded and its values checked",
    )
    parser.set_defaults(func=run_validate)


def run_validate(args: argparse.Namespace) -> int:
    from recondreamer.scene.format import load_scene

    scene = load_scene(args.scene_dir)
    if not args.headers_only:
        log.info("decoding every frame of %s", args.scene_dir)
        scene.check_all()
    print(scene.summary())
    print("valid" + (" (headers only)" if args.headers_only else ""))
    return 0
