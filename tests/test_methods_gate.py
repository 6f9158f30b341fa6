"""Issue 7's gate script (benchmarks/methods_gate.py): the comparison and verdicts from metric
files written here, and a dry run of the quick config asking the workflow for the gate's runs."""

import importlib.util
import json
import re
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from recondreamer.report.layout import metrics_file

REPO = Path(__file__).resolve().parents[1]
SPEC = importlib.util.spec_from_file_location("methods_gate", REPO / "benchmarks" / "methods_gate.py")
gate = importlib.util.module_from_spec(SPEC)
sys.modules[SPEC.name] = gate  # dataclasses look their module up while the script loads
SPEC.loader.exec_module(gate)

TRAJECTORIES = ("shift@3", "shift@6", "lane_change")
RUNS = ("baseline-street", "dd4d-street", "recondreamer-street-dd2_mask-stride1.5", "recondreamer-street-dd2_mask-stride6.0")


def workflow_copy(tmp_path: Path) -> Path:
    root = tmp_path / "wf"
    root.mkdir()
    for name in ("Snakefile", "workflow", "config", "profiles"):
        source = REPO / name
        (shutil.copytree if source.is_dir() else shutil.copy)(source, root / name)
    return root


def two_segment_config(root: Path) -> str:
    """The quick config with two segments (the report averages over segments), written into the workflow copy."""
    config = yaml.safe_load((root / "config" / "quick.yaml").read_text())
    config["synthetic"]["segments"] = {"quick-01": 101, "quick-02": 102}
    (root / "config" / "gate-test.yaml").write_text(yaml.safe_dump(config))
    return "config/gate-test.yaml"


def write_metrics(results: Path, segments, seed: int = 0) -> dict:
    """Evaluate-style metric files of the gate's street runs; returns {(segment, run, trajectory): values}."""
    rng = np.random.default_rng(seed)
    raw = {}
    for segment in segments:
        for run in RUNS:
            document = {}
            for trajectory in TRAJECTORIES:
                values = {"nta_iou": rng.uniform(0.1, 0.6), "ntl_iou": rng.uniform(0.3, 0.6), "fid": rng.uniform(50, 200),
                          "psnr": rng.uniform(15, 30), "ssim": rng.uniform(0.3, 0.9)}
                raw[(segment, run, trajectory)] = values
                document[trajectory] = {"nta_iou": {"nta_iou": values["nta_iou"]}, "ntl_iou": {"ntl_iou": values["ntl_iou"]},
                                        "fid": {"fid": values["fid"]},
                                        "truth": {"psnr": {"mean": values["psnr"]}, "ssim": {"mean": values["ssim"]}}}
            path = metrics_file(results, segment, run)
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(json.dumps({"trajectories": document}))
    return raw


def test_report_prints_segment_means_and_the_papers_verdicts(tmp_path, capsys):
    root = workflow_copy(tmp_path)
    segments = ("quick-01", "quick-02")
    raw = write_metrics(root / "results" / "quick", segments)
    code = gate.main(["--directory", str(root), "--configfile", two_segment_config(root), "--backbones", "street", "--report-only"])
    assert code == 0
    out = capsys.readouterr().out
    assert "8 of 8 metric files present" in out

    def mean(run, trajectory, metric):
        return np.mean([raw[(s, run, trajectory)][metric] for s in segments])

    # The table row of ReconDreamer 1.5 m: shift@6 PSNR and the FID averaged over the trajectories.
    row = next(line for line in out.splitlines() if line.startswith("| ReconDreamer 1.5 m |")).split("|")[2:-1]
    header = next(line for line in out.splitlines() if line.startswith("| method |")).split("|")[2:-1]
    cells = dict(zip((h.strip() for h in header), (c.strip() for c in row)))
    assert float(cells["Lane Shift @ 6m PSNR"]) == pytest.approx(mean(RUNS[2], "shift@6", "psnr"), abs=0.006)
    fid_average = np.mean([mean(RUNS[2], t, "fid") for t in TRAJECTORIES])
    assert float(cells["Average FID"]) == pytest.approx(fid_average, abs=0.006)
    assert float(cells["Lane Shift @ 6m NTL-IoU"]) == pytest.approx(100 * mean(RUNS[2], "shift@6", "ntl_iou"), abs=0.006)

    # Verdicts at shift@6, recomputed here: higher is better except FID.
    verdicts = {line for line in out.splitlines() if line.startswith("- street:")}
    for name, versus in (("ReconDreamer 1.5 m > baseline", RUNS[0]), ("ReconDreamer 1.5 m > DriveDreamer4D", RUNS[1]),
                         ("stride 1.5 m > stride 6.0 m", RUNS[3])):
        line = next(v for v in verdicts if name in v)
        for metric, label in (("nta_iou", "NTA-IoU"), ("fid", "FID"), ("psnr", "PSNR")):
            ours, theirs = mean(RUNS[2], "shift@6", metric), mean(versus, "shift@6", metric)
            holds = ours < theirs if metric == "fid" else ours > theirs
            wins = sum((raw[(s, RUNS[2], "shift@6")][metric] < raw[(s, versus, "shift@6")][metric]) == (metric == "fid") for s in segments)
            assert re.search(rf"{label} {'holds' if holds else 'FAILS'} \([^;]*; {wins}/2 segments\)", line), (label, line)


