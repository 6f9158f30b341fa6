"""End to end: the quick foundation config builds a weight set, then the quick experiment runs on
it, through Snakemake in a temporary directory, then the report. The runs take minutes, hence the
slow mark; they fail whenever the workflow fails."""

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml

from workflow_fixtures import EXPERIMENT_CONFIGS, QUICK_WEIGHTS, TRAINING_COMMANDS, snakemake


def on_weights(root: Path, weights: str) -> tuple[str, str]:
    """Config files for the quick experiment on the weight set ``weights``."""
    (root / "on-weights.yaml").write_text(yaml.safe_dump({"foundation": {"weights": weights}}))
    return "config/quick.yaml", "on-weights.yaml"


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_quick_foundation_publishes_a_verified_weight_set(quick_foundation):
    for command in (*TRAINING_COMMANDS, "make-cycle-pairs", "foundation-gates", "weights publish"):
        assert f"recondreamer {command} " in quick_foundation.log, command
    weights = quick_foundation.root / QUICK_WEIGHTS
    verify = subprocess.run([sys.executable, "-m", "recondreamer", "weights", "verify", str(weights)], check=False, capture_output=True, text=True)
    assert verify.returncode == 0 and "11 files verified" in verify.stdout, verify.stderr
    manifest = json.loads((weights / "manifest.json").read_text())
    assert manifest["corpus"]["seeds"] == [10000, 10003] and manifest["gate_scenes"]["seeds"] == [20000]
    assert manifest["files"]["restorer_svd.pt"]["command"].startswith("recondreamer train-restorer --arch svd ")
    assert {entry["training"].get("steps") for name, entry in manifest["files"].items() if name.startswith("restorer_")} == {20}
    report = (weights / "GATES.md").read_text()
    for row in ("| dd2_mask | shift@3 |", "| dd2_mask | shift@6 |", "| dd2_mask | original |", "| sd | shift@6 |", "| autoencoder |", "| vehicle detector |"):
        assert row in report, row
    assert "- cycle pairs:" in report  # the recipe's addition, named
    assert "| vehicle detector | AP50, 1 gate scene(s) |" in report and "Detector AP50 per scene: gate-000 " in report


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_quick_experiment_on_the_weight_set_trains_no_foundation_model(quick_experiment):
    root = quick_experiment.root
    for command in TRAINING_COMMANDS:
        assert f"recondreamer {command} " not in quick_experiment.log, command
    assert not (root / "results" / "quick" / "models").exists() and not (root / "results" / "quick" / "eval_models").exists()
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
    assert f"from the weight set {QUICK_WEIGHTS}" in (tables / "table1.md").read_text()
    report = snakemake(root, "--configfile", *EXPERIMENT_CONFIGS, "--report", "report.html", timeout=600)
    assert report.returncode == 0, report.stderr[-5000:]
    assert (root / "report.html").stat().st_size > 10_000


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_an_altered_missing_or_foreign_file_stops_the_run_at_parse_time(quick_foundation):
    root = quick_foundation.root
    source = root / QUICK_WEIGHTS
    cases = {
        "altered": (lambda d: (d / "restorer_dd2_mask.pt").open("ab").write(b"\0"), "restorer_dd2_mask.pt: altered: sha256"),
        "missing": (lambda d: (d / "world_model_dd2.pt").unlink(), "world_model_dd2.pt: missing"),
        "foreign": (swap_in_a_detector, "restorer_sd.pt: an architecture this code cannot load as restorer sd"),
    }
    for name, (damage, message) in cases.items():
        copy = root / f"weights-{name}"
        shutil.copytree(source, copy)
        damage(copy)
        result = snakemake(root, "-n", "--configfile", *on_weights(root, copy.name), timeout=300)
        assert result.returncode != 0 and message in result.stdout + result.stderr, (name, result.stdout[-2000:] + result.stderr[-2000:])
        assert "train-restorer" not in result.stdout
    # Evaluation seeds the set's models saw are refused.
    (root / "seen.yaml").write_text(yaml.safe_dump({"synthetic": {"segments": {"seen": 10001}}}))
    result = snakemake(root, "-n", "--configfile", *EXPERIMENT_CONFIGS, "seen.yaml", timeout=300)
    assert result.returncode != 0 and "synthetic.segments seeds [10001] are corpus or gate seeds of the weight set" in result.stdout + result.stderr


def swap_in_a_detector(folder: Path) -> None:
    """The detector's file under the sd restorer's name, with the manifest's hash made to match."""
    from recondreamer.foundation.weights import sha256_file

    shutil.copyfile(folder / "vehicle_detector.pt", folder / "restorer_sd.pt")
    manifest = json.loads((folder / "manifest.json").read_text())
    manifest["files"]["restorer_sd.pt"]["sha256"] = sha256_file(folder / "restorer_sd.pt")
    (folder / "manifest.json").write_text(json.dumps(manifest))
