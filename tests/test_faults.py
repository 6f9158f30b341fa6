"""The fast part of the fault-injection suite (benchmarks/faults.py): damaged inputs of most kinds
and a kill -9 inside train-recon and inside evaluate, run through the real commands; and the suite's own checks,
which must be able to say FAILED. The whole suite: python benchmarks/faults.py."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest
import torch

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "faults.py"


def _load_suite():
    spec = importlib.util.spec_from_file_location("recondreamer_faults", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the file runs
    spec.loader.exec_module(module)
    return module


faults = _load_suite()

# One input of each kind the CLI reads (the script checks a few more of the same kinds).
FAST_CORRUPT_INPUTS = (
    "scene_json",
    "scene_image",
    "scene_depth",
    "tfrecord_garbage",
    "tfrecord_empty",
    "recon_checkpoint",
    "generative_checkpoint",
    "pose_file",
    "weight_set",
    "metrics_tables",
    "study_csv_binary",
    "config_value",
)


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    return faults.Workspace(tmp_path_factory.mktemp("faults"), seed=0, log=lambda text: None)


class TestCorruptInputs:
    @pytest.mark.parametrize("name", FAST_CORRUPT_INPUTS)
    def test_the_reading_command_names_the_file_and_writes_nothing(self, workspace, name):
        row = faults.CORRUPT_INPUTS[name](workspace)
        assert row.ok, faults.markdown_table([row])


class TestKillInTrainRecon:
    def test_resumes_and_ends_equal_to_an_uninterrupted_run(self, workspace):
        rows = faults.recon_kill(workspace)
        assert all(row.ok for row in rows), faults.markdown_table(rows)


class TestKillInEvaluate:
    def test_resumes_and_ends_equal_to_an_uninterrupted_job(self, workspace):
        rows = faults.evaluate_kill(workspace)
        assert all(row.ok for row in rows), faults.markdown_table(rows)


class TestTheSuitesChecks:
    """The verdicts can fail: a traceback, an unnamed file, a written --out, a changed tensor and a
    half-written file are each caught."""

    def completed(self, returncode: int, stderr: str):
        return faults.Completed(["x"], returncode, "", stderr, 0.0)

    def test_one_line_error(self):
        good = self.completed(1, "12:00:00 INFO loading\nrecondreamer render: error: runs/a/model.pt: not a readable torch checkpoint\n")
        assert faults.check_one_line_error(good, "runs/a/model.pt")[0]
        traceback = self.completed(1, "Traceback (most recent call last):\n  File ...\nzipfile.BadZipFile: File is not a zip file\n")
        assert not faults.check_one_line_error(traceback, "runs/a/model.pt")[0]
        assert not faults.check_one_line_error(self.completed(1, "recondreamer render: error: something is wrong\n"), "runs/a/model.pt")[0]
        assert not faults.check_one_line_error(self.completed(0, ""), "runs/a/model.pt")[0]

    def test_nothing_written(self, tmp_path):
        assert faults.nothing_written(tmp_path / "out")[0]
        (tmp_path / ".out.host.1.abc.tmp").write_text("")
        assert not faults.nothing_written(tmp_path / "out")[0]
        (tmp_path / "run").mkdir()
        before = faults.file_state(tmp_path / "run")
        (tmp_path / "run" / "model.pt").write_bytes(b"1")
        assert not faults.nothing_written(tmp_path / "run", before)[0]

    def test_compare_values_reports_the_largest_difference(self):
        a = {"state": {"w": torch.zeros(3), "b": torch.ones(2)}, "step": 100, "metrics": {"ms_per_step": 3.0}}
        b = {"state": {"w": torch.tensor([0.0, 0.5, -2.0]), "b": torch.ones(2)}, "step": 100, "metrics": {"ms_per_step": 4.0}}
        difference = faults.compare_values(a, b, ignore=("ms_per_step",))
        assert difference.numeric == ["state.w"] and difference.max_abs == 2.0 and difference.other == []
        assert faults.compare_values(a, dict(a, step=200)).other == ["step"]
        assert faults.compare_values(a, a, ignore=()).identical

    def test_compare_trees_and_half_written_files(self, tmp_path):
        for name in ("a", "b"):
            (tmp_path / name).mkdir()
            torch.save({"x": torch.arange(4.0)}, tmp_path / name / "model.pt")
        assert faults.compare_trees(tmp_path / "a", tmp_path / "b").identical
        torch.save({"x": torch.arange(4.0) * 2}, tmp_path / "b" / "model.pt")
        assert faults.compare_trees(tmp_path / "a", tmp_path / "b").max_abs == 3.0
        assert faults.half_written(tmp_path / "a") == []
        faults.truncate(tmp_path / "a" / "model.pt")
        (tmp_path / "a" / ".scene.host.7.x.tmp").mkdir()
        (tmp_path / "a" / ".scene.host.7.x.tmp" / "000.png").write_bytes(b"")  # part of the temporary, not listed apart
        found = faults.half_written(tmp_path / "a")
        assert len(found) == 2 and found[0].endswith("(temporary)") and found[1].startswith("model.pt")

    def test_a_kill_may_leave_a_temporary_that_the_rerun_removes_but_no_broken_final_file(self, tmp_path):
        temporary = [".out.host.7.x.tmp (temporary)"]
        assert faults.resume_row("kill", "k", "h", [], temporary, tmp_path).ok  # swept by the rerun: tmp_path is clean
        assert "which the rerun removed" in faults.resume_row("kill", "k", "h", [], temporary, tmp_path).happened
        assert not faults.resume_row("kill", "k", "h", [], ["model.pt (truncated)"], tmp_path).ok
        (tmp_path / ".out.host.7.x.tmp").mkdir()
        assert not faults.resume_row("kill", "k", "h", [], temporary, tmp_path).ok  # still there at the end
        assert not faults.resume_row("kill", "k", "h", ["differs"], [], tmp_path / "nowhere").ok
