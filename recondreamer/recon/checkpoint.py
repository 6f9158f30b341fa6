"""Self-describing checkpoints, snapshots and final models of reconstruction runs.

Every file is a ``torch.save`` dict with ``format``, ``format_version``, ``kind``
("checkpoint" for resume, "snapshot" for a training-stage model, "model" for the final one),
``model_type``, ``scene_id``, ``config``, ``model_spec`` (what rebuilds the module) and
``model_state``; checkpoints add optimiser, density-control and random-generator states.
Files are written atomically. Run directory layout::

    RUN/checkpoint.pt  RUN/model.pt  RUN/snapshots/step_{N:06d}.pt  RUN/train.log  RUN/run.json
"""

from __future__ import annotations

from pathlib import Path

import torch

from recondreamer.errors import CheckpointError
from recondreamer.io import atomic_path
from recondreamer.recon.base import GaussianSceneModel
from recondreamer.configs import from_dict, to_dict
from recondreamer.recon.config import ReconConfig
from recondreamer.recon.models import MODEL_CLASSES

FORMAT = "recondreamer.recon"
FORMAT_VERSION = 1
KINDS = ("checkpoint", "snapshot", "model")
CHECKPOINT_NAME = "checkpoint.pt"
MODEL_NAME = "model.pt"
SNAPSHOT_DIR = "snapshots"
RUN_JSON = "run.json"
TRAIN_LOG = "train.log"


def snapshot_path(run_dir: Path, step: int) -> Path:
    return Path(run_dir) / SNAPSHOT_DIR / f"step_{step:06d}.pt"


def model_record(
    kind: str,
    model: GaussianSceneModel,
    config: ReconConfig,
    step: int,
    scene_path: str | None,
) -> dict:
    """The self-describing part shared by every kind of file."""
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "kind": kind,
        "model_type": model.model_type,
        "scene_id": model.spec().get("scene_id", ""),
        "scene_path": scene_path,
        "step": int(step),
        "config": to_dict(config),
        "model_spec": model.spec(),
        "model_state": model.state_dict(),
    }


def save_record(path: Path, record: dict) -> None:
    """Write atomically: a killed process leaves the previous file intact."""
    with atomic_path(path) as tmp:
        torch.save(record, tmp)


def read_record(path: str | Path) -> dict:
    """Load and check a reconstruction file; CheckpointError naming the file on any problem."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: no such checkpoint file")
    try:
        record = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # a truncated or foreign file: say which one
        raise CheckpointError(
            f"{path}: not a readable torch checkpoint ({error})"
        ) from error
    if not isinstance(record, dict) or record.get("format") != FORMAT:
        raise CheckpointError(
            f"{path}: not a recondreamer reconstruction file (format {record.get('format') if isinstance(record, dict) else None!r})"
        )
    if record.get("format_version") != FORMAT_VERSION:
        raise CheckpointError(
            f"{path}: unknown format version {record.get('format_version')!r} (this code reads {FORMAT_VERSION})"
        )
    if record.get("model_type") not in MODEL_CLASSES:
        raise CheckpointError(
            f"{path}: unknown model type {record.get('model_type')!r}"
        )
    return record


def model_from_record(record: dict) -> GaussianSceneModel:
    config = from_dict(ReconConfig, record["config"])
    model = MODEL_CLASSES[record["model_type"]](record["model_spec"], config.net)
    model.load_state_dict(record["model_state"])
    model.eval()
    return model


def resolve_model_path(path: str | Path) -> Path:
    """A run directory means its final model, else its latest checkpoint; files are taken as given."""
    path = Path(path)
    if path.is_dir():
        for name in (MODEL_NAME, CHECKPOINT_NAME):
            if (path / name).is_file():
                return path / name
        raise CheckpointError(
            f"{path}: run directory has neither {MODEL_NAME} nor {CHECKPOINT_NAME}"
        )
    return path


def load_model(path: str | Path) -> GaussianSceneModel:
    """The model of a run directory, ``model.pt``, a snapshot or a checkpoint, ready to render."""
    return model_from_record(read_record(resolve_model_path(path)))
