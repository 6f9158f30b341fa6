"""Reliability figures from one fault-injection suite.

Injects faults into the real commands on quick-sized data in a temporary folder and prints one
Markdown row per check: case | what was injected | what happened | anything lost or
half-written | verdict (ok / FAILED). Cases, cheapest first:

  corrupt_inputs    every kind of input the CLI reads, damaged: the reading command must exit
                    non-zero with one line naming the file (no traceback) and write nothing
  recon_kill        kill -9 inside train-recon after its first checkpoint, same command again:
                    it resumes and ends equal to an uninterrupted run
  restorer_kill     the same for train-restorer (tiny world model, pairs from make-pairs)
  recondreamer_kill the same for train-recondreamer, killed during a PDUS update and between two updates
  evaluate_kill     the same for evaluate, killed once its first renders exist
  disk_full         a scene and a checkpoint written to a tmpfs that fills up (or an injected
                    ENOSPC where mounting is impossible): one-line error, the earlier file intact
  second_snakemake  a second snakemake on a results folder a first one is writing
  workflow_kills    kill -9 of the whole quick workflow at --workflow-kills random moments,
                    then snakemake until it finishes: tables equal an uninterrupted run's
  scene_changed     one scene file modified after a finished workflow: the dry run plans exactly
                    the jobs that depend on it

    python benchmarks/faults.py                                # every case, table on stdout
    python benchmarks/faults.py --out docs/reliability.md      # also writes the doc page
    python benchmarks/faults.py --cases corrupt_inputs recon_kill --keep

Importing this file runs nothing: tests/test_faults.py imports the cases and runs a fast subset.
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import json
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHIPPED_WEIGHTS = REPO / "recondreamer" / "weights"
WORKFLOW_FILES = ("Snakefile", "workflow", "config", "profiles")
QUICK_CONFIG = "config/quick.yaml"
QUICK_RESULTS = "results/quick"
TINY_SCENE = ["--preset", "quick", "--frames", "3", "--width", "64", "--height", "48"]
RECON_ITERATIONS = 300  # the quick preset's: checkpoints at 100 and 200, the final model at 300
RESTORER_STEPS = 260  # a resume file at step 200 (TrainConfig.checkpoint_every), done at 260
COMMAND_TIMEOUT = 600
WORKFLOW_TIMEOUT = 3 * 3600


# ------------------------------------------------------------------------------------ results


@dataclass
class Row:
    """One line of the table."""

    case: str
    injected: str
    happened: str
    lost: str
    ok: bool


HEADER = ("case", "what was injected", "what happened", "anything lost or half-written", "verdict")


def markdown_table(rows: Sequence[Row]) -> str:
    def cell(text: str) -> str:
        return " ".join(str(text).split()).replace("|", "\\|")

    lines = ["| " + " | ".join(HEADER) + " |", "|" + "---|" * len(HEADER)]
    for row in rows:
        verdict = "ok" if row.ok else "**FAILED**"
        lines.append("| " + " | ".join(cell(c) for c in (row.case, row.injected, row.happened, row.lost)) + f" | {verdict} |")
    return "\n".join(lines) + "\n"


def quoted(text: str, limit: int = 170) -> str:
    """A message for a table cell: one line, at most ``limit`` characters."""
    text = " ".join(text.split())
    return f"`{text if len(text) <= limit else text[: limit - 1] + '…'}`".replace("``", "`")


# ------------------------------------------------------------------------------------ processes


@dataclass
class Completed:
    args: list[str]
    returncode: int
    stdout: str
    stderr: str
    seconds: float
    timed_out: bool = False

    @property
    def output(self) -> str:
        return self.stdout + self.stderr


def recondreamer(*args: str | os.PathLike) -> list[str]:
    return [sys.executable, "-m", "recondreamer", *map(str, args)]


def snakemake(*args: str | os.PathLike) -> list[str]:
    return [sys.executable, "-m", "snakemake", *map(str, args)]


def _environment() -> dict[str, str]:
    env = dict(os.environ)
    env.setdefault("OMP_NUM_THREADS", "1")
    env.setdefault("OMP_WAIT_POLICY", "passive")
    return env


def run(args: Sequence[str], cwd: Path, timeout: float = COMMAND_TIMEOUT) -> Completed:
    """Run a command in its own process group; on timeout the whole group is killed."""
    started = time.monotonic()
    process = subprocess.Popen(
        list(args), cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True, env=_environment()
    )
    try:
        stdout, stderr = process.communicate(timeout=timeout)
        timed_out = False
    except subprocess.TimeoutExpired:
        kill_group(process)
        stdout, stderr = process.communicate()
        timed_out = True
    return Completed(list(args), process.returncode, stdout, stderr, time.monotonic() - started, timed_out)


def start(args: Sequence[str], cwd: Path, log: Path) -> subprocess.Popen:
    """Start a command in a new process group, stdout and stderr to ``log`` (read it while it runs)."""
    log.parent.mkdir(parents=True, exist_ok=True)
    with open(log, "ab") as handle:
        return subprocess.Popen(list(args), cwd=cwd, stdout=handle, stderr=subprocess.STDOUT, start_new_session=True, env=_environment())


def group_members(pgid: int) -> list[int]:
    """Live processes of process group ``pgid`` (zombies excluded)."""
    members = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
        except OSError:
            continue
        fields = text[text.rindex(")") + 2 :].split()
        if int(fields[2]) == pgid and fields[0] != "Z":
            members.append(int(stat.parent.name))
    return members


def kill_group(process: subprocess.Popen) -> int:
    """kill -9 the process group of ``process`` (its leader's pid); returns how many processes
    were alive in it. Waits for the leader and until no member is left."""
    alive = len(group_members(process.pid))
    with contextlib.suppress(ProcessLookupError):
        os.killpg(process.pid, signal.SIGKILL)
    process.wait()
    wait_for(lambda: not group_members(process.pid), timeout=30)
    return alive


def wait_for(condition: Callable[[], bool], timeout: float, poll: float = 0.02) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(poll)
    return condition()


def kill_when_exists(process: subprocess.Popen, path: Path, timeout: float) -> bool:
    """kill -9 the group of ``process`` as soon as ``path`` exists; False if it never appeared
    (the process ended or the timeout passed first; the group is killed either way)."""
    appeared = wait_for(lambda: path.exists() or process.poll() is not None, timeout, poll=0.01) and path.exists()
    still_running = process.poll() is None
    kill_group(process)
    return appeared and still_running


def kill_after(process: subprocess.Popen, delay: float) -> bool:
    """kill -9 the group of ``process`` ``delay`` seconds after now; False if it had ended before."""
    ended = wait_for(lambda: process.poll() is not None, delay, poll=0.2)
    kill_group(process)
    return not ended


# ---------------------------------------------------------------------------------- file checks


def file_state(folder: Path) -> dict[str, tuple[int, int]]:
    """{relative path: (size, mtime_ns)} of every file below ``folder`` (nothing if absent)."""
    if not folder.exists():
        return {}
    if folder.is_file():
        stat = folder.stat()
        return {".": (stat.st_size, stat.st_mtime_ns)}
    return {str(p.relative_to(folder)): (p.stat().st_size, p.stat().st_mtime_ns) for p in sorted(folder.rglob("*")) if p.is_file()}


TEMPORARY = re.compile(r"^\..+\.(tmp|old)$")  # recondreamer.io's temporary siblings


def temporaries(folder: Path) -> list[Path]:
    """Temporary siblings of atomic writes below ``folder``."""
    return sorted(p for p in folder.rglob(".*") if TEMPORARY.match(p.name)) if folder.is_dir() else []


def unreadable(path: Path) -> str | None:
    """Why a finished-looking file does not load (None: it loads or is of a kind not checked)."""
    suffix = path.suffix
    try:
        if suffix == ".pt":
            import torch

            torch.load(path, map_location="cpu", weights_only=False)
        elif suffix == ".json":
            json.loads(path.read_text())
        elif suffix == ".npy":
            import numpy as np

            np.load(path, allow_pickle=False)
        elif suffix == ".npz":
            import numpy as np

            with np.load(path, allow_pickle=False) as arrays:
                for name in arrays.files:
                    arrays[name]
        elif suffix in (".png", ".jpg", ".webp"):
            from PIL import Image

            with Image.open(path) as image:
                image.load()
        elif suffix in (".yaml", ".yml"):
            import yaml

            yaml.safe_load(path.read_text())
    except Exception as error:  # anything that stops a load is what we are looking for
        return f"{type(error).__name__}: {error}"
    return None


def half_written(folder: Path) -> list[str]:
    """Temporaries, and files under their final names that do not load, below ``folder`` (what
    lies inside a temporary folder belongs to that temporary)."""
    problems = [f"{p.relative_to(folder)} (temporary)" for p in temporaries(folder)]
    if folder.is_dir():
        for path in sorted(folder.rglob("*")):
            inside_temporary = any(TEMPORARY.match(part) for part in path.relative_to(folder).parts)
            if path.is_file() and not inside_temporary and (why := unreadable(path)):
                problems.append(f"{path.relative_to(folder)} ({why[:80]})")
    return problems


def _leaves(value, prefix: str = "") -> Iterator[tuple[str, object]]:
    if isinstance(value, dict):
        for key, item in value.items():
            yield from _leaves(item, f"{prefix}{key}.")
    elif isinstance(value, (list, tuple)) and any(isinstance(v, (dict, list, tuple)) or type(v).__name__ == "Tensor" for v in value):
        for index, item in enumerate(value):
            yield from _leaves(item, f"{prefix}{index}.")
    else:
        yield prefix.rstrip("."), value


@dataclass
class Difference:
    """How two loaded records or two trees differ: the largest absolute difference of their
    arrays and tensors, and the names of whatever else differs."""

    max_abs: float = 0.0
    numeric: list[str] = field(default_factory=list)  # arrays/tensors that differ
    other: list[str] = field(default_factory=list)  # everything else that differs

    @property
    def identical(self) -> bool:
        return not self.numeric and not self.other

    def merge(self, other: Difference, prefix: str) -> None:
        self.max_abs = max(self.max_abs, other.max_abs)
        self.numeric += [f"{prefix}{n}" for n in other.numeric]
        self.other += [f"{prefix}{n}" for n in other.other]

    def describe(self, limit: int = 3) -> str:
        if self.identical:
            return "identical"
        parts = []
        if self.numeric:
            parts.append(f"{len(self.numeric)} array(s) differ, max |diff| {self.max_abs:.3g} ({', '.join(self.numeric[:limit])})")
        if self.other:
            parts.append(f"{len(self.other)} other entr(ies) differ ({', '.join(self.other[:limit])})")
        return "; ".join(parts)


def compare_values(a, b, ignore: Sequence[str] = ()) -> Difference:
    """Compare two loaded objects (nested dicts of tensors, arrays and plain values)."""
    import numpy as np

    def as_array(value):
        if type(value).__name__ == "Tensor":
            return value.detach().cpu().numpy()
        return value if isinstance(value, np.ndarray) else None

    result = Difference()
    left, right = dict(_leaves(a)), dict(_leaves(b))
    for key in sorted(set(left) | set(right)):
        if any(key == name or key.endswith("." + name) for name in ignore):
            continue
        if key not in left or key not in right:
            result.other.append(f"{key} (only in one)")
            continue
        x, y = as_array(left[key]), as_array(right[key])
        if x is not None or y is not None:
            if x is None or y is None or x.shape != y.shape or x.dtype != y.dtype:
                result.numeric.append(f"{key} (shape/type)")
                result.max_abs = float("inf")
            elif not np.array_equal(x, y, equal_nan=x.dtype.kind == "f"):
                result.numeric.append(key)
                if x.dtype.kind in "fiub" and x.size:
                    result.max_abs = max(result.max_abs, float(np.nanmax(np.abs(x.astype(np.float64) - y.astype(np.float64)))))
        elif left[key] != right[key]:
            result.other.append(key)
    return result


def load_for_comparison(path: Path):
    """A file's content as comparable values: arrays of .npy/.npz/images, loaded .pt and .json."""
    import numpy as np

    suffix = path.suffix
    if suffix == ".pt":
        import torch

        return torch.load(path, map_location="cpu", weights_only=False)
    if suffix == ".npy":
        return {"array": np.load(path, allow_pickle=False)}
    if suffix == ".npz":
        with np.load(path, allow_pickle=False) as arrays:
            return {name: arrays[name] for name in arrays.files}
    if suffix in (".png", ".jpg", ".webp"):
        from PIL import Image

        with Image.open(path) as image:
            return {"pixels": np.asarray(image.convert("RGB"))}
    if suffix == ".json":
        return json.loads(path.read_text())
    return None


def compare_trees(a: Path, b: Path, ignore_files: Sequence[str] = (), ignore_keys: Sequence[str] = ()) -> Difference:
    """Compare two folders file by file: byte-for-byte, and where the bytes differ by loaded
    content (arrays, tensors, JSON), reporting the largest numeric difference.
    ``ignore_files`` are glob patterns of relative paths to skip."""
    result = Difference()

    def files(root: Path) -> set[str]:
        return {
            str(p.relative_to(root))
            for p in root.rglob("*")
            if p.is_file() and not any(p.relative_to(root).match(g) for g in ignore_files)
        }

    left, right = files(a), files(b)
    for name in sorted(left ^ right):
        result.other.append(f"{name} (only in {'first' if name in left else 'second'})")
    for name in sorted(left & right):
        x, y = a / name, b / name
        if x.read_bytes() == y.read_bytes():
            continue
        loaded = load_for_comparison(x)
        if loaded is None:
            result.other.append(name)
            continue
        result.merge(compare_values(loaded, load_for_comparison(y), ignore_keys), f"{name}:")
    return result


# ------------------------------------------------------------------------------- error messages


def error_lines(result: Completed) -> list[str]:
    return [line for line in result.stderr.splitlines() if re.match(r"^recondreamer [\w -]+: error: ", line)]


def check_one_line_error(result: Completed, names: str) -> tuple[bool, str]:
    """Exit code non-zero, no Python traceback, exactly one error line and it names ``names``
    (a path as given on the command line). Returns (ok, what happened)."""
    problems = []
    if result.timed_out:
        problems.append("timed out")
    if result.returncode == 0:
        problems.append("exit code 0")
    if "Traceback (most recent call last)" in result.output:
        problems.append("Python traceback")
    lines = error_lines(result)
    if len(lines) != 1:
        problems.append(f"{len(lines)} error lines")
    elif names not in lines[0]:
        problems.append(f"the message does not name {names}")
    last = lines[0] if lines else (result.stderr.strip().splitlines() or ["(no output)"])[-1]
    happened = f"exit {result.returncode}: {quoted(last)}"
    return not problems, happened + (f" — {', '.join(problems)}" if problems else "")


def nothing_written(path: Path, before: dict | None = None) -> tuple[bool, str]:
    """``path`` absent (or, given ``before``, unchanged) and no temporary sibling beside it."""
    leftovers = [p.name for p in path.parent.glob(f".{path.name}.*")] if path.parent.is_dir() else []
    if before is None:
        ok = not path.exists() and not leftovers
        said = "nothing at --out" if ok else f"--out exists: {sorted(file_state(path))[:3]}"
    else:
        ok = file_state(path) == before and not leftovers
        said = "run folder unchanged" if ok else "run folder changed"
    if leftovers:
        said += f"; temporaries left: {leftovers}"
    return ok, said


# ------------------------------------------------------------------------------------ workspace


class Workspace:
    """The temporary folder the cases work in, with the valid inputs they share, each built
    once with the project's own commands."""

    def __init__(self, root: Path, seed: int, workflow_kills: int = 5, log: Callable[[str], None] = print):
        self.root = Path(root)
        self.seed = seed
        self.rng = random.Random(seed)
        self.workflow_kills = workflow_kills
        self.log = log
        self._built: dict[str, object] = {}

    def path(self, *parts: str) -> Path:
        """A path below the root, its parent folder created."""
        path = self.root.joinpath(*parts)
        path.parent.mkdir(parents=True, exist_ok=True)
        return path

    def folder(self, *parts: str) -> Path:
        """A folder below the root, created."""
        path = self.root.joinpath(*parts)
        path.mkdir(parents=True, exist_ok=True)
        return path

    def once(self, key: str, build: Callable[[], object]):
        if key not in self._built:
            self._built[key] = build()
        return self._built[key]

    def run(self, *args: str | os.PathLike, cwd: Path | None = None, timeout: float = COMMAND_TIMEOUT, must_pass: bool = False) -> Completed:
        result = run([str(a) for a in args], cwd or self.root, timeout)
        if must_pass and result.returncode != 0:
            raise RuntimeError(f"setup command failed ({result.returncode}): {' '.join(map(str, args))}\n{result.stderr[-3000:]}")
        return result

    def relative(self, path: Path) -> str:
        return os.path.relpath(path, self.root)

    # --- valid inputs -------------------------------------------------------------------------
    def scene(self) -> Path:
        """A tiny synthetic scene (3 frames of 64x48, true novel views), inside a corpus folder."""

        def build():
            out = self.path("inputs", "corpus", "seed5")
            self.run(*recondreamer("synth", "--seed", "5", *TINY_SCENE, "--out", self.relative(out)), must_pass=True)
            return out

        return self.once("scene", build)

    def recon_arguments(self, out: str) -> list[str]:
        """train-recon of the resume cases, run from the run's parent folder (same argv for every run)."""
        return recondreamer("train-recon", "--scene", str(self.scene()), "--model", "street", "--preset", "quick",
                            "--iterations", str(RECON_ITERATIONS), "--seed", "0", "--threads", "1", "--out", out)

    def full_run(self) -> Path:
        """An uninterrupted quick-preset run (snapshots at 100 and 200): the resume reference."""

        def build():
            parent = self.folder("recon", "uninterrupted")
            self.run(*self.recon_arguments("run"), cwd=parent, must_pass=True)
            return parent / "run"

        return self.once("full_run", build)

    def pairs(self) -> Path:
        """Restoration pairs made by make-pairs from the uninterrupted run's two snapshots."""

        def build():
            out = self.path("inputs", "pairs")
            self.run(*recondreamer("make-pairs", "--run", self.relative(self.full_run()), "--out", self.relative(out), "--stages", "2",
                                   "--threads", "1"), must_pass=True)
            return out

        return self.once("pairs", build)

    def evaluated(self) -> tuple[Path, Path]:
        """(metrics JSON, renders folder) of evaluate on the uninterrupted run with the shipped models."""

        def build():
            out = self.path("inputs", "metrics", "run.json")
            renders = self.folder("inputs", "renders")
            self.run(*recondreamer("evaluate", "--scene", self.relative(self.scene()), "--run", self.relative(self.full_run()),
                                   "--renders", self.relative(renders / "shift@3"), "--trajectory", "shift@3",
                                   "--renders", self.relative(renders / "original"), "--trajectory", "original",
                                   "--models", SHIPPED_WEIGHTS, "--threads", "1", "--out", self.relative(out)), must_pass=True)
            return out, renders

        return self.once("evaluated", build)

    def workflow_copy(self, name: str) -> Path:
        """A copy of the workflow (Snakefile, rules, configs, profiles) to run Snakemake in."""
        root = self.folder("workflows", name)
        for item in WORKFLOW_FILES:
            source = REPO / item
            if not (root / item).exists():
                (shutil.copytree if source.is_dir() else shutil.copy)(source, root / item)
        return root

    def finished_workflow(self) -> tuple[Path, float]:
        """The quick workflow run once, uninterrupted: (its root, wall seconds)."""

        def build():
            root = self.workflow_copy("uninterrupted")
            self.log("  quick workflow, uninterrupted ...")
            result = self.run(*snakemake("--cores", "2", "--configfile", QUICK_CONFIG), cwd=root, timeout=WORKFLOW_TIMEOUT)
            (root / "snakemake.log").write_text(result.output)
            if result.returncode != 0:
                raise RuntimeError(f"the uninterrupted quick workflow failed:\n{result.output[-3000:]}")
            return root, result.seconds

        return self.once("finished_workflow", build)


# ----------------------------------------------------------------------- case 1: corrupt inputs


def truncate(path: Path, keep: float = 0.5) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])


