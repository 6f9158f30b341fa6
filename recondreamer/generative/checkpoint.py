"""Self-describing checkpoints of the generative stack, written atomically.

Every file is a dict ``{"format": FORMAT, "format_version", "kind", "arch", "config", "state",
...}``. Kinds: ``autoencoder``, ``world_model`` (a pretrained sd/svd/dd2 model, embedding its
autoencoder), ``restorer`` (a fine-tuned world model, embedding its autoencoder) and
``training_state`` (the resume file of an unfinished job). Loading checks the format and the
kind and raises ``CheckpointError`` naming the file otherwise.
"""

from __future__ import annotations

import os
from pathlib import Path

import torch

from recondreamer.errors import CheckpointError
from recondreamer.io import atomic_path
from recondreamer.provenance import command_line
from recondreamer.device import tensors_to_cpu

FORMAT = "recondreamer.restorer"  # the format tag every generative-stack checkpoint carries (the shipped weight set included)
FORMAT_VERSION = 1
KINDS = ("autoencoder", "world_model", "restorer", "training_state")


def save_checkpoint(path: str | os.PathLike, kind: str, arch: str, config: dict, state: dict, **extra) -> None:
    """Write a checkpoint atomically (temporary file, then rename), every tensor on the CPU."""
    if kind not in KINDS:
        raise ValueError(f"unknown checkpoint kind {kind!r}")
    payload = {"format": FORMAT, "format_version": FORMAT_VERSION, "kind": kind, "arch": arch, "config": config, "state": state}
    payload["command"] = command_line()  # the weight set's manifest names it
    payload.update(extra)
    payload = tensors_to_cpu(payload)  # a job trained on a GPU writes a file any machine loads
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)


def load_checkpoint(path: str | os.PathLike, kind: str | tuple[str, ...]) -> dict:
    """Read a checkpoint and check that it is one of ``kind``; clear errors otherwise."""
    path = Path(path)
    kinds = (kind,) if isinstance(kind, str) else tuple(kind)
    if not path.is_file():
        raise CheckpointError(f"{path}: checkpoint file does not exist")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as error:  # torch raises many types for a corrupt or foreign file
        raise CheckpointError(f"{path}: not a readable torch checkpoint ({error})") from error
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise CheckpointError(f"{path}: not a recondreamer restorer-stack checkpoint (expected one of kinds {', '.join(kinds)})")
    if payload.get("format_version") != FORMAT_VERSION:
        raise CheckpointError(f"{path}: checkpoint format version {payload.get('format_version')} is not supported (this code reads {FORMAT_VERSION})")
    if payload.get("kind") not in kinds:
        raise CheckpointError(f"{path}: checkpoint kind is {payload.get('kind')!r}, expected {' or '.join(repr(k) for k in kinds)}")
    return payload
