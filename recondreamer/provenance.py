"""Where a file came from: the command line that produced it (recorded by ``cli.main`` and stored
in every model file) and the code version, which a weight set's manifest names for each file."""

from __future__ import annotations

import shlex
import subprocess
from pathlib import Path

_argv: list[str] | None = None


def record_command(argv: list[str]) -> None:
    """Remember the arguments of the running ``recondreamer`` command (without the program name)."""
    global _argv
    _argv = list(argv)


def command_line() -> str | None:
    """``recondreamer ARGS...`` of the running command, or None outside the command line (library use)."""
    return None if _argv is None else shlex.join(["recondreamer", *_argv])


def code_version() -> str:
    """The git commit of the code (with '+changes' when the package's code differs from it; the shipped
    weight set itself is not code), else the package version."""
    from recondreamer import __version__

    root = Path(__file__).resolve().parents[1]
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "recondreamer", ":(exclude)recondreamer/weights"], cwd=root, capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return __version__
    return commit + ("+changes" if dirty else "")