def garbage(path: Path, size: int = 3000, seed: int = 0) -> None:
    path.write_bytes(random.Random(seed).randbytes(size))


def flip_byte(path: Path, offset: int) -> None:
    data = bytearray(path.read_bytes())
    data[offset] ^= 0xFF
    path.write_bytes(bytes(data))


def _corrupt_row(ws: Workspace, injected: str, command: Sequence[str], names: Path, out: Path | None, before: dict | None = None) -> Row:
    """Run ``command`` on the damaged input ``names``; judge its message and its --out."""
    result = ws.run(*command)
    message_ok, happened = check_one_line_error(result, ws.relative(names))
    if out is None:
        written_ok, lost = True, "writes nothing by design"
    else:
        written_ok, lost = nothing_written(out, before)
    return Row("corrupt input", injected, happened, lost, message_ok and written_ok)


def damaged_scene(ws: Workspace, name: str, file: str, damage: Callable[[Path], None]) -> Path:
    copy = ws.path("corrupt", name)
    shutil.copytree(ws.scene(), copy)
    damage(copy / file)
    return copy


def _scene_row(ws: Workspace, name: str, file: str, damage: Callable[[Path], None], what: str) -> Row:
    scene = damaged_scene(ws, name, file, damage)
    out = ws.path("corrupt", f"{name}-run")
    command = recondreamer("train-recon", "--scene", ws.relative(scene), "--model", "street", "--preset", "quick",
                           "--iterations", "40", "--threads", "1", "--out", ws.relative(out))
    return _corrupt_row(ws, f"scene: {what} (`train-recon`)", command, scene / file, out)


