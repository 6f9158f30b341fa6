"""Issue 7's gate: baseline vs DriveDreamer4D vs ReconDreamer (strides 1.5 and 6) on the default segments.

    python benchmarks/methods_gate.py [--configfile config/config.yaml] [--segments synth-01 ...]
        [--backbones street pvg] [--strides 1.5 6] [--methods baseline dd4d recondreamer]
        [--iterations N] [--restore-strength X] [--restorer-checkpoint CKPT] [--oracle] [--cores 1]
        [--dry-run | --report-only]

Drives the Snakemake workflow with the given config (default: the embedded one), asking only for
the metric files of the gate's runs (``metrics/<segment>/<run>.json``): baseline-B, dd4d-B and
recondreamer-B-<main restorer>-stride<S> for every backbone B and stride S. The config and
results directory are the default run's, so every run, evaluation model and restorer is shared
with ``snakemake --cores 2`` and nothing is trained twice. DriveDreamer4D with Street Gaussians
is not a row of the paper's table 2, but the rules are generic over the backbone, so the gate
simply asks for it.

Then reads the metric files written by ``recondreamer evaluate`` (NTA-IoU, NTL-IoU, FID, and
PSNR/SSIM against the true novel views of the synthetic segments; FID here is the mean of the
per-segment FIDs, a diagnostic: the tables and ``recondreamer findings`` pool the segments and
add KID) and prints, per backbone,
the paper-style comparison (means over segments per trajectory, and their average) and the
verdicts of the paper's finding at shift@6: ReconDreamer better than its baseline and than
DriveDreamer4D per metric, stride 1.5 better than stride 6, with the number of segments where
it holds. ``--report-only`` prints what the metric files on disk give (missing cells shown as
'-', cells with fewer segments than asked marked with their count).

``--oracle`` adds the same ReconDreamer runs with the oracle restorer (``--restorer truth``: each
update trains on the true views of the shifted trajectory, rendered by the synthetic world), the
upper bound of any restorer: where the oracle beats the baseline and DriveRestorer does not, the
restorer is what is missing; where the oracle does not either, the loop is.

``--iterations N`` sets ``recon.iterations`` of every run and ``--restore-strength X``
``methods.restore_strength`` of the ReconDreamer runs (a second config file merged over the
first): Snakemake then retrains the runs whose settings changed, in the same results directory
(give ``--results-dir`` to keep them apart).
Timings are not measured here: see each rule's ``benchmarks/`` file.
"""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import yaml

from recondreamer.configs import workflow_config
from recondreamer.report.layout import (
    Method,
    format_stride,
    metrics_file,
    trajectory_label,
)
from recondreamer.experiment_plan import segment_names
from recondreamer.report.tables import METRICS as TABLE_METRICS
from recondreamer.report.tables import ReportInputError, read_run_metrics

METRICS = tuple(m for m in TABLE_METRICS if m.key != "kid")  # per-segment values, FID as the segment's diagnostic

REPO = Path(__file__).resolve().parents[1]
SCHEMA = REPO / "workflow" / "schemas" / "config.schema.yaml"
TRAJECTORIES = ("shift@3", "shift@6", "lane_change")
VERDICT_TRAJECTORY = "shift@6"
AVERAGE = "Average"
TRUTH = "truth"  # the oracle restorer of 'train-recondreamer --restorer truth' (synthetic segments only)


@dataclass(frozen=True)
class GateRun:
    """One row of the gate: a workflow run id and its label."""

    label: str
    method: Method


def gate_config(root: Path, configfile: Path, results_dir: str | None) -> dict:
    """The config as the Snakefile sees it: the file layered over the default config, validated."""
    from snakemake.utils import validate

    config = workflow_config(configfile, root=root)
    if results_dir is not None:
        config["results_dir"] = results_dir
    validate(config, str(SCHEMA))
    return config


