"""Sub-commands of the foundation stage: ``foundation-gates``, ``weights verify``, ``weights publish``."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

log = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "foundation-gates",
        help="the foundation models' gates on gate scenes no model saw (JSON and GATES.md)",
        description="Restore the gate scenes' renders with every DriveRestorer (novel trajectories: the final Street "
        "Gaussians model; original: under-trained snapshots), measure the autoencoder on the gate scenes' frames and the "
        "evaluation models on their labelled frames, and write OUT (JSON) and OUT's sibling GATES.md.",
    )
    p.add_argument("--restorer", nargs="+", required=True, metavar="ARCH=FILE", help="DriveRestorer checkpoints")
    p.add_argument("--pairs", nargs="+", required=True, type=Path, help="gate scenes' pairs directories (make-pairs --trajectories original shift@3 shift@6)")
    p.add_argument("--autoencoder", required=True, type=Path, help="autoencoder checkpoint")
    p.add_argument("--gate-scenes", nargs="+", required=True, type=Path, help="gate scene directories")
    p.add_argument("--eval-metrics", required=True, type=Path, help="metrics.json written by train-eval-models")
    p.add_argument("--detector", required=True, type=Path, help="vehicle detector written by train-eval-models")
    p.add_argument("--lane-model", required=True, type=Path, help="lane segmenter written by train-eval-models")
    p.add_argument("--gate-seeds", nargs="+", required=True, type=int, help="world seeds of the gate scenes (for the report)")
    p.add_argument("--corpus-seeds", nargs=2, required=True, type=int, metavar=("FIRST", "LAST"), help="first and last corpus seed")
    p.add_argument("--out", required=True, type=Path, help="gates JSON to write (GATES.md is written beside it)")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    p.set_defaults(func=run_foundation_gates)

    p = subparsers.add_parser("weights", help="check or assemble a weight set (model files + manifest.json)")
    sub = p.add_subparsers(dest="weights_command", required=True, metavar="ACTION")
    v = sub.add_parser(
        "verify",
        help="check every file of a weight set against its manifest",
        description="Check that every file the manifest of DIR lists is present, has the manifest's sha256 and loads with "
        "this code as the manifest's kind and arch. Exit 0 and a summary, or 1 and every problem.",
    )
    v.add_argument("dir", nargs="?", type=Path, default=None, help="weight-set folder (default: the set shipped with the project)")
    v.set_defaults(func=run_verify)
    b = sub.add_parser(
        "publish",
        help="copy trained models into a weight-set folder and write its manifest",
        description="Copy each NAME=FILE into OUT (NAME a weight-set file name, e.g. restorer_dd2_mask.pt), then write "
        "OUT/manifest.json (sha256, kind, architecture config, the command and budget each file records, gate numbers) "
        "and OUT/GATES.md. The manifest is written last: a set without one is incomplete.",
    )
    b.add_argument("files", nargs="+", metavar="NAME=FILE", help="weight-set file name and the trained file")
    b.add_argument("--gates", required=True, type=Path, help="gates JSON written by foundation-gates")
    b.add_argument("--corpus-preset", required=True, help="render preset of the corpus (the models' frame size)")
    b.add_argument("--out", required=True, type=Path, help="weight-set folder to write")
    b.set_defaults(func=run_publish)


def run_foundation_gates(args: argparse.Namespace) -> int:
    import torch

    from recondreamer.errors import RecondreamerError
    from recondreamer.foundation import gates as foundation_gates
    from recondreamer.io import write_json_atomic, write_text_atomic
    from recondreamer.report.notes import restorer_recipe
    from recondreamer.generative.checkpoint import load_checkpoint
    from recondreamer.generative.data import find_pairs_files

    if args.threads:
        torch.set_num_threads(args.threads)
    pair_files = find_pairs_files(args.pairs)
    paths = {}
    for item in args.restorer:
        arch, sep, path = item.partition("=")
        if not sep:
            raise RecondreamerError(f"--restorer {item!r}: expected ARCH=FILE")
        paths[arch] = Path(path)
    restorers = {arch: foundation_gates.restorer_gate(path, pair_files) for arch, path in paths.items()}
    recipe = restorer_recipe(load_checkpoint(paths.get(foundation_gates.GATED_RESTORER, next(iter(paths.values()))), "restorer"))
    result = {
        "gate_seeds": args.gate_seeds,
        "corpus_seeds": args.corpus_seeds,
        "restorers": restorers,
        "autoencoder": foundation_gates.autoencoder_gate(args.autoencoder, args.gate_scenes),
        "eval_models": foundation_gates.eval_model_gates(args.eval_metrics, args.detector, args.lane_model, args.gate_scenes),
        "recipe": recipe or ["none"],
    }
    write_json_atomic(args.out, result)
    write_text_atomic(args.out.with_name("GATES.md"), foundation_gates.gate_report(result))
    log.info("wrote %s and %s", args.out, args.out.with_name("GATES.md"))
    return 0


def run_verify(args: argparse.Namespace) -> int:
    from recondreamer.foundation.weights import shipped_weights_dir, verify_weight_set

    folder = args.dir or shipped_weights_dir()
    manifest = verify_weight_set(folder)
    total = sum(entry["bytes"] for entry in manifest["files"].values())
    print(f"{folder}: {len(manifest['files'])} files verified ({total / 2**20:.1f} MiB), code version {manifest.get('code_version')}")
    return 0


def run_publish(args: argparse.Namespace) -> int:
    import json

    from recondreamer.errors import RecondreamerError
    from recondreamer.foundation.weights import BY_NAME, WeightsError, publish_weight_set

    files = {}
    for item in args.files:
        name, sep, path = item.partition("=")
        if not sep or name not in BY_NAME:
            raise RecondreamerError(f"{item!r}: expected NAME=FILE with NAME one of {', '.join(BY_NAME)}")
        files[name] = Path(path)
    try:
        manifest = publish_weight_set(files, json.loads(args.gates.read_text()), args.corpus_preset, args.out)
    except WeightsError as error:
        raise WeightsError(f"{args.gates}: {error}") from error
    total = sum(entry["bytes"] for entry in manifest["files"].values())
    log.info("wrote %s: %d files, %.1f MiB", args.out / "manifest.json", len(files), total / 2**20)
    return 0