def corrupt_scene_json(ws: Workspace) -> Row:
    return _scene_row(ws, "scene-json", "scene.json", truncate, "scene.json cut in half")


def corrupt_scene_image(ws: Workspace) -> Row:
    return _scene_row(ws, "scene-image", "images/001.png", lambda p: garbage(p, 2000, ws.seed), "images/001.png replaced by random bytes")


def corrupt_scene_boxes(ws: Workspace) -> Row:
    return _scene_row(ws, "scene-boxes", "boxes.json", lambda p: p.write_text('{"boxes": 3}\n'), 'boxes.json a valid JSON of the wrong shape')


def corrupt_scene_map(ws: Workspace) -> Row:
    return _scene_row(ws, "scene-map", "map.json", lambda p: truncate(p, 0.3), "map.json cut to 30 %")


def corrupt_scene_depth(ws: Workspace) -> Row:
    scene = damaged_scene(ws, "scene-depth", "depth/001.npy", lambda p: garbage(p, 4000, ws.seed))
    out = ws.path("corrupt", "scene-depth-preview.png")
    command = recondreamer("preview", ws.relative(scene), "--out", ws.relative(out))
    return _corrupt_row(ws, "scene: depth/001.npy replaced by random bytes (`preview`, which reads depth)", command, scene / "depth/001.npy", out)


def corrupt_tfrecord_garbage(ws: Workspace) -> Row:
    source = ws.path("corrupt", "garbage.tfrecord")
    garbage(source, 5000, ws.seed)
    out = ws.path("corrupt", "waymo-garbage")
    return _corrupt_row(ws, "tfrecord: 5,000 random bytes (`convert-waymo`)", recondreamer("convert-waymo", ws.relative(source), "--out", ws.relative(out)), source, out)


def corrupt_tfrecord_empty(ws: Workspace) -> Row:
    source = ws.path("corrupt", "empty.tfrecord")
    source.write_bytes(b"")
    out = ws.path("corrupt", "waymo-empty")
    return _corrupt_row(ws, "tfrecord: an empty file (`convert-waymo`)", recondreamer("convert-waymo", ws.relative(source), "--out", ws.relative(out)), source, out)


def corrupt_recon_model(ws: Workspace) -> Row:
    run_copy = ws.path("corrupt", "run-model")
    shutil.copytree(ws.full_run(), run_copy)
    truncate(run_copy / "model.pt")
    out = ws.path("corrupt", "run-model-renders")
    command = recondreamer("render", "--run", ws.relative(run_copy), "--trajectory", "original", "--out", ws.relative(out))
    return _corrupt_row(ws, "reconstruction model.pt cut in half (`render`)", command, run_copy / "model.pt", out)


def corrupt_recon_checkpoint(ws: Workspace) -> Row:
    run_copy = ws.path("corrupt", "run-checkpoint", "run")
    shutil.copytree(ws.full_run(), run_copy)
    (run_copy / "model.pt").unlink()  # an unfinished run: the same train-recon resumes from checkpoint.pt
    truncate(run_copy / "checkpoint.pt")
    before = file_state(run_copy)
    return _corrupt_row(ws, "reconstruction checkpoint.pt cut in half (`train-recon` resuming)", ws.recon_arguments(ws.relative(run_copy)),
                        run_copy / "checkpoint.pt", run_copy, before)


def corrupt_generative_checkpoint(ws: Workspace) -> Row:
    autoencoder = ws.path("corrupt", "autoencoder.pt")
    shutil.copyfile(SHIPPED_WEIGHTS / "autoencoder.pt", autoencoder)
    truncate(autoencoder, 0.3)
    out = ws.path("corrupt", "world_model.pt")
    command = recondreamer("pretrain-world-model", "--arch", "dd2", "--corpus", ws.relative(ws.scene().parent), "--autoencoder",
                           ws.relative(autoencoder), "--out", ws.relative(out), "--steps", "2", "--batch-size", "1", "--window", "3")
    return _corrupt_row(ws, "generative checkpoint (autoencoder.pt) cut to 30 % (`pretrain-world-model`)", command, autoencoder, out)


def corrupt_restorer_checkpoint(ws: Workspace) -> Row:
    restorer = ws.path("corrupt", "restorer_dd2_mask.pt")
    shutil.copyfile(SHIPPED_WEIGHTS / "restorer_dd2_mask.pt", restorer)
    truncate(restorer)
    _, renders = ws.evaluated()
    out = ws.path("corrupt", "restored")
    command = recondreamer("restore", "--restorer", ws.relative(restorer), "--scene", ws.relative(ws.scene()), "--renders",
                           ws.relative(renders / "shift@3"), "--trajectory", "shift@3", "--out", ws.relative(out), "--threads", "1")
    return _corrupt_row(ws, "generative checkpoint (restorer_dd2_mask.pt) cut in half (`restore`)", command, restorer, out)


def corrupt_pairs_file(ws: Workspace) -> Row:
    source = next(ws.pairs().glob("*.npz"))
    pairs = ws.path("corrupt", "pairs", source.name)
    shutil.copyfile(source, pairs)
    truncate(pairs)
    out = ws.path("corrupt", "restorer-from-bad-pairs.pt")
    command = recondreamer("train-restorer", "--arch", "dd2", "--world-model", SHIPPED_WEIGHTS / "world_model_dd2.pt", "--pairs",
                           ws.relative(pairs.parent), "--out", ws.relative(out), "--steps", "2", "--threads", "1")
    return _corrupt_row(ws, "restoration-pairs .npz (from make-pairs) cut in half (`train-restorer`)", command, pairs, out)


def corrupt_render_clip(ws: Workspace) -> Row:
    clip = ws.path("corrupt", "renders.npy")
    garbage(clip, 3000, ws.seed)
    out = ws.path("corrupt", "restored-from-bad-clip")
    command = recondreamer("restore", "--restorer", SHIPPED_WEIGHTS / "restorer_dd2_mask.pt", "--scene", ws.relative(ws.scene()),
                           "--renders", ws.relative(clip), "--trajectory", "shift@3", "--out", ws.relative(out), "--threads", "1")
    return _corrupt_row(ws, "rendered clip .npy: 3,000 random bytes (`restore --renders`)", command, clip, out)


def corrupt_pose_file(ws: Workspace) -> Row:
    poses = ws.path("corrupt", "poses.npy")
    garbage(poses, 3000, ws.seed)
    out = ws.path("corrupt", "renders-from-bad-poses")
    command = recondreamer("render", "--run", ws.relative(ws.full_run()), "--trajectory", f"file:{ws.relative(poses)}", "--out", ws.relative(out))
    return _corrupt_row(ws, "trajectory pose file .npy: 3,000 random bytes (`render --trajectory file:`)", command, poses, out)


def corrupt_weight_set(ws: Workspace) -> Row:
    copy = ws.path("corrupt", "weights")
    shutil.copytree(SHIPPED_WEIGHTS, copy, ignore=shutil.ignore_patterns("__pycache__", "*.py"))
    flip_byte(copy / "lane_segmenter.pt", 1000)
    row = _corrupt_row(ws, "weight set: one byte of lane_segmenter.pt flipped (`weights verify`)", recondreamer("weights", "verify", ws.relative(copy)),
                       copy / "lane_segmenter.pt", None)
    return row


