"""Weight sets: the foundation models an experiment run starts from, with their manifest.

A weight set is a folder of model files and ``manifest.json``. The manifest lists, for every
file, its sha256, what it is, its architecture config, the exact command and budget that trained
it, and its gate numbers; for the set, the corpus seeds it was trained on, the seeds of the gate
scenes and the code version. The project ships one set (``weights/`` in the repository,
installed as the package data ``recondreamer.weights``); ``config/foundation.yaml`` builds one;
a user may bring their own in the same format.

Before a run uses a set, ``verify_weight_set`` checks each needed file: present, of the
manifest's hash, and loadable by this code as the manifest's kind and arch. Every failure names
the file and what is wrong.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Iterable
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from recondreamer.errors import RecondreamerError

MANIFEST = "manifest.json"
GATE_REPORT = "GATES.md"
MANIFEST_FORMAT = "recondreamer.weights"
MANIFEST_VERSION = 1


class WeightsError(RecondreamerError):
    """A weight set is incomplete, altered, or holds a file this code cannot load."""


@dataclass(frozen=True)
class WeightFile:
    """One model of a weight set."""

    name: str  # file name inside the set
    kind: str  # autoencoder | world_model | restorer | vehicle_detector | lane_segmenter | fid_features
    arch: str | None  # generative models' backbone (sd, svd, dd2, dd2_mask)
    what: str


WEIGHT_FILES: tuple[WeightFile, ...] = (
    WeightFile("autoencoder.pt", "autoencoder", None, "latent autoencoder every generative model works in"),
    WeightFile("world_model_sd.pt", "world_model", "sd", "image world model, stand-in for Stable Diffusion"),
    WeightFile("world_model_svd.pt", "world_model", "svd", "video world model, stand-in for Stable Video Diffusion"),
    WeightFile("world_model_dd2.pt", "world_model", "dd2", "video world model conditioned on 3D boxes and HD map, stand-in for DriveDreamer-2 (DriveDreamer4D's generator)"),
    WeightFile("restorer_sd.pt", "restorer", "sd", "DriveRestorer fine-tuned from the sd world model"),
    WeightFile("restorer_svd.pt", "restorer", "svd", "DriveRestorer fine-tuned from the svd world model"),
    WeightFile("restorer_dd2.pt", "restorer", "dd2", "DriveRestorer fine-tuned from the dd2 world model"),
    WeightFile("restorer_dd2_mask.pt", "restorer", "dd2_mask", "DriveRestorer fine-tuned from the dd2 world model with masks (the paper's)"),
    WeightFile("vehicle_detector.pt", "vehicle_detector", None, "vehicle detector of NTA-IoU, stand-in for YOLO11"),
    WeightFile("lane_segmenter.pt", "lane_segmenter", None, "lane segmenter of NTL-IoU, stand-in for TwinLiteNet"),
    WeightFile("fid_features.pt", "fid_features", None, "FID/KID feature network, stand-in for InceptionV3"),
)
BY_NAME = {f.name: f for f in WEIGHT_FILES}


def weight_file(kind: str, arch: str | None = None) -> WeightFile:
    """The set's file of a kind (and arch)."""
    for spec in WEIGHT_FILES:
        if spec.kind == kind and spec.arch == arch:
            return spec
    raise KeyError(f"no weight file of kind {kind!r} and arch {arch!r}")


def shipped_weights_dir() -> Path:
    """The weight set shipped with the project (the repository's ``weights/``, package ``recondreamer.weights``)."""
    return Path(str(resources.files("recondreamer.weights")))


