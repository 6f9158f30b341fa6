"""Figures of the experiment (matplotlib, Agg): metric vs shift, stride curve, restorer bars,
qualitative grids and PDUS progression frames.

Values come from the same per-run metric files as the tables (``tables.read_metrics``); images
come from the render directories and from the ReconDreamer runs' update folders. The PDUS
figure reads ``RUN/updates/<update>/rendered/NNN.png`` and ``.../restored/NNN.png`` (one folder
per update, in name order) with an optional ``update.json`` holding ``offset_m``, the layout
``train-recondreamer`` writes for each update.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from recondreamer.report.layout import (
    Method,
    format_stride,
    render_dir,
    trajectory_shift,
)
from recondreamer.experiment_plan import ExperimentPlan
from recondreamer.report.tables import ReportInputError, available_metrics, read_metrics


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(figure, out: Path) -> Path:
    from recondreamer.io import atomic_path

    with atomic_path(out) as tmp:
        figure.savefig(tmp, format=out.suffix.lstrip(".") or "png", dpi=120, bbox_inches="tight")
    _pyplot().close(figure)
    return out


# Colour = backbone, line style = method kind, so that a method's backbone reads at a glance.
_BACKBONE_COLORS = {"street": "C3", "pvg": "C0", "deformable": "C2", "s3": "C1"}
_KIND_STYLES = {
    "baseline": {"linestyle": ":", "marker": "o"},
    "dd4d": {"linestyle": "--", "marker": "s"},
    "recondreamer": {"linestyle": "-", "marker": "^", "linewidth": 2},
}


def _stats(long: pd.DataFrame, run_id: str, trajectory: str, metric: str) -> tuple[float, float]:
    values = long.loc[(long["run"] == run_id) & (long["trajectory"] == trajectory) & (long["metric"] == metric), "value"].dropna()
    if values.empty:
        return math.nan, math.nan
    return float(values.mean()), float(values.std(ddof=0))


def plot_metric_vs_shift(long: pd.DataFrame, rows: Sequence[tuple[str, Method]], trajectories: Sequence[str], out: Path) -> Path:
    """One panel per metric: mean over segments (bars = std) against the lateral shift in metres."""
    shifts = sorted((trajectory_shift(t), t) for t in trajectories if trajectory_shift(t) is not None)
    if not shifts:
        raise ReportInputError(f"no shift@Y trajectory among {list(trajectories)}: nothing to plot against the shift")
    metrics = available_metrics(long)
    plt = _pyplot()
    figure, axes = plt.subplots(1, len(metrics), figsize=(3.4 * len(metrics), 3.2), squeeze=False, layout="constrained")
    for axis, metric in zip(axes[0], metrics):
        for label, method in rows:
            stats = [_stats(long, method.run_id, t, metric.key) for _, t in shifts]
            axis.errorbar([s for s, _ in shifts], [m for m, _ in stats], yerr=[d for _, d in stats], capsize=3, label=label,
                          color=_BACKBONE_COLORS.get(method.backbone, "black"), **_KIND_STYLES[method.kind])
        axis.set_xlabel("lateral shift (m)")
        axis.set_title(f"{metric.label} {'(higher better)' if metric.higher_is_better else '(lower better)'}", fontsize=9)
        axis.set_xticks([s for s, _ in shifts])
    handles, labels = axes[0][0].get_legend_handles_labels()
    figure.legend(handles, labels, loc="outside lower center", ncol=min(4, len(labels)), fontsize=7)
    figure.suptitle("Novel-trajectory quality against the lateral shift (mean over segments, bars: std)", fontsize=10)
    return _save(figure, out)


def plot_stride_curve(long: pd.DataFrame, rows: Sequence[tuple[str, Method]], trajectories: Sequence[str], out: Path) -> Path:
    """Each metric against the PDUS stride: per trajectory and the average over trajectories."""
    metrics = available_metrics(long)
    strides = [method.stride for _, method in rows]
    plt = _pyplot()
    figure, axes = plt.subplots(1, len(metrics), figsize=(3.4 * len(metrics), 3.2), squeeze=False, layout="constrained")
    for axis, metric in zip(axes[0], metrics):
        per_trajectory = {t: [_stats(long, m.run_id, t, metric.key)[0] for _, m in rows] for t in trajectories}
        for trajectory, values in per_trajectory.items():
            axis.plot(strides, values, marker=".", linewidth=1, alpha=0.6, label=trajectory)
        average = np.mean(np.array(list(per_trajectory.values())), axis=0)
        axis.plot(strides, average, marker="o", color="black", linewidth=2, label="average")
        axis.set_xscale("log")
        axis.minorticks_off()  # the log axis' own minor labels would overprint the stride labels
        axis.set_xticks(strides, [format_stride(s) for s in strides])
        axis.set_xlabel("PDUS stride (m)")
        axis.set_title(metric.label, fontsize=9)
    axes[0][0].legend(fontsize=7)
    figure.suptitle("Progressive Data Update Strategy: metrics against the stride (6 m = no PDUS)", fontsize=10)
    return _save(figure, out)


def plot_restorer_bars(long: pd.DataFrame, rows: Sequence[tuple[str, Method]], trajectories: Sequence[str], out: Path) -> Path:
    """Bars of each metric (average over trajectories of the segment means) per restorer backbone."""
    metrics = available_metrics(long)
    plt = _pyplot()
    figure, axes = plt.subplots(1, len(metrics), figsize=(3.0 * len(metrics), 3.4), squeeze=False, layout="constrained")
    for axis, metric in zip(axes[0], metrics):
        values = [float(np.mean([_stats(long, m.run_id, t, metric.key)[0] for t in trajectories])) for _, m in rows]
        axis.bar(range(len(rows)), values, color=[f"C{i}" for i in range(len(rows))])
        axis.set_xticks(range(len(rows)), [label for label, _ in rows], rotation=35, ha="right", fontsize=7)
        axis.set_title(f"{metric.label} {'↑' if metric.higher_is_better else '↓'}", fontsize=9)
    figure.suptitle("DriveRestorer backbones (average over the trajectories)", fontsize=10)
    return _save(figure, out)


def _read_frame(directory: Path, t: int) -> np.ndarray:
    from PIL import Image

    for suffix in (".png", ".jpg", ".jpeg"):
        path = directory / f"{t:03d}{suffix}"
        if path.is_file():
            with Image.open(path) as image:
                return np.asarray(image.convert("RGB"))
    raise ReportInputError(f"frame {t:03d} missing in {directory}")


def qualitative_grid(scene_dir: Path, panels: Sequence[tuple[str, Path]], trajectory: str, frames: Sequence[int], out: Path) -> Path:
    """Rows: ground truth of the original trajectory, the true novel view (synthetic scenes), then each
    method's render along ``trajectory``; columns: the chosen frames."""
    from recondreamer.scene import load_scene

    scene = load_scene(scene_dir)
    frames = [t for t in frames if 0 <= t < scene.num_frames] or [scene.num_frames - 1]
    rows: list[tuple[str, list[np.ndarray]]] = [("ground truth (original trajectory)", [scene.image(t) for t in frames])]
    if trajectory in scene.novel_trajectories:
        rows.append((f"true view ({trajectory})", [scene.novel_image(trajectory, t) for t in frames]))
    rows += [(label, [_read_frame(directory, t) for t in frames]) for label, directory in panels]
    plt = _pyplot()
    aspect = scene.height / scene.width
    figure, axes = plt.subplots(len(rows), len(frames), figsize=(2.6 * len(frames), 2.6 * aspect * len(rows) + 0.6), squeeze=False, layout="constrained")
    for r, (label, images) in enumerate(rows):
        for c, image in enumerate(images):
            axis = axes[r][c]
            axis.imshow(image)
            axis.set_xticks([])
            axis.set_yticks([])
            if c == 0:
                axis.set_ylabel(label, fontsize=7, rotation=0, ha="right", va="center")
            if r == 0:
                axis.set_title(f"frame {frames[c]}", fontsize=8)
    figure.suptitle(f"{scene.scene_id}: {trajectory}", fontsize=10)
    return _save(figure, out)