def gate_runs(backbones: list[str], strides: list[float], restorer: str, methods: list[str], oracle: bool = False) -> list[GateRun]:
    runs = []
    for backbone in backbones:
        if "baseline" in methods:
            runs.append(GateRun("baseline", Method("baseline", backbone)))
        if "dd4d" in methods:
            runs.append(GateRun("DriveDreamer4D", Method("dd4d", backbone)))
        if "recondreamer" in methods:
            runs += [GateRun(f"ReconDreamer {format_stride(s)} m", Method("recondreamer", backbone, restorer, s)) for s in strides]
        if oracle:  # the same loop trained on the true shifted views: what a perfect restorer would give
            runs += [GateRun(f"oracle (true views) {format_stride(s)} m", Method("recondreamer", backbone, TRUTH, s)) for s in strides]
    return runs


def run_workflow(args: argparse.Namespace, targets: list[Path]) -> int:
    """Snakemake on the gate's metric files (one job at a time unless --cores says otherwise)."""
    overrides = {}
    if args.results_dir is not None:
        overrides["results_dir"] = args.results_dir
    if args.iterations is not None:
        overrides["recon"] = {"iterations": args.iterations}
    if args.restore_strength is not None:
        overrides["methods"] = {"restore_strength": args.restore_strength}
    if args.restorer_checkpoint is not None:
        overrides["restorer"] = {"checkpoints": {args.config["experiment"]["main_restorer"]: str(args.restorer_checkpoint.resolve())}}
    with tempfile.TemporaryDirectory() as scratch:
        configfiles = [str(args.configfile)]
        if overrides:
            # A second config file, merged key by key over the first (--config would pass strings).
            configfiles.append(str(Path(scratch) / "gate-overrides.yaml"))
            Path(configfiles[-1]).write_text(yaml.safe_dump(overrides))
        # Targets first: --configfile and --quiet take several values each.
        command = [sys.executable, "-m", "snakemake", *(str(t) for t in targets), "--configfile", *configfiles,
                   "--cores", str(args.cores)]
        if args.dry_run:
            command += ["--dry-run", "--quiet", "rules"]
        print("$ " + " ".join(command), flush=True)
        return subprocess.run(command, cwd=args.directory, check=False).returncode


# ---------------------------------------------------------------------------- reading


def read_values(results_dir: str, segments: list[str], runs: list[GateRun]) -> dict[tuple[str, str], dict[str, dict[str, float | None]]]:
    """{(segment, run id): {trajectory: {metric key: value}}} for every metric file on disk."""
    values = {}
    for segment in segments:
        for run in runs:
            path = metrics_file(results_dir, segment, run.method.run_id)
            if path.is_file():
                values[(segment, run.method.run_id)] = read_run_metrics(path, TRAJECTORIES, METRICS)
    return values


def cell(values, segments: list[str], run_id: str, trajectory: str, metric: str) -> tuple[float | None, int]:
    """Mean over the segments that have the value, and how many do; AVERAGE = mean of the trajectory means."""
    if trajectory == AVERAGE:
        means = [cell(values, segments, run_id, t, metric)[0] for t in TRAJECTORIES]
        counts = [cell(values, segments, run_id, t, metric)[1] for t in TRAJECTORIES]
        if any(m is None for m in means):
            return None, min(counts)
        return sum(means) / len(means), min(counts)
    found = [values[(s, run_id)][trajectory][metric] for s in segments if (s, run_id) in values]
    found = [v for v in found if v is not None and math.isfinite(v)]
    return (sum(found) / len(found), len(found)) if found else (None, 0)


def better(metric: str, a: float, b: float) -> bool:
    spec = next(m for m in METRICS if m.key == metric)
    return a > b if spec.higher_is_better else a < b


