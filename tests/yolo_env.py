"""The YOLO environment of the system tier (tests/test_eval_yolo.py), built by .ci/run.

ultralytics needs torchvision, and no torchvision imports beside the project's pinned CPU torch
2.13.0 (PyPI's wheels fail with "operator torchvision::nms does not exist"); torch 2.14.1 with
torchvision 0.29.1 does. So the adapter is checked in a venv of its own: that pair, ultralytics
and the project's other dependencies (about 1.5 min and 6 GB to build), in
``~/.cache/recondreamer/yolo-venv`` or the folder ``RECONDREAMER_YOLO_VENV`` names.

    python3 tests/yolo_env.py     # builds it (or leaves an up-to-date one alone); prints its python

The tests never build it: without it they fail, naming this command.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# The torch / torchvision pair that imports on these CPU machines, with ultralytics.
YOLO_STACK = ["torch==2.14.1", "torchvision==0.29.1", "ultralytics>=8.3"]
BUILD_COMMAND = "python3 tests/yolo_env.py"


def venv_path() -> Path:
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return Path(os.environ.get("RECONDREAMER_YOLO_VENV") or cache / "recondreamer" / "yolo-venv")


def requirements() -> list[str]:
    """The YOLO stack and the project's dependencies but its pinned torch."""
    dependencies = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    return YOLO_STACK + [d for d in dependencies if not d.replace(" ", "").startswith("torch==")]


def _marker(venv: Path) -> Path:
    return venv / "recondreamer-requirements.json"


def built_python() -> Path | None:
    """The venv's python when the venv holds today's requirements, else None."""
    venv = venv_path()
    marker = _marker(venv)
    if marker.is_file() and json.loads(marker.read_text()) == requirements() and (venv / "bin" / "python").is_file():
        return venv / "bin" / "python"
    return None


def build() -> Path:
    """Builds the venv unless an up-to-date one is there; returns its python."""
    found = built_python()
    if found is not None:
        return found
    venv = venv_path()
    shutil.rmtree(venv, ignore_errors=True)
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    subprocess.run([str(venv / "bin" / "python"), "-m", "pip", "install", "-q", *requirements()], check=True, timeout=1800)
    _marker(venv).write_text(json.dumps(requirements()))  # last: a broken install is rebuilt next time
    return venv / "bin" / "python"


if __name__ == "__main__":
    print(build())
