"""Per-rule totals of Snakemake ``benchmark:`` files: where the workflow's time goes.

The workflow writes each job's benchmark to ``<results_dir>/benchmarks/<rule>/<job>.tsv``
(Snakemake's columns: ``s``, ``h:m:s``, ``max_rss``, ..., ``cpu_time``), so the rule is the
first folder below the benchmark root.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from recondreamer.report.tables import ReportInputError


def read_benchmarks(root: str | Path) -> pd.DataFrame:
    """One row per benchmark file (rule, job, seconds, cpu_time, max_rss); last repeat of a file wins."""
    root = Path(root)
    if not root.is_dir():
        raise ReportInputError(f"benchmark directory {root} does not exist (run the workflow first)")
    records = []
    for path in sorted(root.glob("*/**/*.tsv")):
        try:
            frame = pd.read_csv(path, sep="\t")
        except (pd.errors.EmptyDataError, pd.errors.ParserError) as error:
            raise ReportInputError(f"{path}: not a Snakemake benchmark file ({error})") from None
        if "s" not in frame.columns or frame.empty:
            raise ReportInputError(f"{path}: no 's' column / no rows (not a Snakemake benchmark file)")
        row = frame.iloc[-1]
        records.append({
            "rule": path.relative_to(root).parts[0],
            "job": str(path.relative_to(root).with_suffix("")),
            "seconds": float(row["s"]),
            "cpu_seconds": float(pd.to_numeric(row.get("cpu_time"), errors="coerce")),
            "max_rss_mb": float(pd.to_numeric(row.get("max_rss"), errors="coerce")),
        })
    return pd.DataFrame.from_records(records, columns=["rule", "job", "seconds", "cpu_seconds", "max_rss_mb"])


def summarize_benchmarks(root: str | Path) -> pd.DataFrame:
    """Per rule: jobs, total/mean/max wall seconds, total CPU seconds, peak RSS, share of the total.

    Sorted by total wall time, largest first. The share is of the summed job wall time, which on
    several cores is more than the elapsed time of the run.
    """
    jobs = read_benchmarks(root)
    if jobs.empty:
        raise ReportInputError(f"no benchmark files (*.tsv) below {root}")
    summary = jobs.groupby("rule").agg(
        jobs=("job", "count"),
        total_s=("seconds", "sum"),
        mean_s=("seconds", "mean"),
        max_s=("seconds", "max"),
        cpu_s=("cpu_seconds", "sum"),
        peak_rss_mb=("max_rss_mb", "max"),
    )
    summary["share_pct"] = 100.0 * summary["total_s"] / summary["total_s"].sum()
    summary = summary.sort_values("total_s", ascending=False)
    summary.loc["TOTAL"] = [summary["jobs"].sum(), summary["total_s"].sum(), jobs["seconds"].mean(), jobs["seconds"].max(),
                            summary["cpu_s"].sum(), summary["peak_rss_mb"].max(), 100.0]
    summary["jobs"] = summary["jobs"].astype(int)
    return summary


def write_benchmark_summary(summary: pd.DataFrame, out_stem: str | Path) -> list[Path]:
    """``out_stem``.csv, .md and .html."""
    from recondreamer.io import write_text_atomic

    stem = Path(out_stem)
    rounded = summary.round({"total_s": 1, "mean_s": 1, "max_s": 1, "cpu_s": 1, "peak_rss_mb": 0, "share_pct": 1})
    header = ["rule", *rounded.columns]
    markdown = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    markdown += ["| " + " | ".join([str(rule), *(f"{v:g}" for v in row)]) + " |" for rule, row in rounded.iterrows()]
    outputs = {
        stem.with_suffix(".csv"): summary.to_csv(float_format="%.3f"),
        stem.with_suffix(".md"): "\n".join(markdown) + "\n",
        stem.with_suffix(".html"): "<!DOCTYPE html>\n<html><head><meta charset='utf-8'><title>Time per rule</title></head><body>\n<h2>Time per rule (Snakemake benchmark files)</h2>\n" + rounded.to_html(border=0) + "\n</body></html>\n",
    }
    for path, text in outputs.items():
        write_text_atomic(path, text)
    return list(outputs)