def sha256_file(path: str | os.PathLike) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for chunk in iter(lambda: handle.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def read_manifest(folder: str | os.PathLike) -> dict:
    """The manifest of a weight set, its format checked."""
    path = Path(folder) / MANIFEST
    if not path.is_file():
        hint = " (build a set with: snakemake --cores 2 --configfile config/foundation.yaml)" if Path(folder).is_dir() else " (the folder does not exist)"
        raise WeightsError(f"{path}: weight-set manifest not found{hint}")
    try:
        manifest = json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise WeightsError(f"{path}: not a readable JSON manifest ({error})") from None
    if not isinstance(manifest, dict) or manifest.get("format") != MANIFEST_FORMAT:
        raise WeightsError(f"{path}: not a recondreamer weight-set manifest (format {MANIFEST_FORMAT!r} expected)")
    if manifest.get("format_version") != MANIFEST_VERSION:
        raise WeightsError(f"{path}: manifest format version {manifest.get('format_version')!r} is not supported (this code reads {MANIFEST_VERSION})")
    if not isinstance(manifest.get("files"), dict):
        raise WeightsError(f"{path}: manifest has no 'files' mapping")
    return manifest


def load_weight(path: Path, spec: WeightFile):
    """Load one file as its kind (and arch) with this code's architectures; WeightsError otherwise."""
    try:
        if spec.kind == "autoencoder":
            from recondreamer.generative.models import load_autoencoder

            return load_autoencoder(path)[0]
        if spec.kind in ("world_model", "restorer"):
            from recondreamer.generative.models import load_generative_model

            model = load_generative_model(path, spec.kind)
            if model.arch != spec.arch:
                raise WeightsError(f"{path}: holds a {model.arch!r} {spec.kind}, the set's {spec.name} must be {spec.arch!r}")
            return model
        from recondreamer.evaluation import inference

        if spec.kind == "fid_features":
            return inference.load_fid_model(path)
        return inference.load_model(path, spec.kind)
    except WeightsError:
        raise
    except Exception as error:  # noqa: BLE001 - CheckpointError, or torch's RuntimeError for a state dict of another architecture
        details = " ".join(str(error).split())
        raise WeightsError(f"{path}: an architecture this code cannot load as {spec.kind} {spec.arch or ''} ({details[:400]})".replace(" )", ")")) from None


def verify_weight_set(folder: str | os.PathLike, names: Iterable[str] | None = None, load: bool = True) -> dict:
    """Check the files ``names`` (default: every file of the manifest) of a weight set; returns the manifest.

    Each must be listed in the manifest, present, of the manifest's sha256 and (with ``load``)
    loadable by this code as the manifest's kind and arch. Raises WeightsError listing every problem.
    """
    folder = Path(folder)
    manifest = read_manifest(folder)
    names = list(manifest["files"]) if names is None else list(names)
    problems = []
    for name in names:
        path = folder / name
        entry = manifest["files"].get(name)
        if entry is None:
            problems.append(f"{path}: not listed in {folder / MANIFEST}")
            continue
        spec = BY_NAME.get(name)
        if spec is None:
            problems.append(f"{path}: not a file of a weight set (known: {', '.join(BY_NAME)})")
            continue
        if (entry.get("kind"), entry.get("arch")) != (spec.kind, spec.arch):
            problems.append(f"{path}: manifest says kind {entry.get('kind')!r} arch {entry.get('arch')!r}, expected {spec.kind!r} {spec.arch!r}")
            continue
        if not path.is_file():
            problems.append(f"{path}: missing (the manifest lists it)")
            continue
        digest = sha256_file(path)
        if digest != entry.get("sha256"):
            problems.append(f"{path}: altered: sha256 {digest[:16]}... differs from the manifest's {str(entry.get('sha256'))[:16]}...")
            continue
        if load:
            try:
                load_weight(path, spec)
            except WeightsError as error:
                problems.append(str(error))
    if problems:
        raise WeightsError(f"weight set {folder}: " + ("; ".join(problems) if len(problems) == 1 else "\n  - " + "\n  - ".join(problems)))
    return manifest


def manifest_entry(path: Path, spec: WeightFile, gates: dict | None) -> dict:
    """A file's manifest entry, read from the file itself (config, command, training budget)."""
    import torch

    payload = torch.load(path, map_location="cpu", weights_only=False)
    if spec.kind in ("autoencoder", "world_model", "restorer"):
        config = payload.get("config", {})
        training = payload.get("metrics", {})
        if spec.kind != "autoencoder":
            training = {k: v for k, v in training.items() if not isinstance(v, (list, dict))}
    else:
        config = payload.get("config", {})
        training = payload.get("training", {})
    return {
        "sha256": sha256_file(path),
        "bytes": path.stat().st_size,
        "kind": spec.kind,
        "arch": spec.arch,
        "what": spec.what,
        "config": config,
        "command": payload.get("command"),
        "training": _jsonable(training),
        "gates": gates or {},
    }


def publish_weight_set(files: dict[str, Path], gates: dict, corpus_preset: str, out: str | os.PathLike) -> dict:
    """Copy ``files`` (weight-set name -> trained file) into ``out`` and write GATES.md and the
    manifest; the manifest last (and any old one removed first), so a set without one is incomplete.
    A file already in ``out`` with the same content is left as it is, its modification time too,
    so that republishing one retrained model does not make Snakemake rerun every run of the others."""
    import filecmp
    import shutil

    from recondreamer.foundation.gates import file_gates, gate_report
    from recondreamer.io import atomic_path, write_json_atomic, write_text_atomic
    from recondreamer.provenance import code_version

    out = Path(out)
    evaluation = gates.get("eval_models", {})
    missing = [f"eval_models.{kind}.{key}" for kind in ("vehicle_detector", "lane_segmenter") for key in ("scenes", "heldout_corpus")
               if key not in evaluation.get(kind, {})]
    if missing:
        raise WeightsError(f"the gates document lacks {', '.join(missing)}: it was written by an older foundation-gates; run that rule again")
    for name, source in files.items():
        if name not in BY_NAME:
            raise WeightsError(f"{name}: not a file of a weight set (known: {', '.join(BY_NAME)})")
        if not Path(source).is_file():
            raise WeightsError(f"{source}: file not found (for {name})")
    out.mkdir(parents=True, exist_ok=True)
    (out / MANIFEST).unlink(missing_ok=True)
    entries = {}
    for name, source in files.items():
        spec = BY_NAME[name]
        if not ((out / name).is_file() and filecmp.cmp(source, out / name, shallow=False)):
            with atomic_path(out / name) as tmp:
                shutil.copyfile(source, tmp)
        entries[name] = manifest_entry(out / name, spec, file_gates(spec, gates))
    manifest = {
        "format": MANIFEST_FORMAT,
        "format_version": MANIFEST_VERSION,
        "code_version": code_version(),
        "corpus": {"seeds": gates["corpus_seeds"], "preset": corpus_preset},
        "gate_scenes": {"seeds": gates["gate_seeds"]},
        "recipe": gates["recipe"],
        "files": entries,
    }
    write_text_atomic(out / GATE_REPORT, gate_report(gates))
    write_json_atomic(out / MANIFEST, manifest)
    return manifest


def _jsonable(value):
    """Plain JSON values of a training record (tensors and arrays become lists or are dropped)."""
    try:
        return json.loads(json.dumps(value, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))
    except (TypeError, ValueError):
        return str(value)