def test_report_with_missing_files_marks_cells_and_counts(tmp_path, capsys):
    root = workflow_copy(tmp_path)
    write_metrics(root / "results" / "quick", ("quick-01",))
    (root / "results" / "quick" / "metrics" / "quick-01" / "dd4d-street.json").unlink()
    assert gate.main(["--directory", str(root), "--configfile", two_segment_config(root), "--backbones", "street", "pvg", "--report-only"]) == 0
    out = capsys.readouterr().out
    assert "3 of 16 metric files present" in out
    dd4d_row = next(line for line in out.splitlines() if line.startswith("| DriveDreamer4D |"))
    assert {c.strip() for c in dd4d_row.split("|")[2:-1]} == {"-"}
    assert "(1)" in next(line for line in out.splitlines() if line.startswith("| baseline |"))  # 1 of 2 segments
    assert any("DriveDreamer4D at shift@6: NTA-IoU not measured" in line for line in out.splitlines())


def test_dry_run_asks_the_workflow_for_street_dd4d_and_both_strides(tmp_path, capfd):
    root = workflow_copy(tmp_path)
    config = yaml.safe_load((root / "config" / "quick.yaml").read_text())
    assert gate.main(["--directory", str(root), "--configfile", "config/quick.yaml", "--iterations", "7", "--dry-run"]) == 0
    text = "".join(capfd.readouterr())
    counts = dict(re.findall(r"^(\w+)\s+(\d+)$", text.split("Job stats:")[1], flags=re.MULTILINE))
    segments = len(config["synthetic"]["segments"])
    runs = 2 * 4  # street and pvg: baseline, DriveDreamer4D, ReconDreamer at 1.5 m and 6 m
    assert int(counts["evaluate"]) == runs * segments
    assert int(counts["train_dd4d"]) == 2 * segments and int(counts["train_recondreamer"]) == 4 * segments
    assert int(counts["generate_dd4d"]) == 3 * segments  # shared by both backbones
    assert int(counts["train_restorer"]) == 1  # only the main restorer
    assert "make_tables" not in counts
    # Bad arguments stop before Snakemake runs.
    with pytest.raises(SystemExit):
        gate.main(["--directory", str(root), "--configfile", "config/quick.yaml", "--segments", "nowhere", "--dry-run"])


def test_oracle_adds_truth_runs_with_no_restorer_behind_them(tmp_path, capfd):
    root = workflow_copy(tmp_path)
    segments = len(yaml.safe_load((root / "config" / "quick.yaml").read_text())["synthetic"]["segments"])
    assert gate.main(["--directory", str(root), "--configfile", "config/quick.yaml", "--backbones", "street",
                      "--methods", "baseline", "recondreamer", "--oracle", "--dry-run"]) == 0
    counts = dict(re.findall(r"^(\w+)\s+(\d+)$", "".join(capfd.readouterr()).split("Job stats:")[1], flags=re.MULTILINE))
    assert int(counts["train_recondreamer_truth"]) == 2 * segments  # strides 1.5 and 6
    assert int(counts["train_recondreamer"]) == 2 * segments
    assert int(counts["evaluate"]) == 5 * segments  # baseline, 2 restored, 2 oracle
    runs = gate.gate_runs(["street"], [1.5, 6.0], "dd2_mask", ["recondreamer"], oracle=True)
    assert [r.method.run_id for r in runs][2:] == ["recondreamer-street-truth-stride1.5", "recondreamer-street-truth-stride6.0"]


def test_local_restorer_checkpoint_needs_no_restorer_training(tmp_path, capfd):
    root = workflow_copy(tmp_path)
    checkpoint = tmp_path / "restorer.pt"
    checkpoint.write_bytes(b"")  # a dry run only checks that it exists
    assert gate.main(["--directory", str(root), "--configfile", "config/quick.yaml", "--backbones", "street",
                      "--methods", "recondreamer", "--restorer-checkpoint", str(checkpoint), "--dry-run"]) == 0
    counts = dict(re.findall(r"^(\w+)\s+(\d+)$", "".join(capfd.readouterr()).split("Job stats:")[1], flags=re.MULTILINE))
    assert "train_restorer" not in counts and "pretrain_world_model" not in counts
    assert int(counts["train_recondreamer"]) >= 2
    with pytest.raises(SystemExit):
        gate.main(["--directory", str(root), "--configfile", "config/quick.yaml", "--restorer-checkpoint", str(tmp_path / "absent.pt")])
