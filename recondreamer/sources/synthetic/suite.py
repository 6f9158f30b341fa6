"""The default synthetic suite: the evaluation segments and the training corpus of a config file.

Names, seeds and presets come from the ``synthetic:`` section of a workflow config (layered over
``config/config.yaml`` as the Snakefile layers it, ``configs.workflow_config``); scenes
go to ``<results_dir>/scenes/<name>/`` and ``<results_dir>/corpus/<name>/``. A scene that is
already on disk, loads, and was made by this generator version from the same seed and settings
is kept, so an interrupted suite resumes where it stopped (each scene is written atomically).
"""

from __future__ import annotations

import dataclasses
import logging
import time as clock
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from recondreamer.configs import workflow_config
from recondreamer.errors import RecondreamerError
from recondreamer.sources.synthetic.config import PRESETS, make_config

log = logging.getLogger(__name__)
GROUPS = ("segments", "corpus")


@dataclass(frozen=True)
class SuiteJob:
    """One scene of the suite."""

    group: str  # "segments" | "corpus"
    name: str
    seed: int
    preset: str
    out: Path


def _require(mapping: object, key: str, kind: type | tuple[type, ...], where: str, file: Path):
    if not isinstance(mapping, dict) or key not in mapping:
        raise RecondreamerError(f"{file}: missing key {where}{key}")
    value = mapping[key]
    if not isinstance(value, kind) or isinstance(value, bool):
        raise RecondreamerError(f"{file}: {where}{key} has the wrong type ({type(value).__name__})")
    return value


def _preset(value: object, where: str, file: Path) -> str:
    if value not in PRESETS:
        raise RecondreamerError(f"{file}: {where} = {value!r} is not a synthetic preset ({', '.join(PRESETS)})")
    return str(value)


def load_suite(config_path: str | Path) -> list[SuiteJob]:
    """Every scene of the suite described by the config file, segments first."""
    file = Path(config_path)
    config = workflow_config(file)
    results = Path(_require(config, "results_dir", str, "", file))  # relative: to the working directory, as in Snakemake
    synthetic = _require(config, "synthetic", dict, "", file)
    preset = _preset(_require(synthetic, "preset", str, "synthetic.", file), "synthetic.preset", file)
    segments = _require(synthetic, "segments", dict, "synthetic.", file)
    jobs = []
    for name, seed in segments.items():
        if not isinstance(name, str) or not name or "/" in name:
            raise RecondreamerError(f"{file}: synthetic.segments: {name!r} is not a valid scene name")
        if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
            raise RecondreamerError(f"{file}: synthetic.segments.{name}: seed must be a non-negative integer, got {seed!r}")
        jobs.append(SuiteJob("segments", name, seed, preset, results / "scenes" / name))
    corpus = _require(synthetic, "corpus", dict, "synthetic.", file)
    count = _require(corpus, "num_scenes", int, "synthetic.corpus.", file)
    first = _require(corpus, "first_seed", int, "synthetic.corpus.", file)
    corpus_preset = _preset(_require(corpus, "preset", str, "synthetic.corpus.", file), "synthetic.corpus.preset", file)
    if count < 0 or first < 0:
        raise RecondreamerError(f"{file}: synthetic.corpus.num_scenes and first_seed must be non-negative")
    corpus_seeds = range(first, first + count)
    clash = sorted({job.seed for job in jobs} & set(corpus_seeds))
    if clash:
        raise RecondreamerError(f"{file}: synthetic.corpus seeds {first}..{first + count - 1} overlap the evaluation segment seed(s) {clash}; the corpus must use disjoint seeds")
    jobs += [SuiteJob("corpus", f"corpus-{i:03d}", seed, corpus_preset, results / "corpus" / f"corpus-{i:03d}") for i, seed in enumerate(corpus_seeds)]
    return jobs


def is_current(job: SuiteJob) -> bool:
    """True when ``job.out`` holds a valid scene made from the same seed, preset and generator."""
    from recondreamer.scene import load_scene
    from recondreamer.sources.synthetic.segment import GENERATOR_VERSION

    if not (job.out / "scene.json").is_file():
        return False
    try:
        scene = load_scene(job.out)
    except RecondreamerError as error:
        log.warning("%s will be rebuilt: %s", job.out, error)
        return False
    meta = scene.metadata
    return (
        meta.get("generator_version") == GENERATOR_VERSION
        and meta.get("seed") == job.seed
        and meta.get("config") == dataclasses.asdict(make_config(job.preset))
        and scene.scene_id == job.name
    )


def build_scene(job: SuiteJob) -> float:
    """Generate and write one scene; returns the seconds it took."""
    from recondreamer.io import check_replaceable
    from recondreamer.scene import write_scene
    from recondreamer.sources.synthetic.segment import generate_segment

    check_replaceable(job.out, "scene")
    started = clock.perf_counter()
    write_scene(job.out, generate_segment(job.seed, job.preset, scene_id=job.name))
    return clock.perf_counter() - started


def run_suite(config_path: str | Path, only: str | None = None, jobs: int = 1, force: bool = False) -> list[SuiteJob]:
    """Build the missing or outdated scenes of the suite; returns the jobs that were built."""
    if jobs < 1:
        raise RecondreamerError(f"--jobs {jobs}: must be at least 1")
    planned = [job for job in load_suite(config_path) if only in (None, job.group)]
    todo = [job for job in planned if force or not is_current(job)]
    log.info("synthetic suite: %d scenes, %d already current, %d to build with %d process(es)", len(planned), len(planned) - len(todo), len(todo), jobs)
    started = clock.perf_counter()
    if jobs == 1:
        results = map(build_scene, todo)
    else:
        pool = ProcessPoolExecutor(max_workers=jobs)
        results = pool.map(build_scene, todo)
    try:
        for done, (job, seconds) in enumerate(zip(todo, results), start=1):
            elapsed = clock.perf_counter() - started
            eta = elapsed / done * (len(todo) - done)
            log.info("[%d/%d] %s (seed %d) written to %s in %.1f s; ETA %.0f s", done, len(todo), job.name, job.seed, job.out, seconds, eta)
    finally:
        if jobs > 1:
            pool.shutdown(cancel_futures=True)
    return todo


def write_previews(config_path: str | Path) -> list[Path]:
    """Draw ``<results_dir>/previews/<name>.png`` for every evaluation segment of the suite.

    A sheet newer than its scene's ``scene.json`` is kept; returns the paths of all sheets.
    """
    from recondreamer.sources.synthetic.preview import contact_sheet

    preview_dir = Path(workflow_config(config_path)["results_dir"]) / "previews"
    sheets = []
    for job in load_suite(config_path):
        if job.group != "segments":
            continue
        sheet = preview_dir / f"{job.name}.png"
        scene_file = job.out / "scene.json"
        if not scene_file.is_file():
            raise RecondreamerError(f"{scene_file}: missing; build the segment before drawing its preview")
        if not sheet.is_file() or sheet.stat().st_mtime < scene_file.stat().st_mtime:
            contact_sheet(job.out, sheet)
        sheets.append(sheet)
    return sheets