def _plan_arguments(segment: str) -> list[str]:
    return ["--segments", segment, "--backbones", "street", "--dd4d-backbones", "street", "--restorers", "dd2_mask",
            "--strides", "1.5", "--versus", "baseline-street", "--trajectories", "shift@3"]


def _results_with_metrics(ws: Workspace, name: str) -> Path:
    """A results folder holding the metric files a one-segment street plan needs, each a copy of
    a real 'recondreamer evaluate' output."""
    metrics, _ = ws.evaluated()
    results = ws.path("corrupt", name)
    for run_id in ("baseline-street", "dd4d-street", "recondreamer-street-dd2_mask-stride1.5"):
        target = results / "metrics" / "seg" / f"{run_id}.json"
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(metrics, target)
        shutil.copyfile(metrics.with_suffix(".features.npz"), target.with_suffix(".features.npz"))
    return results


def corrupt_metrics_tables(ws: Workspace) -> Row:
    results = _results_with_metrics(ws, "results-tables")
    bad = results / "metrics" / "seg" / "baseline-street.json"
    truncate(bad)
    out = ws.path("corrupt", "tables")
    command = recondreamer("make-tables", "--results", ws.relative(results), "--out", ws.relative(out), "--tables", "1", *_plan_arguments("seg"))
    return _corrupt_row(ws, "metrics JSON cut in half (`make-tables`)", command, bad, out)


def corrupt_metrics_findings(ws: Workspace) -> Row:
    results = _results_with_metrics(ws, "results-findings")
    bad = results / "metrics" / "seg" / "dd4d-street.json"
    bad.write_text(json.dumps({"scene": {"scene_id": "seg"}, "trajectories": {"shift@3": {"fid": "n/a"}}}))
    out = ws.path("corrupt", "findings.md")
    command = recondreamer("findings", "--results", ws.relative(results), "--out", ws.relative(out), *_plan_arguments("seg"))
    return _corrupt_row(ws, "metrics JSON without its metrics (`findings`)", command, bad, out)


def _study_page(ws: Workspace) -> Path:
    def build():
        _, renders = ws.evaluated()
        page = ws.path("inputs", "study")
        ws.run(*recondreamer("study-page", "--clip", "seg", "shift@3", f"A={ws.relative(renders / 'shift@3')}",
                             f"B={ws.relative(renders / 'original')}", "--out", ws.relative(page)), must_pass=True)
        return page / "placement.json"

    return ws.once("study_page", build)


def corrupt_study_csv_binary(ws: Workspace) -> Row:
    placement = _study_page(ws)
    bad = ws.path("corrupt", "study-binary.csv")
    garbage(bad, 3000, ws.seed)
    out = ws.path("corrupt", "win-rates-binary.json")
    command = recondreamer("study-ingest", "--placement", ws.relative(placement), "--out", ws.relative(out), ws.relative(bad))
    return _corrupt_row(ws, "study CSV: 3,000 random bytes (`study-ingest`)", command, bad, out)


def corrupt_study_csv_cut(ws: Workspace) -> Row:
    placement = _study_page(ws)
    clip = json.loads(placement.read_text())["clips"][0]["clip_id"]
    bad = ws.path("corrupt", "study-cut.csv")
    bad.write_text(f"participant,clip_id,choice,time\np1,{clip},top,3.1\np2,{clip}")  # the download stopped mid-row
    out = ws.path("corrupt", "win-rates-cut.json")
    command = recondreamer("study-ingest", "--placement", ws.relative(placement), "--out", ws.relative(out), ws.relative(bad))
    return _corrupt_row(ws, "study CSV: last row cut short (`study-ingest`)", command, bad, out)


def corrupt_config_value(ws: Workspace) -> Row:
    """The workflow's schema check reports a bad config value at parse time: its message names the
    config file that set it, the key and the value; nothing may be created."""
    root = ws.workflow_copy("config-check")
    bad = root / "bad.yaml"
    bad.write_text("results_dir: results/bad\nrecon:\n  iterations: -5\n")
    result = ws.run(*snakemake("-n", "--configfile", QUICK_CONFIG, "bad.yaml"), cwd=root, timeout=300)
    problems = []
    if result.returncode == 0:
        problems.append("exit code 0")
    if "Traceback (most recent call last)" in result.output:
        problems.append("Python traceback")
    message = next((line for line in result.output.splitlines() if "config key" in line), None)
    if message is None or "recon.iterations" not in message or "-5" not in message or "bad.yaml" not in message:
        problems.append("the message does not name the config file, the key and the value")
    happened = f"exit {result.returncode}: {quoted(message or result.output.strip().splitlines()[-1])}"
    written_ok = not (root / "results").exists()
    return Row("corrupt input", "config: `recon.iterations: -5` (`snakemake -n --configfile`)", happened + (f" — {', '.join(problems)}" if problems else ""),
               "nothing created" if written_ok else "results/ created", not problems and written_ok)


CORRUPT_INPUTS: dict[str, Callable[[Workspace], Row]] = {
    "scene_json": corrupt_scene_json,
    "scene_image": corrupt_scene_image,
    "scene_depth": corrupt_scene_depth,
    "scene_boxes": corrupt_scene_boxes,
    "scene_map": corrupt_scene_map,
    "tfrecord_garbage": corrupt_tfrecord_garbage,
    "tfrecord_empty": corrupt_tfrecord_empty,
    "recon_model": corrupt_recon_model,
    "recon_checkpoint": corrupt_recon_checkpoint,
    "generative_checkpoint": corrupt_generative_checkpoint,
    "restorer_checkpoint": corrupt_restorer_checkpoint,
    "pairs_file": corrupt_pairs_file,
    "render_clip": corrupt_render_clip,
    "pose_file": corrupt_pose_file,
    "weight_set": corrupt_weight_set,
    "metrics_tables": corrupt_metrics_tables,
    "metrics_findings": corrupt_metrics_findings,
    "study_csv_binary": corrupt_study_csv_binary,
    "study_csv_cut": corrupt_study_csv_cut,
    "config_value": corrupt_config_value,
}


def corrupt_inputs(ws: Workspace) -> list[Row]:
    return [check(ws) for check in CORRUPT_INPUTS.values()]


def resume_row(case: str, injected: str, happened: str, problems: list[str], left_after_kill: list[str], folder: Path) -> Row:
    """The row of a kill-and-resume case: ok when nothing differed, no file under its final name
    was half-written after the kill, and nothing at all was left at the end. A kill -9 in the
    middle of a write leaves that write's hidden temporary (no process can clean up on SIGKILL):
    allowed, provided the rerun removes it."""
    damaged = [p for p in left_after_kill if not p.endswith("(temporary)")]
    swept = [p.removesuffix(" (temporary)") for p in left_after_kill if p.endswith("(temporary)")]
    left_at_end = half_written(folder)
    lost = "nothing" if not damaged and not left_at_end else f"after the kill: {damaged}; at the end: {left_at_end}"
    if swept and not left_at_end:
        happened += f"; the kill left the hidden temporary of the write in progress ({', '.join(swept)}), which the rerun removed"
    return Row(case, injected, happened + (f" — {'; '.join(problems)}" if problems else ""), lost, not problems and lost == "nothing")


# ------------------------------------------------------------------ case 2: kill in train-recon


def _record_difference(a: Path, b: Path) -> Difference:
    return compare_values(load_for_comparison(a), load_for_comparison(b))


def recon_kill(ws: Workspace) -> list[Row]:
    reference = ws.full_run()
    parent = ws.folder("recon", "killed")
    run_dir = parent / "run"
    process = start(ws.recon_arguments("run"), parent, parent / "killed.log")
    killed = kill_when_exists(process, run_dir / "checkpoint.pt", timeout=COMMAND_TIMEOUT)
    injected = "kill -9 of `train-recon` (quick preset, 300 iterations) as soon as its first checkpoint.pt exists"
    if not killed or (run_dir / "model.pt").exists():
        return [Row("kill in train-recon", injected, "the kill came too late: the run had finished (inconclusive)", "-", False)]
    import torch

    killed_at = int(torch.load(run_dir / "checkpoint.pt", map_location="cpu", weights_only=True)["step"])
    left_after_kill = half_written(run_dir)
    again = ws.run(*ws.recon_arguments("run"), cwd=parent)
    log = (run_dir / "train.log").read_text() if (run_dir / "train.log").exists() else ""
    resumed = re.search(r"resumed from checkpoint\.pt at step (\d+)/", log)
    problems = []
    if again.returncode != 0:
        problems.append(f"the second run failed: {quoted(again.stderr.strip().splitlines()[-1] if again.stderr.strip() else '')}")
    if not resumed:
        problems.append("train.log does not say it resumed")
    difference = Difference()
    for name in ("model.pt", "checkpoint.pt", "snapshots/step_000100.pt", "snapshots/step_000200.pt"):
        if not (run_dir / name).exists():
            problems.append(f"{name} missing")
            continue
        difference.merge(_record_difference(reference / name, run_dir / name), f"{name}:")
    renders = []
    for which in (reference, run_dir):
        out = which.parent / "render-shift@3"
        ws.run(*recondreamer("render", "--run", which, "--trajectory", "shift@3", "--out", out, "--threads", "1"), must_pass=True)
        renders.append(out)
    render_difference = compare_trees(*renders)
    if not difference.identical:
        problems.append(f"state differs from the uninterrupted run: {difference.describe()}")
    if not render_difference.identical:
        problems.append(f"renders differ: {render_difference.describe()}")
    happened = (
        f"killed at step {killed_at} (checkpoint); the rerun logged `resumed from checkpoint.pt at step {resumed.group(1) if resumed else '?'}/300` "
        f"and finished; model.pt, checkpoint.pt, both snapshots (every tensor, optimiser moments included) and the shift@3 render: "
        f"{'identical to' if difference.identical and render_difference.identical else 'NOT identical to'} an uninterrupted run's"
    )
    return [resume_row("kill in train-recon", injected, happened, problems, left_after_kill, run_dir)]


