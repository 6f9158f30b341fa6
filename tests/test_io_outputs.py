"""Output paths are safe: an --out that names something other than an earlier output of the same
command is refused before anything is written, options shared by many commands are checked in one
place, and a run resumes only on the scene it started on."""

from __future__ import annotations

import errno
import os
import shutil
import signal
import subprocess
import sys

import pytest

from recondreamer.cli import main
from recondreamer.io import (
    OUTPUT_MARKER,
    SNAKEMAKE_FOLDER_STAMP,
    OutputPathError,
    OutputWriteError,
    atomic_directory,
    atomic_path,
    output_kind,
    restamp_edited_folder,
    write_text_atomic,
)

TINY_SCENE = ["--preset", "quick", "--frames", "3", "--width", "64", "--height", "48", "--no-novel"]


def synth(out, seed=5, *extra):
    return main(["synth", "--seed", str(seed), "--out", str(out), *TINY_SCENE, *extra])


class TestAtomicDirectory:
    def test_marks_its_kind_and_replaces_an_output_of_the_same_kind(self, tmp_path):
        out = tmp_path / "renders"
        with atomic_directory(out, "renders") as tmp:
            (tmp / "a.png").write_bytes(b"1")
        assert output_kind(out) == "renders" and (out / OUTPUT_MARKER).is_file()
        with atomic_directory(out, "renders") as tmp:
            (tmp / "b.png").write_bytes(b"2")
        assert sorted(p.name for p in out.iterdir()) == [OUTPUT_MARKER, "b.png"]

    def test_an_empty_folder_may_be_filled(self, tmp_path):
        (tmp_path / "empty").mkdir()
        with atomic_directory(tmp_path / "empty", "frames") as tmp:
            (tmp / "000.png").write_bytes(b"1")
        assert (tmp_path / "empty" / "000.png").is_file()

    @pytest.mark.parametrize("existing", ["file", "folder", "other kind", "symlink"])
    def test_refuses_anything_else_and_writes_nothing(self, tmp_path, existing):
        out = tmp_path / "out"
        if existing == "file":
            out.write_text("keep")
        elif existing == "symlink":
            (tmp_path / "target").mkdir()
            out.symlink_to(tmp_path / "target")
        else:
            out.mkdir()
            (out / "keep.txt").write_text("keep")
            if existing == "other kind":
                (out / OUTPUT_MARKER).write_text("scene\n")
        before = sorted(p.name for p in tmp_path.iterdir())
        with pytest.raises(OutputPathError, match="refusing to replace it with a renders"):
            with atomic_directory(out, "renders"):
                pytest.fail("the block must not run")
        assert sorted(p.name for p in tmp_path.iterdir()) == before  # no temporary folder left
        if existing in ("folder", "other kind"):
            assert (out / "keep.txt").read_text() == "keep"
        if existing == "file":
            assert out.read_text() == "keep"


def _killed_mid_write(target, directory: bool) -> list:
    """Start a process that writes ``target`` atomically and hangs inside the write, kill -9 it,
    and return the temporaries it left beside ``target``."""
    helper = "atomic_directory(target, 'frames')" if directory else "atomic_path(target)"
    code = (
        "import sys, time\nfrom pathlib import Path\nfrom recondreamer.io import atomic_directory, atomic_path\n"
        f"target = Path(sys.argv[1])\nwith {helper} as tmp:\n    print(tmp, flush=True)\n    time.sleep(60)\n"
    )
    process = subprocess.Popen([sys.executable, "-c", code, str(target)], stdout=subprocess.PIPE, text=True)
    process.stdout.readline()  # the write has started
    process.send_signal(signal.SIGKILL)
    process.wait()
    return sorted(target.parent.glob(f".{target.name}.*.tmp"))