def segment_wins(values, segments: list[str], a: str, b: str, trajectory: str, metric: str) -> tuple[int, int]:
    """Segments where run a beats run b, out of the segments where both have the value."""
    wins = total = 0
    for segment in segments:
        if (segment, a) not in values or (segment, b) not in values:
            continue
        x, y = values[(segment, a)][trajectory][metric], values[(segment, b)][trajectory][metric]
        if x is None or y is None:
            continue
        total += 1
        wins += better(metric, x, y)
    return wins, total


# ---------------------------------------------------------------------------- printing


def number(value: float, decimals: int) -> str:
    """The table's decimals, but at least three for values below 1: the FID of the feature network
    trained here is about 0.1, which two decimals would round to ties."""
    return f"{value:.{decimals if abs(value) >= 1 else max(decimals, 3)}f}"


def format_cell(value: float | None, count: int, expected: int, decimals: int) -> str:
    if value is None:
        return "-"
    text = number(value, decimals)
    return text if count == expected else f"{text} ({count})"


def print_comparison(values, segments: list[str], backbone: str, runs: list[GateRun]) -> None:
    columns = [*TRAJECTORIES, AVERAGE]
    print(f"\n### {backbone}: means over {len(segments)} segment(s); NTL-IoU in percent; PSNR/SSIM against the true novel views")
    header = "| method | " + " | ".join(f"{trajectory_label(c)} {m.label}" for c in columns for m in METRICS) + " |"
    print(header)
    print("|" + "---|" * (header.count("|") - 1))
    for run in runs:
        cells = [format_cell(*cell(values, segments, run.method.run_id, c, m.key), len(segments), m.decimals) for c in columns for m in METRICS]
        print(f"| {run.label} | " + " | ".join(cells) + " |")


