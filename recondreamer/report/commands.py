"""Sub-commands of the report stage: ``make-tables``, ``findings``, ``make-plots``, ``pdus-figure``,
``novel-view-clip``, ``config-page``, ``benchmark-summary``."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

log = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    from recondreamer.experiment_plan import add_plan_arguments

    p = subparsers.add_parser(
        "make-tables",
        help="the paper's tables 1-5 from per-run metric files (CSV, Markdown, LaTeX, HTML)",
        description="Read RESULTS/metrics/<segment>/<run>.json for every run the tables need, average over "
        "segments and write OUT/table<N>.{csv,md,tex,html} and OUT/table<N>_sources.csv. Fails, naming "
        "them, when metric files are missing.",
    )
    p.add_argument("--results", required=True, type=Path, help="results directory of the workflow (holds metrics/)")
    p.add_argument("--out", required=True, type=Path, help="output directory of the tables")
    p.add_argument("--tables", nargs="+", type=int, default=[1, 2, 3, 4, 5], help="table numbers to build (default 1 2 3 4 5)")
    p.add_argument("--win-rates", type=Path, default=None, help="win-rate JSON of 'recondreamer judge' or 'study-ingest' (table 3)")
    p.add_argument("--run-config", type=Path, default=None, help="the workflow config of the run (YAML): every table then notes its stand-ins, recipe changes and training budgets")
    add_plan_arguments(p)
    p.set_defaults(func=run_make_tables)

    p = subparsers.add_parser(
        "findings",
        help="the paper's claims on this run: our numbers, segments where each holds, bootstrap interval, verdict",
        description="Read the same metric and feature files as make-tables (and the win rates) and write OUT (Markdown) "
        "with OUT's .html and .csv siblings: one line per claim of the paper's tables and per metric-validity check.",
    )
    p.add_argument("--results", required=True, type=Path, help="results directory of the workflow (holds metrics/)")
    p.add_argument("--out", required=True, type=Path, help="Markdown file to write (e.g. results/findings.md)")
    p.add_argument("--win-rates", type=Path, default=None, help="win-rate JSON of 'recondreamer judge' or 'study-ingest' (table 3's claims)")
    p.add_argument("--run-config", type=Path, default=None, help="the workflow config of the run (YAML), for the stand-in notes")
    p.add_argument("--seed", type=int, default=0, help="seed of the bootstrap resamples (default 0)")
    add_plan_arguments(p)
    p.set_defaults(func=run_findings)

    p = subparsers.add_parser(
        "make-plots",
        help="figures: metric vs shift, stride curve, restorer bars, qualitative grids",
        description="Read the same metric files as make-tables plus render and run folders, and write PNG figures to OUT.",
    )
    p.add_argument("--results", required=True, type=Path, help="results directory of the workflow")
    p.add_argument("--out", required=True, type=Path, help="output directory of the figures")
    p.add_argument("--qualitative-trajectory", default="shift@6", help="trajectory of the qualitative grids (default shift@6)")
    p.add_argument("--qualitative-frames", nargs="+", type=int, default=[0, 20, 39], help="frame indices shown in the grids (default 0 20 39; out-of-range ones are dropped)")
    p.add_argument("--dd4d-backbone", default=None, help="DriveDreamer4D backbone shown in the grids (default: the first of --dd4d-backbones)")
    add_plan_arguments(p)
    p.set_defaults(func=run_make_plots)

    p = subparsers.add_parser(
        "pdus-figure",
        help="PDUS progression of a ReconDreamer run: render and restoration per update",
        description="Read RUN/updates/<update>/{rendered,restored}/NNN.png (one folder per update) and draw one column per update.",
    )
    p.add_argument("--run", required=True, type=Path, help="ReconDreamer run directory (train-recondreamer output)")
    p.add_argument("--out", required=True, type=Path, help="image file to write (PNG)")
    p.add_argument("--frame", type=int, default=None, help="frame index shown (default: the middle frame of each update)")
    p.set_defaults(func=run_pdus_figure)

    p = subparsers.add_parser(
        "novel-view-clip",
        help="WebM video, animated GIF and an HTML page playing the video, of renders side by side with the true novel view",
        description="Read each --panel frame folder (frames 0..T-1 of the scene's size) and, when the scene has them, the "
        "true novel views along --trajectory, and write OUT (GIF: the panels two a row, each under its label), OUT's .webm "
        "sibling (the same clip as WebM video) and OUT's .html sibling (the video embedded, for the Snakemake report).",
    )
    p.add_argument("--scene", required=True, type=Path, help="scene directory (frame count and size; true novel views)")
    p.add_argument("--trajectory", required=True, help="trajectory the panels were rendered along (e.g. shift@6)")
    p.add_argument("--panel", required=True, action="append", dest="panels", metavar="LABEL=DIR", help="a panel: its label and frame folder (repeat, in reading order; two panels a row)")
    p.add_argument("--out", required=True, type=Path, help="GIF to write (e.g. results/clips/synth-01.gif)")
    p.add_argument("--fps", type=float, default=6.0, help="frames per second (default 6)")
    p.add_argument("--min-panel-width", type=int, default=240, help="panels are enlarged by a whole factor to at least this width in pixels (default 240)")
    p.set_defaults(func=run_novel_view_clip)

    p = subparsers.add_parser(
        "config-page",
        help="the run's configuration (run_config.yaml) as an HTML page for the report",
        description="Write OUT: the YAML file, escaped, on an HTML page.",
    )
    p.add_argument("config", type=Path, help="the workflow's run_config.yaml")
    p.add_argument("--out", required=True, type=Path, help="HTML file to write")
    p.set_defaults(func=run_config_page)

    p = subparsers.add_parser(
        "benchmark-summary",
        help="per-rule totals of the Snakemake benchmark files",
        description="Sum the benchmark TSV files below ROOT/<rule>/ per rule and write OUT.{csv,md,html}.",
    )
    p.add_argument("root", type=Path, help="benchmark root (RESULTS/benchmarks)")
    p.add_argument("--out", required=True, type=Path, help="output path without suffix, e.g. results/benchmark_summary")
    p.set_defaults(func=run_benchmark_summary)


def _plan(args: argparse.Namespace):
    from recondreamer.errors import RecondreamerError
    from recondreamer.experiment_plan import plan_from_arguments

    try:
        return plan_from_arguments(args)
    except ValueError as error:
        raise RecondreamerError(f"inconsistent plan options: {error}") from None


def _run_notes(path: Path | None) -> dict[int, list[str]]:
    if path is None:
        return {}
    import yaml

    from recondreamer.errors import RecondreamerError
    from recondreamer.report.notes import run_notes

    try:
        config = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as error:
        raise RecondreamerError(f"--run-config {path}: not a readable YAML file ({error})") from None
    try:
        return run_notes(config)
    except (KeyError, TypeError) as error:
        raise RecondreamerError(f"--run-config {path}: not a workflow config (missing or malformed key {error})") from None


def run_make_tables(args: argparse.Namespace) -> int:
    from recondreamer.report.tables import build_tables, write_table

    tables = build_tables(_plan(args), args.results, args.tables, args.win_rates, _run_notes(args.run_config))
    for table in tables:  # all inputs were read before the first write
        paths = write_table(table, args.out)
        log.info("table %d: %d rows -> %s", table.number, len(table.values), ", ".join(str(p) for p in paths))
    return 0


def run_findings(args: argparse.Namespace) -> int:
    from recondreamer.report.findings import build_findings, write_findings

    plan = _plan(args)
    evidence = build_findings(plan, args.results, args.win_rates, args.seed)
    notes = _run_notes(args.run_config).get(1, [])
    paths = write_findings(evidence, plan, args.out, notes)
    verdicts = [e.verdict for e in evidence]
    log.info("%d claims: %d hold, %d do not hold -> %s", len(evidence), verdicts.count("holds"), verdicts.count("does not hold"), ", ".join(str(p) for p in paths))
    return 0


def run_make_plots(args: argparse.Namespace) -> int:
    from recondreamer.report.plots import make_plots

    paths = make_plots(_plan(args), args.results, args.out, args.qualitative_trajectory, args.qualitative_frames, args.dd4d_backbone)
    log.info("wrote %d figures to %s", len(paths), args.out)
    return 0


def run_pdus_figure(args: argparse.Namespace) -> int:
    from recondreamer.report.plots import pdus_progression

    pdus_progression(args.run, args.out, args.frame)
    log.info("wrote %s", args.out)
    return 0


def run_novel_view_clip(args: argparse.Namespace) -> int:
    from recondreamer.report.clips import novel_view_clip, parse_panel

    gif, video, page = novel_view_clip(args.scene, args.trajectory, [parse_panel(text) for text in args.panels], args.out, args.fps, args.min_panel_width)
    log.info("wrote %s, %s and %s", gif, video, page)
    return 0


def run_config_page(args: argparse.Namespace) -> int:
    from recondreamer.report.config_page import config_page

    log.info("wrote %s", config_page(args.config, args.out))
    return 0


def run_benchmark_summary(args: argparse.Namespace) -> int:
    from recondreamer.report.benchmarks import (
        summarize_benchmarks,
        write_benchmark_summary,
    )

    summary = summarize_benchmarks(args.root)
    write_benchmark_summary(summary, args.out)
    total = summary.loc["TOTAL"]
    log.info("%d jobs, %.1f s summed wall time; largest: %s (%.1f%%)", total["jobs"], total["total_s"], summary.index[0], summary.iloc[0]["share_pct"])
    return 0