class TestRestampEditedFolder:
    """A file edited inside a finished folder output dates the folder (Snakemake's stamp file)."""

    @staticmethod
    def finished_folder(tmp_path):
        folder = tmp_path / "scene"
        (folder / "images").mkdir(parents=True)
        for name in ("scene.json", "images/000.png"):
            (folder / name).write_bytes(b"x")
            os.utime(folder / name, ns=(1_000_000_000, 1_000_000_000))
        (folder / SNAKEMAKE_FOLDER_STAMP).touch()
        os.utime(folder / SNAKEMAKE_FOLDER_STAMP, ns=(2_000_000_000, 2_000_000_000))
        return folder

    def test_an_untouched_folder_keeps_its_date(self, tmp_path):
        folder = self.finished_folder(tmp_path)
        assert restamp_edited_folder(folder) == []
        assert (folder / SNAKEMAKE_FOLDER_STAMP).stat().st_mtime_ns == 2_000_000_000

    def test_an_edit_in_a_subfolder_moves_the_stamp_to_the_edit(self, tmp_path):
        folder = self.finished_folder(tmp_path)
        os.utime(folder / "images" / "000.png", ns=(5_000_000_000, 5_000_000_000))
        assert restamp_edited_folder(folder) == [folder / "images" / "000.png"]
        assert (folder / SNAKEMAKE_FOLDER_STAMP).stat().st_mtime_ns == 5_000_000_000
        assert restamp_edited_folder(folder) == []  # dated once: the next parse sees nothing new

    def test_a_folder_without_a_stamp_or_missing_is_left_alone(self, tmp_path):
        folder = self.finished_folder(tmp_path)
        (folder / SNAKEMAKE_FOLDER_STAMP).unlink()
        os.utime(folder / "scene.json", ns=(9_000_000_000, 9_000_000_000))
        assert restamp_edited_folder(folder) == [] and not (folder / SNAKEMAKE_FOLDER_STAMP).exists()
        assert restamp_edited_folder(tmp_path / "absent") == []


class TestKilledWrites:
    @pytest.mark.parametrize("directory", [False, True])
    def test_the_next_write_removes_what_a_killed_writer_left(self, tmp_path, directory):
        target = tmp_path / ("renders" if directory else "metrics.json")
        left = _killed_mid_write(target, directory)
        assert len(left) == 1  # kill -9 gives the writer no chance to clean up
        if directory:
            with atomic_directory(target, "frames") as tmp:
                (tmp / "000.png").write_bytes(b"1")
        else:
            write_text_atomic(target, "{}")
        assert not left[0].exists() and target.exists()
        assert list(tmp_path.glob(".*.tmp")) == []

    def test_a_live_writers_temporary_is_kept(self, tmp_path):
        target = tmp_path / "metrics.json"
        with atomic_path(target) as inflight:
            inflight.write_text("partial")
            write_text_atomic(target, "{}")  # a second writer of the same file meanwhile
            assert inflight.read_text() == "partial"
        assert target.read_text() == "partial"  # the first writer's rename came last


def _no_space(path) -> OSError:
    return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))


class TestFullDisk:
    """A write that runs out of space is one error naming the output; the earlier output stays
    and no temporary is left (benchmarks/faults.py fills a real tmpfs)."""

    def test_a_file_keeps_its_earlier_version(self, tmp_path):
        out = tmp_path / "model.pt"
        out.write_bytes(b"earlier")
        match = r"model.pt: could not be written: no space left on its file system.*earlier one is unchanged"
        with pytest.raises(OutputWriteError, match=match), atomic_path(out) as tmp:
            tmp.write_bytes(b"half")
            raise _no_space(tmp)
        assert out.read_bytes() == b"earlier" and sorted(tmp_path.iterdir()) == [out]

    def test_a_new_directory_leaves_nothing(self, tmp_path):
        with pytest.raises(OutputWriteError, match=r"scene: could not be written.*nothing was written"), atomic_directory(tmp_path / "scene", "scene") as tmp:
            (tmp / "a.png").write_bytes(b"1")
            raise _no_space(tmp / "b.png")
        assert list(tmp_path.iterdir()) == []

    def test_a_failed_swap_puts_the_earlier_directory_back(self, tmp_path, monkeypatch):
        out = tmp_path / "scene"
        with atomic_directory(out, "scene") as tmp:
            (tmp / "old.png").write_bytes(b"earlier")
        real_replace = os.replace

        def replace(source, destination):  # the new directory cannot be renamed into place
            if str(source).endswith(".tmp") and os.fspath(destination) == os.fspath(out):
                raise _no_space(destination)
            return real_replace(source, destination)

        monkeypatch.setattr(os, "replace", replace)
        with pytest.raises(OutputWriteError, match="earlier one is unchanged"), atomic_directory(out, "scene") as tmp:
            (tmp / "new.png").write_bytes(b"new")
        assert sorted(p.name for p in tmp_path.iterdir()) == ["scene"]  # no .old or .tmp sibling
        assert (out / "old.png").read_bytes() == b"earlier"

    def test_a_writer_that_hides_the_os_error_on_a_full_disk(self, tmp_path, monkeypatch):
        # torch.save to a path reports a full disk as RuntimeError("... unexpected pos ..."), no errno.
        monkeypatch.setattr(shutil, "disk_usage", lambda path: shutil._ntuple_diskusage(1 << 30, 1 << 30, 0))
        with pytest.raises(OutputWriteError, match="0 bytes free"), atomic_path(tmp_path / "checkpoint.pt"):
            raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 704 vs 598")
        assert list(tmp_path.iterdir()) == []

    def test_other_errors_are_not_taken_for_a_full_disk(self, tmp_path):
        with pytest.raises(RuntimeError, match="a bug"), atomic_path(tmp_path / "checkpoint.pt"):
            raise RuntimeError("a bug")
        with pytest.raises(FileNotFoundError), atomic_directory(tmp_path / "scene", "scene"):
            (tmp_path / "missing-input.json").read_text()
        assert list(tmp_path.iterdir()) == []

    def test_synth_prints_one_line(self, tmp_path, capsys, monkeypatch):
        import numpy as np

        def save(file, *args, **kwargs):
            raise _no_space(file)

        monkeypatch.setattr(np, "save", save)
        assert synth(tmp_path / "scene") == 1
        err = capsys.readouterr().err
        assert f"recondreamer synth: error: {tmp_path / 'scene'}: could not be written: no space left" in err
        assert "Traceback" not in err and list(tmp_path.iterdir()) == []