def verdicts(values, segments: list[str], backbone: str, runs: list[GateRun], main_stride: float, strides: list[float]) -> list[str]:
    """The paper's finding at shift@6, metric by metric: holds / fails / not measured."""
    by_label = {run.label: run.method.run_id for run in runs}
    comparisons = []
    for name in ("ReconDreamer", "oracle (true views)"):
        ours = by_label.get(f"{name} {format_stride(main_stride)} m")
        if ours is None:
            continue
        comparisons += [(f"{name} {format_stride(main_stride)} m > baseline", ours, by_label.get("baseline")),
                        (f"{name} {format_stride(main_stride)} m > DriveDreamer4D", ours, by_label.get("DriveDreamer4D"))]
        widest = max(strides)
        if widest != main_stride:
            comparisons.append((f"{name}: stride {format_stride(main_stride)} m > stride {format_stride(widest)} m", ours,
                                by_label.get(f"{name} {format_stride(widest)} m")))
    lines = []
    for name, a, b in comparisons:
        if b is None:
            continue
        parts = []
        for metric in METRICS:
            x, _ = cell(values, segments, a, VERDICT_TRAJECTORY, metric.key)
            y, _ = cell(values, segments, b, VERDICT_TRAJECTORY, metric.key)
            if x is None or y is None:
                parts.append(f"{metric.label} not measured")
                continue
            wins, total = segment_wins(values, segments, a, b, VERDICT_TRAJECTORY, metric.key)
            verdict = "holds" if better(metric.key, x, y) else "FAILS"
            parts.append(f"{metric.label} {verdict} ({number(x, metric.decimals)} vs {number(y, metric.decimals)}; {wins}/{total} segments)")
        lines.append(f"{backbone}: {name} at {VERDICT_TRAJECTORY}: " + "; ".join(parts))
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--directory", type=Path, default=REPO, help="workflow directory: Snakefile, config/, results (default: this checkout)")
    parser.add_argument("--configfile", type=Path, default=Path("config/config.yaml"),
                        help="workflow config, relative to --directory (default: the embedded config/config.yaml)")
    parser.add_argument("--results-dir", default=None, help="override the config's results_dir (default: the config's, shared with the full run)")
    parser.add_argument("--segments", nargs="+", default=None, help="segment names (default: every segment of the config)")
    parser.add_argument("--backbones", nargs="+", default=["street", "pvg"], choices=["street", "pvg", "deformable", "s3"], help="reconstruction backbones (default street pvg)")
    parser.add_argument("--strides", nargs="+", type=float, default=[1.5, 6.0], help="ReconDreamer PDUS strides in metres (default 1.5 6)")
    parser.add_argument("--methods", nargs="+", default=["baseline", "dd4d", "recondreamer"], choices=["baseline", "dd4d", "recondreamer"],
                        help="which methods to run (default all three; e.g. 'baseline dd4d' before the restorer is ready)")
    parser.add_argument("--iterations", type=int, default=None, help="recon.iterations of every run (default: the config's preset)")
    parser.add_argument("--restore-strength", type=float, default=None,
                        help="methods.restore_strength of the ReconDreamer runs, in (0, 1] (default: the config's)")
    parser.add_argument("--restorer-checkpoint", type=Path, default=None, metavar="CKPT",
                        help="a local DriveRestorer checkpoint for the ReconDreamer runs instead of the one the workflow "
                        "trains (restorer.checkpoints); give --results-dir too so its runs do not replace the default ones")
    parser.add_argument("--oracle", action="store_true",
                        help="also run ReconDreamer with the oracle restorer (the true views of each shifted trajectory; "
                        "synthetic segments only) at every stride: separates what PDUS gives from the restorer's quality")
    parser.add_argument("--cores", type=int, default=1, help="Snakemake --cores (default 1: one job at a time)")
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--dry-run", action="store_true", help="list the jobs the gate needs (Snakemake dry run) and print nothing else")
    mode.add_argument("--report-only", action="store_true", help="run nothing; print the comparison from the metric files on disk")
    args = parser.parse_args(argv)
    if args.iterations is not None and args.iterations < 1:
        parser.error(f"--iterations must be at least 1, got {args.iterations}")
    if args.restore_strength is not None and not 0.0 < args.restore_strength <= 1.0:
        parser.error(f"--restore-strength must lie in (0, 1], got {args.restore_strength}")
    if args.restorer_checkpoint is not None and not args.restorer_checkpoint.is_file():
        parser.error(f"--restorer-checkpoint {args.restorer_checkpoint}: file not found")

    args.config = gate_config(args.directory, args.configfile, args.results_dir)
    results_dir = str(args.directory / args.config["results_dir"])
    known = segment_names(args.config)
    segments = args.segments or known
    unknown = sorted(set(segments) - set(known))
    if unknown:
        parser.error(f"--segments {unknown} are not segments of {args.configfile} ({', '.join(known)})")
    experiment = args.config["experiment"]
    if args.oracle and args.config["source"] != "synthetic":
        parser.error("--oracle needs synthetic segments (the true views of a real recording do not exist)")
    runs = gate_runs(args.backbones, args.strides, experiment["main_restorer"], args.methods, args.oracle)
    # Targets relative to the workflow directory, as the rules name their outputs.
    targets = [metrics_file(args.config["results_dir"], s, run.method.run_id) for s in segments for run in runs]

    if not args.report_only:
        code = run_workflow(args, targets)
        if code != 0 or args.dry_run:
            return code
    try:
        values = read_values(results_dir, segments, runs)
    except ReportInputError as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    print(f"Gate of issue 7: {len(segments)} segment(s) ({', '.join(segments)}), results in {results_dir}, "
          f"restorer {experiment['main_restorer']}; {len(values)} of {len(targets)} metric files present")
    lines = []
    for backbone in args.backbones:
        mine = [run for run in runs if run.method.backbone == backbone]
        print_comparison(values, segments, backbone, mine)
        lines += verdicts(values, segments, backbone, mine, float(experiment["main_stride"]), args.strides)
    print("\n### Verdicts (the paper's finding at shift@6; 'k/n segments' = segments where it holds)")
    for line in lines or ["no comparison measured yet"]:
        print("- " + line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
