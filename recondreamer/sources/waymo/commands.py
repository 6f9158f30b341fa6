"""Sub-commands ``recondreamer convert-waymo`` (a Waymo segment to a scene directory) and
``export-waymo`` (a synthetic scene to a Waymo segment file, to run the real-data path on known truth)."""

from __future__ import annotations

import argparse
import logging

log = logging.getLogger(__name__)


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "convert-waymo",
        help="convert a Waymo Open Dataset v1 segment (.tfrecord) into a scene directory",
        description="Stream a Waymo Open Dataset v1 segment (no TensorFlow needed) and write one camera's "
        "frames, calibration, ego poses, tracked 3D boxes, TOP LiDAR points and map polylines as a scene "
        "directory (JPEGs kept as they are). The world frame is the ego frame of the first selected frame.",
    )
    parser.add_argument("tfrecord", metavar="SEGMENT.tfrecord", help="Waymo Open Dataset v1 segment file")
    parser.add_argument("--out", required=True, metavar="DIR", help="scene directory to write (replaced atomically)")
    parser.add_argument(
        "--start", type=int, default=None, help="first frame index to convert, 0-based (default: 0)"
    )
    parser.add_argument(
        "--end", type=int, default=None, help="last frame index to convert, inclusive (default: the last frame)"
    )
    parser.add_argument(
        "--camera",
        default="FRONT",
        choices=["FRONT", "FRONT_LEFT", "FRONT_RIGHT", "SIDE_LEFT", "SIDE_RIGHT"],
        help="which camera to convert (default: FRONT)",
    )
    parser.set_defaults(func=_convert)

    parser = subparsers.add_parser(
        "export-waymo",
        help="write a synthetic scene as a Waymo Open Dataset v1 segment (.tfrecord)",
        description="Write a synthetic scene's camera frames (JPEG), calibration, poses, 3D boxes, LiDAR (as a TOP "
        "range image) and map as a Waymo Open Dataset v1 segment, so that convert-waymo and the workflow's "
        "'source: waymo' path can run on scenes whose truth is known.",
    )
    parser.add_argument("scene", metavar="SCENE_DIR", help="a scene written by 'recondreamer synth'")
    parser.add_argument("--out", required=True, metavar="FILE.tfrecord", help="segment file to write (replaced atomically)")
    parser.set_defaults(func=_export)


def _convert(args: argparse.Namespace) -> int:
    from recondreamer.sources.waymo.convert import convert_waymo

    out = convert_waymo(args.tfrecord, args.out, start=args.start, end=args.end, camera=args.camera)
    log.info("wrote %s", out)
    return 0


def _export(args: argparse.Namespace) -> int:
    from recondreamer.sources.waymo.export import export_waymo

    out = export_waymo(args.scene, args.out)
    log.info("wrote %s", out)
    return 0