class TestOutPaths:
    def test_a_second_synth_replaces_its_own_scene(self, tmp_path):
        assert synth(tmp_path / "scene") == 0
        assert synth(tmp_path / "scene", 6) == 0
        assert output_kind(tmp_path / "scene") == "scene"

    def test_synth_refuses_a_file_an_unrelated_folder_and_the_working_directory(self, tmp_path, capsys, monkeypatch):
        (tmp_path / "notes.txt").write_text("keep")
        (tmp_path / "project").mkdir()
        (tmp_path / "project" / "data.csv").write_text("keep")
        assert synth(tmp_path / "notes.txt") == 1
        assert "notes.txt: exists and is not a directory" in capsys.readouterr().err
        assert synth(tmp_path / "project") == 1
        assert "project: exists and is not marked as a recondreamer output" in capsys.readouterr().err
        monkeypatch.chdir(tmp_path / "project")
        assert synth(".") == 1
        assert "is the working directory" in capsys.readouterr().err
        assert (tmp_path / "notes.txt").read_text() == "keep" and (tmp_path / "project" / "data.csv").read_text() == "keep"
        assert sorted(os.listdir(tmp_path / "project")) == ["data.csv"]  # no hidden temporary folder

    def test_convert_waymo_refuses_its_input_and_the_folder_holding_it(self, tmp_path, capsys):
        record = tmp_path / "segment.tfrecord"
        record.write_bytes(b"not read: the output is checked first")
        for out in (record, tmp_path):
            assert main(["convert-waymo", str(record), "--out", str(out)]) == 1
            assert "refusing to replace it with a scene" in capsys.readouterr().err
        assert record.read_bytes() == b"not read: the output is checked first"
        assert sorted(p.name for p in tmp_path.iterdir()) == ["segment.tfrecord"]

    def test_render_refuses_the_scene_it_reads(self, tmp_path, capsys):
        scene = tmp_path / "scene"
        assert synth(scene) == 0
        run = tmp_path / "run"
        assert main(["train-recon", "--scene", str(scene), "--model", "street", "--preset", "quick", "--iterations", "2", "--out", str(run)]) == 0
        capsys.readouterr()
        assert main(["render", "--run", str(run), "--trajectory", "shift@3", "--out", str(scene)]) == 1
        assert "exists and is a scene output; refusing to replace it with a renders" in capsys.readouterr().err
        assert (scene / "scene.json").is_file()