# --------------------------------------------------------------- case 3: kill in train-restorer


def generative_inputs(ws: Workspace) -> dict[str, Path]:
    """A tiny autoencoder and dd2 world model trained on the scene, and restoration pairs made
    by make-pairs from the uninterrupted reconstruction's snapshots."""

    def build():
        folder = ws.folder("inputs", "generative")
        autoencoder, world_model = folder / "autoencoder.pt", folder / "world_model.pt"
        ws.run(*recondreamer("train-autoencoder", "--corpus", ws.scene(), "--out", autoencoder, "--steps", "3", "--threads", "1"), must_pass=True)
        ws.run(*recondreamer("pretrain-world-model", "--arch", "dd2", "--corpus", ws.scene().parent, "--autoencoder", autoencoder,
                             "--out", world_model, "--steps", "2", "--batch-size", "1", "--window", "3", "--channels", "8", "16", "16",
                             "--threads", "1"), must_pass=True)
        return {"world_model": world_model, "pairs": ws.pairs()}

    return ws.once("generative_inputs", build)


def restorer_arguments(inputs: dict[str, Path]) -> list[str]:
    return recondreamer("train-restorer", "--arch", "dd2", "--world-model", inputs["world_model"], "--pairs", inputs["pairs"],
                        "--out", "restorer.pt", "--steps", str(RESTORER_STEPS), "--batch-size", "1", "--window", "3", "--crop", "0", "0",
                        "--seed", "1", "--threads", "1")


TIMING_KEYS = ("ms_per_step", "cpu_ms_per_step", "total_cpu_minutes")


def tiny_restorer(ws: Workspace) -> Path:
    """restorer.pt of an uninterrupted train-restorer job: the reference of restorer_kill and the
    DriveRestorer of recondreamer_kill."""

    def build():
        folder = ws.folder("restorer", "uninterrupted")
        ws.run(*restorer_arguments(generative_inputs(ws)), cwd=folder, must_pass=True)
        return folder / "restorer.pt"

    return ws.once("tiny_restorer", build)


def restorer_kill(ws: Workspace) -> list[Row]:
    arguments = restorer_arguments(generative_inputs(ws))
    reference = tiny_restorer(ws).parent
    killed_dir = ws.folder("restorer", "killed")
    resume_file = killed_dir / "restorer.pt.resume.pt"
    process = start(arguments, killed_dir, killed_dir / "killed.log")
    killed = kill_when_exists(process, resume_file, timeout=COMMAND_TIMEOUT)
    injected = f"kill -9 of `train-restorer` (dd2, {RESTORER_STEPS} steps, tiny world model) as soon as its resume file exists (step 200)"
    if not killed or (killed_dir / "restorer.pt").exists():
        return [Row("kill in train-restorer", injected, "the kill came too late: the job had finished (inconclusive)", "-", False)]
    left_after_kill = half_written(killed_dir)
    again = ws.run(*arguments, cwd=killed_dir)
    resumed = re.search(r"resuming from \S*restorer\.pt\.resume\.pt at step (\d+)", again.stderr)
    problems = []
    if again.returncode != 0:
        problems.append("the second run failed")
    if not resumed:
        problems.append("its log does not say it resumed")
    if resume_file.exists():
        problems.append("the resume file was not removed")
    difference = compare_values(load_for_comparison(reference / "restorer.pt"), load_for_comparison(killed_dir / "restorer.pt"), ignore=TIMING_KEYS)
    if not difference.identical:
        problems.append(f"differs from the uninterrupted job: {difference.describe()}")
    happened = (
        f"the rerun logged `resuming from restorer.pt.resume.pt at step {resumed.group(1) if resumed else '?'}`, finished and removed the "
        f"resume file; restorer.pt (weights, configs, final loss; timings aside): "
        f"{'identical to' if difference.identical else 'NOT identical to'} an uninterrupted job's"
    )
    return [resume_row("kill in train-restorer", injected, happened, problems, left_after_kill, killed_dir)]


# ------------------------------------------------------------ case 3b: kill in train-recondreamer

RECONDREAMER_UPDATE_EVERY = 100  # PDUS updates at steps 100 and 200 of 300, each right after that step's checkpoint


def recondreamer_arguments(ws: Workspace) -> list[str]:
    """train-recondreamer of the resume case, run from the run's parent folder (same argv for every run)."""
    return recondreamer("train-recondreamer", "--scene", str(ws.scene()), "--model", "street", "--preset", "quick",
                        "--iterations", str(RECON_ITERATIONS), "--seed", "0", "--threads", "1", "--restorer", str(tiny_restorer(ws)),
                        "--stride", "1.5", "--update-every", str(RECONDREAMER_UPDATE_EVERY), "--out", "run")


def _pdus_state(run_dir: Path) -> str:
    """Where a killed ReconDreamer run stood: its checkpoint step and the update folders on disk."""
    import torch

    step = torch.load(run_dir / "checkpoint.pt", map_location="cpu", weights_only=True)["step"] if (run_dir / "checkpoint.pt").exists() else 0
    updates = sorted(p.name for p in (run_dir / "updates").glob("update_*")) if (run_dir / "updates").is_dir() else []
    pending = [p.name for p in temporaries(run_dir / "updates")] if (run_dir / "updates").is_dir() else []
    return (f"checkpoint at step {step}, update folders on disk: {', '.join(updates) or 'none'}"
            + (f", an unfinished update's temporary ({', '.join(pending)})" if pending else ""))


def recondreamer_kill(ws: Workspace) -> list[Row]:
    """kill -9 inside train-recondreamer during a PDUS update and between two updates; the same
    command again must resume and end with the uninterrupted run's model, updates and pdus.json."""
    arguments = recondreamer_arguments(ws)
    reference = ws.folder("recondreamer", "uninterrupted")
    ws.run(*arguments, cwd=reference, must_pass=True)
    rows = []
    for label, trigger, extra_delay in (
        ("during update 1", "checkpoint.pt", 0.0),  # the step-100 checkpoint is written just before update 1 starts
        # The steps between two updates take about a second on the tiny scene: kill the moment update 1 is on disk.
        ("between updates 1 and 2", "updates/update_01", 0.0),
    ):
        parent = ws.folder("recondreamer", f"killed-{label.split()[0]}")
        run_dir = parent / "run"
        process = start(arguments, parent, parent / "killed.log")
        injected = (f"kill -9 of `train-recondreamer` (quick preset, 300 iterations, updates every {RECONDREAMER_UPDATE_EVERY} steps, "
                    f"tiny dd2 restorer) {label}: " + (f"as soon as `{trigger}` exists" if not extra_delay else f"{extra_delay:.1f} s after `{trigger}` appears"))
        appeared = wait_for(lambda: (run_dir / trigger).exists() or process.poll() is not None, COMMAND_TIMEOUT, poll=0.01)
        killed = appeared and (run_dir / trigger).exists() and kill_after(process, extra_delay)
        if not killed or (run_dir / "model.pt").exists():
            kill_group(process)
            rows.append(Row("kill in train-recondreamer", injected, "the kill came too late: the run had finished (inconclusive)", "-", False))
            continue
        where = _pdus_state(run_dir)
        left_after_kill = half_written(run_dir)
        again = ws.run(*arguments, cwd=parent)
        log = (run_dir / "train.log").read_text() if (run_dir / "train.log").exists() else ""
        problems = []
        if again.returncode != 0:
            problems.append(f"the second run failed: {quoted(again.stderr.strip().splitlines()[-1] if again.stderr.strip() else '')}")
        resumed = re.search(r"resumed from checkpoint\.pt at step (\d+)/", log)
        if not resumed:
            problems.append("train.log does not say it resumed")
        reloaded = sorted(set(re.findall(r"pdus: update (\d+) \(\S+ m\) reloaded", again.output)))
        # update.json records the update's wall time ('seconds'), which differs between any two runs.
        difference = compare_trees(reference / "run", run_dir, ignore_files=("train.log", "run.json"), ignore_keys=("seconds",))
        if not difference.identical:
            problems.append(f"differs from the uninterrupted run: {difference.describe()}")
        happened = (
            f"at the kill: {where}; the rerun resumed at step {resumed.group(1) if resumed else '?'}, "
            + (f"reloaded update(s) {', '.join(reloaded)} from disk" if reloaded else "reloaded no update")
            + " and finished; model.pt, checkpoint.pt, snapshots, pdus.json and every update's rendered and restored frames: "
            + ("identical to" if difference.identical else "NOT identical to") + " an uninterrupted run's"
        )
        rows.append(resume_row("kill in train-recondreamer", injected, happened, problems, left_after_kill, run_dir))
    return rows


# ------------------------------------------------------------------------ case 3c: kill in evaluate


def evaluate_arguments(ws: Workspace) -> list[str]:
    """evaluate of the resume case (the uninterrupted run along shift@3 and the original
    trajectory, shipped evaluation models), run from its parent folder."""
    return recondreamer("evaluate", "--scene", str(ws.scene()), "--run", str(ws.full_run()),
                        "--renders", "renders/shift@3", "--trajectory", "shift@3", "--renders", "renders/original", "--trajectory", "original",
                        "--models", SHIPPED_WEIGHTS, "--threads", "1", "--out", "metrics.json")


