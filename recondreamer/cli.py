"""The ``recondreamer`` command line: one sub-command per workflow step.

Each stage's package owns its sub-commands in a ``commands.py`` module exposing
``register(subparsers)``; this file only collects them. Sub-command handlers import
their heavy dependencies (torch, ...) lazily so that ``--help`` stays instant.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from recondreamer import __version__
from recondreamer.errors import RecondreamerError
from recondreamer.provenance import record_command

# Stage order = the order sub-commands are listed in ``recondreamer --help``.
COMMAND_MODULES = (
    "recondreamer.scene.commands",
    "recondreamer.sources.waymo.commands",
    "recondreamer.sources.synthetic.commands",
    "recondreamer.recon.commands",
    "recondreamer.generative.commands",
    "recondreamer.methods.commands",
    "recondreamer.evaluation.commands",
    "recondreamer.foundation.commands",
    "recondreamer.report.commands",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="recondreamer",
        description="ReconDreamer experiment system: every workflow step as a sub-command. "
        "Run 'recondreamer COMMAND --help' for a command's options.",
    )
    parser.add_argument("--version", action="version", version=f"recondreamer {__version__}")
    parser.add_argument(
        "--log-level",
        default="INFO",
        choices=["DEBUG", "INFO", "WARNING", "ERROR"],
        help="verbosity of progress messages on stderr (default: INFO)",
    )
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module_name in COMMAND_MODULES:
        importlib.import_module(module_name).register(subparsers)
    return parser


def check_common_arguments(args: argparse.Namespace) -> None:
    """Options many sub-commands share, checked in one place: torch's thread count must be
    positive (0 or a negative number would mean 'all cores' or crash inside torch) and seeds
    non-negative (numpy's generators refuse negative seeds)."""
    threads = getattr(args, "threads", None)
    if threads is not None and threads < 1:
        raise RecondreamerError(f"--threads {threads}: must be a positive integer")
    seed = getattr(args, "seed", None)
    if isinstance(seed, int) and seed < 0:
        raise RecondreamerError(f"--seed {seed}: must be a non-negative integer")


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    record_command(sys.argv[1:] if argv is None else argv)
    logging.basicConfig(
        level=getattr(logging, args.log_level),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        datefmt="%H:%M:%S",
    )
    try:
        check_common_arguments(args)
        return int(args.func(args) or 0)
    except RecondreamerError as error:
        print(f"recondreamer {args.command}: error: {error}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