class TestSharedOptions:
    @pytest.mark.parametrize(("option", "value", "message"), [("--threads", "0", "--threads 0: must be a positive integer"),
                                                               ("--threads", "-1", "--threads -1: must be a positive integer"),
                                                               ("--seed", "-1", "--seed -1: must be a non-negative integer")])
    def test_train_recon_names_the_option(self, tmp_path, capsys, option, value, message):
        scene = tmp_path / "scene"
        assert synth(scene) == 0
        capsys.readouterr()
        arguments = {"--threads": "1", "--seed": "0", option: value}
        command = ["train-recon", "--scene", str(scene), "--model", "street", "--preset", "quick", "--iterations", "2", "--out", str(tmp_path / "run")]
        for name, given in arguments.items():
            command += [name, given]
        assert main(command) == 1
        assert message in capsys.readouterr().err
        assert not (tmp_path / "run").exists()

    def test_restore_refuses_threads_zero(self, tmp_path, capsys):
        assert main(["restore", "--restorer", str(tmp_path / "r.pt"), "--renders", str(tmp_path), "--scene", str(tmp_path),
                     "--trajectory", "shift@3", "--out", str(tmp_path / "out"), "--threads", "0"]) == 1
        assert "--threads 0: must be a positive integer" in capsys.readouterr().err


class TestRunResume:
    def test_train_recon_out_naming_a_file(self, tmp_path, capsys):
        scene = tmp_path / "scene"
        assert synth(scene) == 0
        (tmp_path / "run").write_text("keep")
        capsys.readouterr()
        assert main(["train-recon", "--scene", str(scene), "--model", "street", "--preset", "quick", "--iterations", "2", "--out", str(tmp_path / "run")]) == 1
        assert "run: exists and is not a directory" in capsys.readouterr().err
        assert (tmp_path / "run").read_text() == "keep"

    def test_a_run_does_not_continue_on_another_scene_with_the_same_id(self, tmp_path, capsys):
        run = tmp_path / "run"
        train = ["train-recon", "--model", "street", "--preset", "quick", "--iterations", "2", "--out", str(run)]
        assert main(["synth", "--seed", "5", "--scene-id", "same", "--out", str(tmp_path / "a"), *TINY_SCENE]) == 0
        assert main(["synth", "--seed", "6", "--scene-id", "same", "--out", str(tmp_path / "b"), *TINY_SCENE]) == 0
        assert main([*train, "--scene", str(tmp_path / "a")]) == 0
        run_json = (run / "run.json").read_text()
        capsys.readouterr()
        assert main([*train, "--scene", str(tmp_path / "b")]) == 1
        assert "differs in scene content (fingerprint)" in capsys.readouterr().err
        assert (run / "run.json").read_text() == run_json
        assert main([*train, "--scene", str(tmp_path / "a")]) == 0  # the same scene still resumes

    def test_train_log_marks_a_resume(self, tmp_path):
        scene = tmp_path / "scene"
        assert synth(scene) == 0
        run = tmp_path / "run"
        train = ["train-recon", "--scene", str(scene), "--model", "street", "--preset", "quick", "--out", str(run)]
        assert main([*train, "--iterations", "4"]) == 0
        # The same run asked for more iterations is a different config; a checkpoint mid-way is what a kill leaves.
        from recondreamer.recon.checkpoint import CHECKPOINT_NAME, read_record, save_record

        record = read_record(run / CHECKPOINT_NAME)
        record["step"] = 2
        save_record(run / CHECKPOINT_NAME, record)
        assert main([*train, "--iterations", "4"]) == 0
        assert "resumed from checkpoint.pt at step 2/4" in (run / "train.log").read_text()


class TestWaymoInputs:
    def test_an_empty_file_and_a_folder_get_their_own_message(self, tmp_path, capsys):
        (tmp_path / "empty.tfrecord").write_bytes(b"")
        assert main(["convert-waymo", str(tmp_path / "empty.tfrecord"), "--out", str(tmp_path / "a")]) == 1
        assert "empty.tfrecord: holds no records (0 bytes): not a Waymo Open Dataset segment" in capsys.readouterr().err
        (tmp_path / "segments").mkdir()
        assert main(["convert-waymo", str(tmp_path / "segments"), "--out", str(tmp_path / "b")]) == 1
        assert "segments: is a folder; give one segment's .tfrecord file" in capsys.readouterr().err
        assert sorted(p.name for p in tmp_path.iterdir()) == ["empty.tfrecord", "segments"]