def pdus_progression(run: Path, out: Path, frame: int | None = None) -> Path:
    """One column per PDUS update: the render of the widened trajectory and its restoration."""
    updates = sorted(p for p in (run / "updates").glob("*") if (p / "rendered").is_dir() and (p / "restored").is_dir())
    if not updates:
        raise ReportInputError(f"{run}: no PDUS update folders (updates/<k>/rendered and restored) to show")
    columns = []
    for update in updates:
        rendered = sorted((update / "rendered").glob("*.png"))
        if not rendered:
            raise ReportInputError(f"{update / 'rendered'}: no frames")
        t = int(rendered[len(rendered) // 2].stem) if frame is None else frame
        info = json.loads((update / "update.json").read_text()) if (update / "update.json").is_file() else {}
        offset = info.get("offset_m")
        title = update.name + (f"\n{offset:g} m" if isinstance(offset, (int, float)) else "")
        columns.append((title, _read_frame(update / "rendered", t), _read_frame(update / "restored", t)))
    plt = _pyplot()
    height, width = columns[0][1].shape[:2]
    figure, axes = plt.subplots(2, len(columns), figsize=(2.4 * len(columns), 2 * 2.4 * height / width + 0.8), squeeze=False, layout="constrained")
    for c, (title, rendered, restored) in enumerate(columns):
        for r, (image, label) in enumerate(((rendered, "rendered"), (restored, "restored"))):
            axes[r][c].imshow(image)
            axes[r][c].set_xticks([])
            axes[r][c].set_yticks([])
            if c == 0:
                axes[r][c].set_ylabel(label, fontsize=8)
        axes[0][c].set_title(title, fontsize=8)
    figure.suptitle(f"PDUS progression of {run.name}", fontsize=10)
    return _save(figure, out)


def make_plots(plan: ExperimentPlan, results_dir: str | Path, out_dir: str | Path, qualitative_trajectory: str = "shift@6",
               qualitative_frames: Sequence[int] = (0, 20, 39), dd4d_backbone: str | None = None) -> list[Path]:
    """The metric figures and the qualitative grids (PDUS figures: ``pdus_progression`` per run)."""
    results_dir, out_dir = Path(results_dir), Path(out_dir)
    runs = plan.runs()
    long = read_metrics(results_dir, plan.segments, runs, plan.trajectories)
    written = [
        plot_metric_vs_shift(long, plan.table1_rows() + [(m.label, m) for _, m in plan.table2_rows() if m.kind == "dd4d"], plan.trajectories, out_dir / "metric_vs_shift.png"),
        plot_stride_curve(long, plan.table5_rows(), plan.trajectories, out_dir / "stride_curve.png"),
        plot_restorer_bars(long, [(f"{plan.baseline(plan.ablation_backbone).label} (no restorer)", plan.baseline(plan.ablation_backbone))] + plan.table4_rows(), plan.trajectories, out_dir / "restorer_bars.png"),
    ]
    dd4d = dd4d_backbone or (plan.dd4d_backbones[0] if plan.dd4d_backbones else None)
    methods = [plan.baseline(plan.ablation_backbone)] + ([plan.dd4d(dd4d)] if dd4d else []) + [plan.preference_method()]
    for segment in plan.segments:
        panels = [(m.label, render_dir(results_dir, segment, m.run_id, qualitative_trajectory)) for m in methods]
        written.append(qualitative_grid(results_dir / "scenes" / segment, panels, qualitative_trajectory, qualitative_frames, out_dir / f"qualitative_{segment}.png"))
    return written