def evaluate_kill(ws: Workspace) -> list[Row]:
    """kill -9 of evaluate once its first renders are on disk; the same command again
    must give the uninterrupted job's metrics file and renders."""
    arguments = evaluate_arguments(ws)
    reference = ws.folder("evaluate", "uninterrupted")
    ws.run(*arguments, cwd=reference, must_pass=True)
    parent = ws.folder("evaluate", "killed")
    process = start(arguments, parent, parent / "killed.log")
    injected = ("kill -9 of `evaluate` (shift@3 and original, shipped evaluation models) as soon as its first renders "
                "(shift@3) are on disk, before its metrics file")
    killed = kill_when_exists(process, parent / "renders" / "shift@3", timeout=COMMAND_TIMEOUT)
    if not killed or (parent / "metrics.json").exists():
        return [Row("kill in evaluate", injected, "the kill came too late: the job had finished (inconclusive)", "-", False)]
    on_disk = sorted(p.name for p in (parent / "renders").iterdir() if not TEMPORARY.match(p.name))
    left_after_kill = half_written(parent)
    again = ws.run(*arguments, cwd=parent)
    problems = []
    if again.returncode != 0:
        problems.append(f"the second run failed: {quoted(again.stderr.strip().splitlines()[-1] if again.stderr.strip() else '')}")
    difference = compare_trees(reference, parent, ignore_files=("killed.log",))
    if not difference.identical:
        problems.append(f"differs from the uninterrupted job: {difference.describe()}")
    happened = (
        f"at the kill: renders on disk: {', '.join(on_disk) or 'none'}, no metrics file; the rerun finished; metrics.json "
        f"and every render: {'identical to' if difference.identical else 'NOT identical to'} an uninterrupted job's"
    )
    return [resume_row("kill in evaluate", injected, happened, problems, left_after_kill, parent)]


# ------------------------------------------------------------------------- case 4: disk full


@contextlib.contextmanager
def small_filesystem(path: Path, size_bytes: int) -> Iterator[bool]:
    """Mount a tmpfs of ``size_bytes`` at ``path`` (root only); yields False where that is
    impossible (the caller then injects ENOSPC instead). Unmounted afterwards."""
    path.mkdir(parents=True, exist_ok=True)
    mounted = False
    if os.geteuid() == 0 and shutil.which("mount"):
        mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_bytes}", "tmpfs", str(path)], capture_output=True, check=False).returncode == 0
    try:
        yield mounted
    finally:
        if mounted:
            subprocess.run(["umount", str(path)], capture_output=True, check=False)
            if os.path.ismount(path):
                subprocess.run(["umount", "-l", str(path)], capture_output=True, check=False)


def fill_filesystem(folder: Path) -> Path:
    """Write zeros into ``folder/ballast`` until its file system is full."""
    ballast = folder / "ballast"
    chunk = b"\0" * 4096
    with contextlib.suppress(OSError), open(ballast, "wb", buffering=0) as handle:
        while True:
            handle.write(chunk)
    return ballast


# Runs a recondreamer command with os.replace failing with ENOSPC on the NTH rename onto a path
# named NAME (where no small file system can be mounted): the rename that completes an atomic write.
ENOSPC_WRAPPER = """
import errno, os, sys
name, nth = sys.argv[1], int(sys.argv[2])
real_replace, seen = os.replace, [0]
def replace(source, destination, **kwargs):
    if os.path.basename(os.fspath(destination)) == name:
        seen[0] += 1
        if seen[0] == nth:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), os.fspath(destination))
    return real_replace(source, destination, **kwargs)
os.replace = replace
from recondreamer.cli import main
sys.exit(main(sys.argv[3:]))
"""


def disk_full_scene(ws: Workspace) -> Row:
    folder = ws.path("disk-full", "scene-fs")
    with small_filesystem(folder, 16 << 20) as mounted:
        out = folder / "scene"
        first = ws.run(*recondreamer("synth", "--seed", "5", *TINY_SCENE, "--no-novel", "--out", ws.relative(out)), must_pass=True)
        assert first.returncode == 0
        before = {name: (out / name).read_bytes() for name in file_state(out)}
        second_args = ["synth", "--seed", "5", *TINY_SCENE, "--out", ws.relative(out)]
        if mounted:
            fill_filesystem(folder)
            result = ws.run(*recondreamer(*second_args))
            how = "a 16 MiB tmpfs filled up by another file"
        else:
            result = ws.run(sys.executable, "-c", ENOSPC_WRAPPER, "scene", "2", *second_args)
            how = "an ENOSPC injected into the rename that puts the new scene in place (no tmpfs could be mounted)"
        message_ok, happened = check_one_line_error(result, ws.relative(out))
        after = {name: (out / name).read_bytes() for name in file_state(out)}
        leftovers = [p.name for p in folder.glob(".scene.*")]
        valid = ws.run(*recondreamer("validate", ws.relative(out)))
    intact = after == before and valid.returncode == 0
    lost = ("nothing: the earlier scene is byte-identical and validates" if intact else "the earlier scene changed") + (
        f"; temporaries left: {leftovers}" if leftovers else "; no temporary left")
    return Row("disk full", f"`synth` replacing an existing scene on {how}", happened, lost, message_ok and intact and not leftovers)


def disk_full_checkpoint(ws: Workspace) -> Row:
    reference = ws.full_run()
    folder = ws.path("disk-full", "run-fs")
    run_dir = folder / "run"
    with small_filesystem(folder, 16 << 20) as mounted:
        if mounted:
            process = start(ws.recon_arguments("run"), folder, ws.path("disk-full", "train-recon.out"))
            appeared = wait_for(lambda: (run_dir / "checkpoint.pt").exists() or process.poll() is not None, COMMAND_TIMEOUT, poll=0.01)
            if appeared and process.poll() is None:
                fill_filesystem(folder)
            process.wait(timeout=COMMAND_TIMEOUT)
            output = ws.path("disk-full", "train-recon.out").read_text()
            result = Completed(ws.recon_arguments("run"), process.returncode, "", output, 0.0)
            how = "a 16 MiB tmpfs filled up by another file right after the first checkpoint"
        else:
            # The second rename onto checkpoint.pt (step 200) fails; the first (step 100) succeeded.
            result = ws.run(sys.executable, "-c", ENOSPC_WRAPPER, "checkpoint.pt", "2", *ws.recon_arguments("run")[3:], cwd=folder)
            how = "an ENOSPC injected into the second checkpoint's rename (no tmpfs could be mounted)"
        message_ok, happened = check_one_line_error(result, "run/")
        import torch

        try:
            step = int(torch.load(run_dir / "checkpoint.pt", map_location="cpu", weights_only=True)["step"])
            loads = f"checkpoint.pt (step {step}) loads"
        except Exception as error:
            step, loads = None, f"checkpoint.pt does not load ({type(error).__name__})"
        leftovers = half_written(run_dir)
        finished_anyway = (run_dir / "model.pt").exists()
        # Room again: the same command resumes from the checkpoint that survived.
        (folder / "ballast").unlink(missing_ok=True)
        again = ws.run(*ws.recon_arguments("run"), cwd=folder)
        difference = _record_difference(reference / "model.pt", run_dir / "model.pt") if again.returncode == 0 else None
    ok = message_ok and step is not None and not leftovers and not finished_anyway and difference is not None and difference.identical
    lost = f"nothing: {loads}, no temporary left; with space freed the same command resumed and its model.pt is " + (
        "identical to an uninterrupted run's" if difference is not None and difference.identical else f"NOT as expected ({difference.describe() if difference else 'rerun failed'})")
    if leftovers:
        lost += f"; half-written: {leftovers}"
    if finished_anyway:
        happened += " — the run finished before the disk filled (inconclusive)"
    return Row("disk full", f"`train-recon` writing its run on {how}", happened, lost, ok)


def disk_full(ws: Workspace) -> list[Row]:
    return [disk_full_scene(ws), disk_full_checkpoint(ws)]


# ------------------------------------------------------------- case 5: a second snakemake


def _text_after(log: Path, offset: int) -> str:
    if not log.exists():
        return ""
    with open(log, "rb") as handle:
        handle.seek(offset)
        return handle.read().decode(errors="replace")


def start_workflow(root: Path, command: list[str], log: Path, notes: list[str]) -> subprocess.Popen | None:
    """Start ``command`` (a Snakemake run) and wait until it runs a job. Where a killed run's lock
    refuses it, note "unlock", run ``snakemake --unlock`` and start again. None: it ended first."""
    for _ in range(3):
        offset = log.stat().st_size if log.exists() else 0
        process = start(command, root, log)
        wait_for(lambda process=process, offset=offset: process.poll() is not None or "Shell command:" in _text_after(log, offset),
                 WORKFLOW_TIMEOUT, poll=0.5)
        if process.poll() is None:
            return process
        if "cannot be locked" not in _text_after(log, offset):
            return None
        notes.append("unlock")
        run(snakemake("--unlock", "--configfile", QUICK_CONFIG), root, timeout=600)
    return None


def _sentence(text: str, containing: str) -> str:
    """The sentence of ``text`` that contains ``containing`` ('' if none)."""
    match = re.search(rf"[^.:\n]*{re.escape(containing)}[^.:\n]*[.:]?", text)
    return match.group(0).strip() if match else ""


def incomplete_outputs(root: Path) -> list[str]:
    """Outputs Snakemake marked incomplete (jobs that were running when it died)."""
    names = []
    for marker in (root / ".snakemake" / "incomplete").glob("*"):
        try:
            names.append(base64.urlsafe_b64decode(marker.name + "=" * (-len(marker.name) % 4)).decode())
        except (ValueError, UnicodeDecodeError):
            names.append(marker.name)
    return sorted(names)


