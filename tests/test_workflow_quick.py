"""End to end: the quick config through Snakemake in a temporary directory, then the report.
The run takes minutes, hence the slow mark; it fails whenever the workflow fails."""

import math
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_quick_config_end_to_end(tmp_path):
    root = tmp_path / "wf"
    root.mkdir()
    for name in ("Snakefile", "workflow", "config", "profiles"):
        source = REPO / name
        (shutil.copytree if source.is_dir() else shutil.copy)(source, root / name)
    run = subprocess.run([sys.executable, "-m", "snakemake", "--cores", "2", "--configfile", "config/quick.yaml"],
                         check=False, cwd=root, capture_output=True, text=True, timeout=1700)
    assert run.returncode == 0, run.stderr[-5000:]

    tables = root / "results" / "quick" / "tables"
    expected_rows = {
        1: ["PVG", "S3Gaussian", "Deformable-GS", "Street Gaussians", "ReconDreamer with PVG", "ReconDreamer with S3Gaussian",
            "ReconDreamer with Deformable-GS", "ReconDreamer with Street Gaussians", "Upper bound: true novel views in the loop"],
        2: ["PVG", "DriveDreamer4D with PVG", "ReconDreamer with PVG", "S3Gaussian", "DriveDreamer4D with S3Gaussian",
            "ReconDreamer with S3Gaussian", "Deformable-GS", "DriveDreamer4D with Deformable-GS", "ReconDreamer with Deformable-GS"],
        3: ["Lane Shift @ 3m", "Lane Shift @ 6m", "Lane Change", "Average"],
        4: ["Street Gaussians (no restorer)", "Stable Diffusion", "Stable Video Diffusion", "DriveDreamer-2", "DriveDreamer-2+Mask"],
        5: ["0.5m", "1.0m", "1.5m", "3.0m", "6.0m"],
    }
    for number, rows in expected_rows.items():
        table = pd.read_csv(tables / f"table{number}.csv", index_col="row", comment="#")
        means = table[table["kind"] == "mean"] if "kind" in table.columns else table
        assert list(means.index) == rows
        for suffix in ("md", "tex", "html"):
            assert (tables / f"table{number}.{suffix}").is_file()
        notes = (tables / f"table{number}.md").read_text()
        for stand_in in ("Stable Diffusion: a stand-in", "DriveDreamer-2+Mask: a stand-in", "stand-in for YOLO11x", "stand-in for TwinLiteNet", "stand-in for InceptionV3", "Training budgets"):
            assert stand_in in notes, (number, stand_in)
        if number != 3:
            for trajectory in ("Lane Shift @ 3m", "Lane Shift @ 6m", "Lane Change", "Average"):
                for metric in ("NTL-IoU", "FID", "KIDx1000", "PSNR", "SSIM"):
                    column = f"{trajectory} | {metric}"
                    assert all(math.isfinite(v) for v in means[column]), column
    findings = (root / "results" / "quick" / "findings.md").read_text()
    assert "## Table 1: reconstruction baselines and ReconDreamer" in findings and "## Metric validity" in findings
    assert "fewer than 3 segments" in findings  # the quick config has one segment: no verdict claims significance
    report = subprocess.run([sys.executable, "-m", "snakemake", "--configfile", "config/quick.yaml", "--report", "report.html"],
                            check=False, cwd=root, capture_output=True, text=True, timeout=600)
    assert report.returncode == 0, report.stderr[-5000:]
    assert (root / "report.html").stat().st_size > 10_000
