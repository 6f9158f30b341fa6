"""Figures and the benchmark summary on small generated inputs."""

import numpy as np
import pandas as pd
import pytest
from PIL import Image
from test_report_tables import small_plan, write_metrics

from recondreamer.cli import main
from recondreamer.report import plots
from recondreamer.report.benchmarks import summarize_benchmarks
from recondreamer.report.tables import ReportInputError, read_metrics


def _is_png(path):
    with Image.open(path) as image:
        return image.format == "PNG" and image.width > 100


def test_metric_figures(tmp_path):
    plan = small_plan()
    write_metrics(tmp_path, plan)
    long = read_metrics(tmp_path, plan.segments, plan.runs(), plan.trajectories)
    assert _is_png(plots.plot_metric_vs_shift(long, plan.table1_rows(), plan.trajectories, tmp_path / "shift.png"))
    assert _is_png(plots.plot_stride_curve(long, plan.table5_rows(), plan.trajectories, tmp_path / "stride.png"))
    assert _is_png(plots.plot_restorer_bars(long, plan.table4_rows(), plan.trajectories, tmp_path / "bars.png"))
    with pytest.raises(ReportInputError, match="no shift@Y trajectory"):
        plots.plot_metric_vs_shift(long, plan.table1_rows(), ["lane_change"], tmp_path / "none.png")


def _frames(directory, count, size=(24, 16), value=0):
    directory.mkdir(parents=True, exist_ok=True)
    for t in range(count):
        Image.fromarray(np.full((size[1], size[0], 3), (value + 10 * t) % 255, np.uint8)).save(directory / f"{t:03d}.png")


def test_pdus_progression_and_qualitative_grid(tmp_path):
    from recondreamer.scene import write_scene
    from recondreamer.sources.synthetic import generate_segment

    run = tmp_path / "run"
    for k in (1, 2, 3):
        _frames(run / "updates" / f"update_{k:02d}" / "rendered", 4)
        _frames(run / "updates" / f"update_{k:02d}" / "restored", 4, value=100)
        (run / "updates" / f"update_{k:02d}" / "update.json").write_text(f'{{"offset_m": {1.5 * k}}}')
    assert _is_png(plots.pdus_progression(run, tmp_path / "pdus.png"))
    assert main(["pdus-figure", "--run", str(run), "--out", str(tmp_path / "pdus_cli.png"), "--frame", "3"]) == 0
    assert _is_png(tmp_path / "pdus_cli.png")
    with pytest.raises(ReportInputError, match="no PDUS update folders"):
        plots.pdus_progression(tmp_path / "empty", tmp_path / "x.png")

    scene_dir = tmp_path / "scene"
    data = generate_segment(5, "quick", frames=4, width=48, height=32)
    write_scene(scene_dir, data)
    _frames(tmp_path / "renders" / "a", 4, size=(48, 32))
    assert _is_png(plots.qualitative_grid(scene_dir, [("method a", tmp_path / "renders" / "a")], "shift@6", [0, 3, 99], tmp_path / "grid.png"))
    with pytest.raises(ReportInputError, match="frame 000 missing"):
        plots.qualitative_grid(scene_dir, [("absent", tmp_path / "renders" / "b")], "shift@6", [0], tmp_path / "grid2.png")


def test_benchmark_summary_totals_per_rule(tmp_path):
    root = tmp_path / "benchmarks"
    header = "s\th:m:s\tmax_rss\tmax_vms\tmax_uss\tmax_pss\tio_in\tio_out\tmean_load\tcpu_time\n"
    times = {"train_recon": [10.0, 30.0, 20.0], "render": [1.5, 2.5]}
    for rule, seconds in times.items():
        for i, s in enumerate(seconds):
            path = root / rule / "seg" / f"job{i}.tsv"
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(header + f"{s}\t0:00:{int(s):02d}\t{100 + i}\t0\t0\t0\t0\t0\t50\t{s / 2}\n")
    summary = summarize_benchmarks(root)
    assert summary.loc["train_recon", "jobs"] == 3
    assert summary.loc["train_recon", "total_s"] == pytest.approx(60.0)
    assert summary.loc["render", "mean_s"] == pytest.approx(2.0)
    assert summary.loc["train_recon", "share_pct"] == pytest.approx(100 * 60 / 64)
    assert summary.loc["TOTAL", "cpu_s"] == pytest.approx(32.0)
    assert list(summary.index[:2]) == ["train_recon", "render"]
    assert main(["benchmark-summary", str(root), "--out", str(tmp_path / "summary")]) == 0
    assert pd.read_csv(tmp_path / "summary.csv", index_col=0).loc["render", "jobs"] == 2
    assert main(["benchmark-summary", str(tmp_path / "absent"), "--out", str(tmp_path / "s2")]) == 1