def second_snakemake(ws: Workspace) -> list[Row]:
    root = ws.workflow_copy("two-at-once")
    command = snakemake("--cores", "2", "--configfile", QUICK_CONFIG)
    first = start(command, root, root / "first.log")
    started = wait_for(lambda: first.poll() is not None or "Shell command:" in _text_after(root / "first.log", 0), 600, poll=0.5)
    if not started or first.poll() is not None:
        kill_group(first)
        return [Row("second snakemake", "a second snakemake while one runs", "the first run did not start a job", "-", False)]
    second = run(command, root, timeout=600)
    first_still_running = first.poll() is None
    second_started_jobs = "Shell command:" in second.output
    refused = second.returncode != 0 and "cannot be locked" in second.output
    kill_group(first)
    killed_jobs = incomplete_outputs(root)
    results = root / QUICK_RESULTS
    broken = [p for p in half_written(results) if "(temporary)" not in p]
    left_temporaries = [p for p in half_written(results) if "(temporary)" in p]
    # The next run after the kill: Snakemake must refuse it and say what to do.
    next_run = start(command, root, root / "next.log")
    wait_for(lambda: next_run.poll() is not None or "Shell command:" in _text_after(root / "next.log", 0), 600, poll=0.5)
    next_started_jobs = next_run.poll() is None
    kill_group(next_run)
    next_output = _text_after(root / "next.log", 0)
    says_unlock = not next_started_jobs and next_run.returncode != 0 and "--unlock" in next_output
    unlock = run(snakemake("--unlock", "--configfile", QUICK_CONFIG), root, timeout=600)
    plan = run(snakemake("-n", "--configfile", QUICK_CONFIG), root, timeout=600)
    reruns_killed = all(name in plan.output for name in killed_jobs)
    rows = [
        Row(
            "second snakemake",
            "a second `snakemake --cores 2` on the same folder once the first has started a job",
            (f"refused in {second.seconds:.0f} s, exit {second.returncode}: {quoted(_sentence(second.output, 'cannot be locked'))}; "
             f"it started no job; the first kept running") if refused and not second_started_jobs and first_still_running
            else f"NOT refused cleanly: exit {second.returncode}, started jobs: {second_started_jobs}, first still running: {first_still_running}",
            "nothing: the first run's outputs all load" if not broken else f"broken: {broken}",
            refused and not second_started_jobs and first_still_running and not broken,
        ),
        Row(
            "second snakemake",
            "kill -9 of the first snakemake's process group, then `snakemake` again, `snakemake --unlock`, `snakemake -n`",
            (f"the next `snakemake` was refused: {quoted(_sentence(next_output, '--unlock'))}; " if says_unlock
             else f"the next `snakemake` did NOT say to unlock (started jobs: {next_started_jobs}); ")
            + f"`--unlock` exit {unlock.returncode}; the next dry run plans the rest"
            + (f", the {len(killed_jobs)} killed job(s) included" if reruns_killed else ", NOT every killed job"),
            (f"killed mid-job: {', '.join(Path(n).name for n in killed_jobs) or 'none'}; no output that looks complete fails to load"
             + (f"; {len(left_temporaries)} temporaries of killed writers (removed by the next write)" if left_temporaries else "")) if not broken else f"broken: {broken}",
            says_unlock and unlock.returncode == 0 and plan.returncode == 0 and reruns_killed and not broken,
        ),
    ]
    return rows


# ------------------------------------------------------------- case 6: kill the whole workflow


def _restart_until_finished(root: Path, command: list[str], notes: list[str], attempts: int = 4) -> Completed | None:
    """Run ``command`` until it succeeds, unlocking after a refused start (a killed run's lock)."""
    for _ in range(attempts):
        result = run(command, root, timeout=WORKFLOW_TIMEOUT)
        with open(root / "snakemake.log", "a") as log:
            log.write(result.output)
        if result.returncode == 0:
            return result
        if "cannot be locked" in result.output:
            notes.append("unlock")
            run(snakemake("--unlock", "--configfile", QUICK_CONFIG), root, timeout=600)
            continue
        notes.append(f"failed: {result.output.strip().splitlines()[-1] if result.output.strip() else result.returncode}")
    return None


# What differs between any two runs, killed or not: models record their training times and the
# absolute corpus path, so the hashes of the model files (which the metric files name) differ too.
RUN_SPECIFIC_KEYS = (*TIMING_KEYS, "seconds", "corpus", "sha256", "feature_model_sha256")


def compare_workflow_outputs(reference: Path, other: Path) -> dict[str, Difference]:
    a, b = reference / QUICK_RESULTS, other / QUICK_RESULTS
    return {
        "tables": compare_trees(a / "tables", b / "tables"),
        "findings": _compare_files(a, b, ["findings.md", "findings.csv", "findings.html"]),
        "metrics": compare_trees(a / "metrics", b / "metrics", ignore_keys=("sha256", "feature_model_sha256")),
        "models": compare_trees(a / "models", b / "models", ignore_keys=RUN_SPECIFIC_KEYS),
        "eval_models": compare_trees(a / "eval_models", b / "eval_models", ignore_keys=RUN_SPECIFIC_KEYS),
    }


def _compare_files(a: Path, b: Path, names: Sequence[str]) -> Difference:
    result = Difference()
    for name in names:
        if not (a / name).exists() or not (b / name).exists():
            result.other.append(f"{name} (missing)")
        elif (a / name).read_bytes() != (b / name).read_bytes():
            result.other.append(name)
    return result


def workflow_kills(ws: Workspace) -> list[Row]:
    reference, reference_seconds = ws.finished_workflow()
    root = ws.workflow_copy("killed")
    command = snakemake("--cores", "2", "--configfile", QUICK_CONFIG)
    kills = ws.workflow_kills
    started = time.monotonic()
    landed, during, notes = [], [], []
    for _ in range(kills):
        delay = reference_seconds * ws.rng.uniform(0.2, 0.8) / max(kills, 1)
        process = start_workflow(root, command, root / "snakemake.log", notes)
        if process is None:
            landed.append(f"{delay:.0f} s (the run ended before it)")
            continue
        hit = kill_after(process, delay)
        landed.append(f"{delay:.0f} s" + ("" if hit else " (the run had already ended)"))
        during.append(", ".join(n.removeprefix(QUICK_RESULTS + "/").removesuffix("/model.pt") for n in incomplete_outputs(root)) or "between jobs")
        for temporary in temporaries(root / QUICK_RESULTS):
            notes.append(f"temporary {temporary.name}")
    final = _restart_until_finished(root, command, notes)
    seconds = time.monotonic() - started
    if final is None:
        return [Row("workflow kills", f"kill -9 of the quick workflow's process group {kills} time(s)", f"did NOT finish: {notes}", "-", False)]
    differences = compare_workflow_outputs(reference, root)
    broken = half_written(root / QUICK_RESULTS)
    unlocks = notes.count("unlock")
    same = all(d.identical for d in differences.values())
    restarts = "each restart" if unlocks == kills else f"{unlocks} of {kills} restarts"
    happened = (
        f"kills {', '.join(landed)} into each start, during: {'; '.join(during)}; "
        f"{restarts} first met the killed run's lock and needed `snakemake --unlock`; the last `snakemake` finished; "
        + ("tables and findings byte-identical to an uninterrupted run's, every metrics file equal (the model hashes they name aside) "
           "and every model's tensors identical (model files differ only in recorded training times and corpus paths)"
           if same else "; ".join(f"{k}: {d.describe()}" for k, d in differences.items() if not d.identical))
        + f" (killed runs and restarts {seconds / 60:.1f} min, the uninterrupted run {reference_seconds / 60:.1f} min)"
    )
    lost = "nothing: no temporary left, every output loads" if not broken else f"half-written: {broken[:5]}"
    return [Row("workflow kills", f"kill -9 of the quick workflow's process group at {kills} seeded random moment(s), then `snakemake` again until it finishes",
                happened, lost, same and not broken)]


# ----------------------------------------------------------- case 7: a scene changed between runs


def parse_dag(dot: str) -> tuple[dict[str, str], list[tuple[str, str]]]:
    """Job labels and edges of ``snakemake --dag`` output: ({node: 'rule key=value ...'}, [(from, to)]).
    Snakemake's labels show only the wildcards that tell a rule's jobs apart."""
    nodes = {}
    for node, label in re.findall(r'^\s*(\d+)\[label = "([^"]*)"', dot, re.MULTILINE):
        parts = label.split("\\n")
        wildcards = sorted(p.replace(": ", "=", 1) for p in parts[1:] if p)
        nodes[node] = " ".join([parts[0], *wildcards])
    edges = re.findall(r"^\s*(\d+)\s*->\s*(\d+)", dot, re.MULTILINE)
    return nodes, edges


def planned_jobs(dry_run: str, dag_labels: Sequence[str]) -> list[str]:
    """The jobs a ``snakemake -n`` output plans, labelled like ``parse_dag`` (only the wildcard
    keys the DAG's labels of the same rule show)."""
    shown: dict[str, set[str]] = {}
    for label in dag_labels:
        rule, *wildcards = label.split()
        shown.setdefault(rule, set()).update(w.split("=", 1)[0] for w in wildcards)
    jobs = []
    for block in re.split(r"\n(?=(?:local)?rule \w+:)", dry_run):
        match = re.match(r"(?:local)?rule (\w+):", block.strip())
        if not match:
            continue
        rule = match.group(1)
        wildcards = re.search(r"^\s*wildcards: (.*)$", block, re.MULTILINE)
        pairs = [p.strip() for p in wildcards.group(1).split(",")] if wildcards else []
        jobs.append(" ".join([rule, *sorted(p for p in pairs if p.split("=", 1)[0] in shown.get(rule, set()))]))
    return jobs


def _plan_row(root: Path, nodes: dict[str, str], expected: Counter, injected: str, checks_before: bool) -> Row:
    """Dry-run the workflow and compare the jobs it plans with ``expected`` (DAG labels)."""
    plan = run(snakemake("-n", "--configfile", QUICK_CONFIG), root, timeout=600)
    planned = Counter(planned_jobs(plan.output, list(nodes.values())))
    missing, extra = expected - planned, planned - expected
    planned_rules = Counter(job.split()[0] for job in planned.elements())
    untouched = sorted({label.split()[0] for label in nodes.values()} - set(planned_rules))
    ok = checks_before and plan.returncode == 0 and not missing and not extra
    if not planned:
        happened = f"`snakemake -n`: {quoted(_sentence(plan.output, 'Nothing to be done') or plan.output.strip()[-120:])}: the change is NOT seen"
    else:
        happened = f"`snakemake -n` plans {sum(planned.values())} of {len(nodes)} jobs (" + ", ".join(
            f"{rule} x{count}" for rule, count in sorted(planned_rules.items())) + ")"
    happened += f"; the job graph's descendants of the scene: {sum(expected.values())} jobs"
    if missing:
        happened += f"; NOT planned: {len(list(missing.elements()))} ({', '.join(sorted(missing)[:3])}, ...)"
    if extra:
        happened += f"; planned beyond them: {', '.join(sorted(extra)[:4])}"
    if planned and not missing and not extra:
        happened += f": exactly those; not rerun: {', '.join(untouched)}"
    if not checks_before:
        happened += "; (the finished run was not up to date before the change)"
    return Row("scene changed", injected, happened, "nothing (dry runs)", ok)


def scene_changed(ws: Workspace) -> list[Row]:
    """After a finished quick workflow: one file of a segment's scene edited in place, the folder's
    Snakemake timestamp touched, then the whole scene folder rewritten by hand; each time the dry
    run must plan exactly the jobs below the scene in the job graph."""
    import yaml

    root, _ = ws.finished_workflow()
    idle = run(snakemake("-n", "--configfile", QUICK_CONFIG), root, timeout=600)
    up_to_date = "Nothing to be done" in idle.output
    dag = run(snakemake("--configfile", QUICK_CONFIG, "--forceall", "--dag"), root, timeout=600)
    nodes, edges = parse_dag(dag.stdout)
    children: dict[str, list[str]] = {}
    for source, target in edges:
        children.setdefault(source, []).append(target)
    scene_job = next(n for n, label in nodes.items() if label.startswith("synth_segment "))
    segment = nodes[scene_job].split("=", 1)[1]
    below, stack = set(), list(children.get(scene_job, []))
    while stack:
        node = stack.pop()
        if node not in below:
            below.add(node)
            stack.extend(children.get(node, []))
    expected = Counter(nodes[n] for n in below)
    scene = root / QUICK_RESULTS / "scenes" / segment

    import numpy as np
    from PIL import Image

    image = scene / "images" / "000.png"
    pixels = np.array(Image.open(image))
    pixels[0, 0] = 255 - pixels[0, 0]
    Image.fromarray(pixels).save(image)  # rewritten in place, as an edit by hand would be
    rows = [_plan_row(root, nodes, expected, f"one pixel of {segment}'s images/000.png rewritten in place after a finished quick workflow", up_to_date)]
    # Snakemake takes a directory output's time from the .snakemake_timestamp file it leaves in it.
    (scene / ".snakemake_timestamp").touch()
    rows.append(_plan_row(root, nodes, expected, "then `touch` of the scene folder's `.snakemake_timestamp` (Snakemake's time of a folder output)", up_to_date))

    config = yaml.safe_load((root / QUICK_CONFIG).read_text())
    seed = int(config["synthetic"]["segments"][segment]) + 1
    ws.run(*recondreamer("synth", "--seed", str(seed), "--preset", config["synthetic"]["preset"], "--scene-id", segment, "--out", scene),
           must_pass=True)
    rows.append(_plan_row(root, nodes, expected, f"{segment}'s scene folder rewritten by hand (`recondreamer synth --seed {seed} --out` it)", up_to_date))
    return rows


# ------------------------------------------------------------------------------------ the suite


CASES: dict[str, Callable[[Workspace], list[Row]]] = {
    "corrupt_inputs": corrupt_inputs,
    "recon_kill": recon_kill,
    "restorer_kill": restorer_kill,
    "recondreamer_kill": recondreamer_kill,
    "evaluate_kill": evaluate_kill,
    "disk_full": disk_full,
    "second_snakemake": second_snakemake,
    "workflow_kills": workflow_kills,
    "scene_changed": scene_changed,
}


def run_cases(ws: Workspace, names: Sequence[str]) -> list[Row]:
    rows = []
    for name in names:
        started = time.monotonic()
        ws.log(f"{name} ...")
        try:
            new = CASES[name](ws)
        except Exception as error:  # a broken harness step is a failed row, not a lost suite
            ws.log(f"{name} failed:\n{error}")
            new = [Row(name, "-", f"the case itself failed: {type(error).__name__}: {quoted(str(error), 300)}", "-", False)]
        ws.log(f"{name}: {sum(r.ok for r in new)}/{len(new)} ok in {time.monotonic() - started:.0f} s")
        rows += new
    return rows


def document(table: str, names: Sequence[str], args: argparse.Namespace, seconds: float) -> str:
    return f"""# Reliability

What happens when things go wrong: damaged inputs, a job killed with `kill -9`, a disk that fills
up, two Snakemake runs on one results folder, a whole workflow killed at random moments, a scene
changed after a finished run. `benchmarks/faults.py` injects each fault into the real commands on
quick-sized data in a temporary folder and checks the outcome; the table below is its output.
Regenerate it with

```bash
python benchmarks/faults.py --out docs/reliability.md
```

(`--cases NAME...` runs some cases only, `--seed` changes the random kill moments,
`--workflow-kills N` the number of kills of the whole workflow, `--keep` keeps the temporary
folder). `tests/test_faults.py` runs the damaged-input checks and the `train-recon` kill in the
test suite.

What the cases check:

- **corrupt input**: for every kind of file a command reads, the command exits non-zero with one
  line naming the file and the problem (no Python traceback) and writes nothing at its `--out`.
  A bad config value is reported when the workflow is parsed, naming the config file that set it,
  the key and the value.
- **kill in train-recon / train-restorer / train-recondreamer / evaluate**: after a `kill -9` (past
  the first checkpoint; for train-recondreamer during a PDUS update and between two updates; for
  evaluate once its renders are on disk, before its metrics file), the same command resumes (its
  log says so) and ends with exactly the state an uninterrupted run ends with (every tensor
  compared, renders and restored frames compared pixel by pixel). No file under its final name is
  ever half-written; a kill in the middle of a write leaves that write's hidden temporary, which
  the rerun removes.
- **disk full**: a write that runs out of space ends with a one-line error naming the output; the
  earlier scene or checkpoint is intact and no temporary is left.
- **second snakemake**: a second run on a folder a first run is writing is refused, and after a
  killed run Snakemake says how to unlock.
- **workflow kills**: the quick workflow, killed with its whole process group at random moments and
  restarted until it finishes, gives the same tables, findings, metric files and model tensors as
  an uninterrupted run (model files also record training times and paths, which differ between
  any two runs).
- **scene changed**: after a segment's scene changes (a file edited in place, then the whole folder
  rewritten), the dry run plans exactly the jobs that depend on that scene in the job graph.
  Snakemake dates a folder output by the `.snakemake_timestamp` file it leaves inside; the
  workflow moves that date to the newest file of each scene folder when it parses
  (`restamp_edited_folder` in `recondreamer/io.py`), so an edit inside the folder is seen.

Cases {", ".join(f"`{n}`" for n in names)}; seed {args.seed}, {args.workflow_kills} workflow kill(s);
{seconds / 60:.0f} min wall on two CPU cores shared with other jobs.

{table}"""


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", nargs="+", choices=list(CASES), default=list(CASES), metavar="NAME", help=f"cases to run (default all: {' '.join(CASES)})")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random kill moments and garbage bytes (default 0)")
    parser.add_argument("--workflow-kills", type=int, default=5, help="kills of the whole quick workflow in workflow_kills (default 5)")
    parser.add_argument("--keep", action="store_true", help="keep the temporary folder (its path is printed)")
    parser.add_argument("--out", type=Path, default=None, help="also write the doc page (Markdown) here, e.g. docs/reliability.md")
    args = parser.parse_args(argv)
    names = [name for name in CASES if name in args.cases]  # cheapest first, whatever the order given
    started = time.monotonic()
    root = Path(tempfile.mkdtemp(prefix="recondreamer-faults-"))
    ws = Workspace(root, args.seed, args.workflow_kills, log=lambda text: print(text, file=sys.stderr, flush=True))
    try:
        rows = run_cases(ws, names)
    finally:
        if args.keep:
            print(f"kept {root}", file=sys.stderr)
        else:
            shutil.rmtree(root, ignore_errors=True)
    seconds = time.monotonic() - started
    table = markdown_table(rows)
    print(table)
    print(f"{sum(r.ok for r in rows)}/{len(rows)} ok, {seconds:.0f} s", file=sys.stderr)
    if args.out is not None:
        from recondreamer.io import write_text_atomic

        write_text_atomic(args.out, document(table, names, args, seconds))
    return 0 if all(r.ok for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
