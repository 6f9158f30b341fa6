# Helpers of every rule: paths, the experiment plan, config checks the schema cannot express.
# Run ids and output paths come from recondreamer.report.layout, the same module the table
# builder reads them with.

import os
import shlex
import sys

from snakemake.exceptions import WorkflowError

from recondreamer.io import restamp_edited_folder
from recondreamer.foundation.weights import WeightsError, verify_weight_set, weight_file
from recondreamer.report.layout import features_file, metrics_file, model_path, render_dir, restorer_checkpoint_path, run_dir, weight_set_dir
from recondreamer.experiment_plan import ExperimentPlan

RESULTS = config["results_dir"]
EXPERIMENT = config["experiment"]
TRAJECTORIES = list(EXPERIMENT["trajectories"])
DD4D_TRAJECTORIES = list(config["methods"]["dd4d_trajectories"])  # generated once per segment, shared by every backbone
TARGET = config["target"]  # experiment: the tables; foundation: a weight set (config/foundation.yaml)
WEIGHTS_DIR = weight_set_dir(config)  # None: this DAG trains the foundation models itself
FOUNDATION = config["foundation"]


def results(*parts):
    """A path below results_dir."""
    return os.path.join(RESULTS, *parts)


def log_file(rule_name, pattern):
    return results("logs", rule_name, f"{pattern}.log")


def benchmark_file(rule_name, pattern):
    return results("benchmarks", rule_name, f"{pattern}.tsv")


def parent(path, levels=1):
    """The directory ``levels`` above ``path`` (params derived from inputs/outputs, not hard-coded)."""
    for _ in range(levels):
        path = os.path.dirname(path)
    return path


def option(flag, value):
    """'--flag value', or '' when the config leaves the value to the command's default (null)."""
    return "" if value is None else f"{flag} {value}"


# ------------------------------------------------------------------------------------ checks


def _check_config():
    """Cross-key checks; each failure names the key and what is wrong (parse time, before any job)."""
    problems = []
    try:
        plan = ExperimentPlan.from_config(config)
    except ValueError as error:
        raise WorkflowError(f"config: {error}")
    if config["source"] == "synthetic":
        corpus = config["synthetic"]["corpus"]
        seeds = set(range(corpus["first_seed"], corpus["first_seed"] + corpus["num_scenes"]))
        evaluation_seeds = set(config["synthetic"]["segments"].values()) | set(FOUNDATION["reserved_seeds"])
        clash = sorted(seeds & evaluation_seeds)
        if clash and WEIGHTS_DIR is None:  # with a weight set the corpus is the set's (checked against its manifest)
            problems.append(f"synthetic.corpus seeds overlap the evaluation seeds (segments, foundation.reserved_seeds) {clash}")
        if TARGET == "foundation":
            clash = sorted(set(FOUNDATION["gate_seeds"]) & (seeds | evaluation_seeds))
            if clash:
                problems.append(f"foundation.gate_seeds {clash} overlap the corpus or evaluation seeds: gates need scenes no model saw")
    else:
        waymo = config["waymo"]
        missing = [
            os.path.join(waymo["tfrecord_dir"], spec["file"])
            for spec in waymo["segments"].values()
            if not os.path.isfile(os.path.join(waymo["tfrecord_dir"], spec["file"]))
        ]
        if missing:
            problems.append(
                f"missing segment file(s) for source 'waymo' ({len(missing)} of {len(waymo['segments'])}): "
                + ", ".join(missing)
                + ". Download these Waymo Open Dataset v1 validation segments and place them in "
                f"waymo.tfrecord_dir ({waymo['tfrecord_dir']}), or point waymo.tfrecord_dir at them."
            )
        for name, spec in waymo["segments"].items():
            if spec.get("end") is not None and spec["end"] < spec.get("start", 0):
                problems.append(f"waymo.segments.{name}: end {spec['end']} is before start {spec.get('start', 0)}")
        if config["preference"]["judge"] == "automatic":
            problems.append("preference.judge 'automatic' needs the true novel views of synthetic scenes; use 'people' or 'none' with source 'waymo'")
    if TARGET == "foundation" and WEIGHTS_DIR is not None:
        problems.append(f"target 'foundation' trains the foundation models: set foundation.weights to 'train' (it is {FOUNDATION['weights']!r})")
    if WEIGHTS_DIR is not None and config["restorer"]["refiner_steps"]:
        problems.append("restorer.refiner_steps > 0 trains a refiner on restorers this DAG trains: it needs foundation.weights 'train'")
    if config["preference"]["judge"] == "people":
        if not config["preference"]["answers"]:
            problems.append("preference.judge 'people' needs preference.answers (CSV files downloaded from the study page)")
        problems += [f"preference.answers: file {path} not found" for path in config["preference"]["answers"] if not os.path.isfile(path)]
    for key in ("detector", "lane_model", "fid_model"):
        path = config["eval_models"][key]
        if path is not None and not os.path.isfile(path):
            problems.append(f"eval_models.{key}: file {path} not found")
    for arch, path in config["restorer"]["checkpoints"].items():
        if path is not None and not os.path.isfile(path):
            problems.append(f"restorer.checkpoints.{arch}: file {path} not found")
    if config["eval_models"]["holdout_scenes"] >= config["synthetic"]["corpus"]["num_scenes"]:
        problems.append("eval_models.holdout_scenes must be smaller than synthetic.corpus.num_scenes")
    if config["restorer"]["pair_corpus_scenes"] > config["synthetic"]["corpus"]["num_scenes"]:
        problems.append("restorer.pair_corpus_scenes exceeds synthetic.corpus.num_scenes")
    if config["restorer"]["cycle_corpus_scenes"] > config["synthetic"]["corpus"]["num_scenes"]:
        problems.append("restorer.cycle_corpus_scenes exceeds synthetic.corpus.num_scenes")
    if config["restorer"]["cycle_corpus_scenes"] and not config["restorer"]["cycle_trajectories"]:
        problems.append("restorer.cycle_corpus_scenes is set but restorer.cycle_trajectories is empty (name the lateral drives, e.g. [shift@3, shift@6])")
    unshared = sorted(set(config["restorer"]["pair_segment_backbones"]) - set(plan.backbones))
    if unshared:
        problems.append(f"restorer.pair_segment_backbones {unshared} must be among experiment.recon_backbones (their baseline runs provide the pairs)")
    if not config["restorer"]["pair_segment_backbones"] and not config["restorer"]["pair_corpus_scenes"]:
        problems.append("no restoration pairs: set restorer.pair_segment_backbones or restorer.pair_corpus_scenes")
    if config["report"]["qualitative_trajectory"] not in TRAJECTORIES:
        problems.append(f"report.qualitative_trajectory {config['report']['qualitative_trajectory']!r} is not in experiment.trajectories")
    if config["report"]["dd4d_backbone"] not in plan.dd4d_backbones:
        problems.append(f"report.dd4d_backbone {config['report']['dd4d_backbone']!r} is not in experiment.dd4d_backbones")
    if problems:
        raise WorkflowError("invalid config:\n  - " + "\n  - ".join(problems))
    return plan


def _check_weight_set(plan):
    """The files of the weight set this run uses: listed, unaltered, loadable; trained on no evaluation seed.

    A job's own parse (the batch and job steps of every SLURM job) checks the hashes only: the main
    process loaded every file before submitting, and loading them again in each job would import
    torch and read the models twice per job (about 3 s of the quick SLURM test's 13 s per job)."""
    needed = [os.path.basename(path) for path in weight_set_files(plan)]
    try:
        manifest = verify_weight_set(WEIGHTS_DIR, needed, load=workflow.is_main_process)
    except WeightsError as error:
        raise WorkflowError(f"foundation.weights {FOUNDATION['weights']!r}: {error}")
    if config["source"] == "synthetic":
        first, last = manifest["corpus"]["seeds"]
        seen = set(range(first, last + 1)) | set(manifest["gate_scenes"]["seeds"])
        clash = sorted(seen & set(config["synthetic"]["segments"].values()))
        if clash:
            raise WorkflowError(f"synthetic.segments seeds {clash} are corpus or gate seeds of the weight set {WEIGHTS_DIR}: evaluate on seeds its models never saw")


def weight_set_files(plan):
    """The weight-set files a run reads (those not replaced by a configured local file)."""
    files = [restorer_checkpoint_path(config, arch) for arch in plan.restorers]
    if plan.dd4d_backbones:
        files.append(model_path(config, "world_model", "dd2"))
    files += eval_model_files()
    return [path for path in files if WEIGHTS_DIR is not None and os.path.dirname(path) == str(WEIGHTS_DIR)]


PLAN = _check_config()
SEGMENTS = list(PLAN.segments)
RUNS = PLAN.runs()
CORPUS_SCENES = [f"corpus-{i:03d}" for i in range(config["synthetic"]["corpus"]["num_scenes"])]
PAIR_CORPUS_SCENES = CORPUS_SCENES[: config["restorer"]["pair_corpus_scenes"]]
CYCLE_CORPUS_SCENES = CORPUS_SCENES[: config["restorer"]["cycle_corpus_scenes"]]
CYCLE_BACKBONE = "street"  # run A of every cycle: the corpus scene's Street Gaussians run (recon.smk)
WORLD_MODEL_OF = {"sd": "sd", "svd": "svd", "dd2": "dd2", "dd2_mask": "dd2"}  # dd2_mask fine-tunes the dd2 world model
TABLES = [1, 2, 4, 5] if config["preference"]["judge"] == "none" else [1, 2, 3, 4, 5]
# Scheduling priorities (config/README.md, "Time"). No ReconDreamer run can start before the
# restorers exist, so the chain corpus -> autoencoder -> world models -> pairs -> restorers goes
# first; the baselines the pairs read and the evaluation models every evaluation waits for come next.
RESTORER_PATH_PRIORITY = 10
FEEDER_PRIORITY = 5


def _restamp_edited_scenes():
    """A scene edited in place after its rule finished is dated by its newest file (parse time), so
    what was computed from it is planned again; the user is told which files."""
    for folder in [results("scenes", s) for s in SEGMENTS] + [results("corpus", c) for c in CORPUS_SCENES]:
        edited = restamp_edited_folder(folder)
        if edited:
            shown = ", ".join(os.path.relpath(path, folder) for path in edited[:3]) + (", ..." if len(edited) > 3 else "")
            print(f"{folder}: {len(edited)} file(s) edited after the scene was written ({shown}): "
                  "what depends on the scene is planned again", file=sys.stderr)


_restamp_edited_scenes()


wildcard_constraints:
    segment="[A-Za-z0-9][A-Za-z0-9_.-]*",
    corpus_scene=r"corpus-\d+",
    backbone="street|pvg|deformable|s3",
    restorer="sd|svd|dd2|dd2_mask",
    arch="sd|svd|dd2",
    stride=r"\d+\.\d+",
    trajectory=r"shift@-?\d+(\.\d+)?|lane_change",
    cycle_trajectory=r"shift@-?\d+(\.\d+)?|lane_change",
    run=r"(baseline|dd4d)-(street|pvg|deformable|s3)|recondreamer-(street|pvg|deformable|s3)-(sd|svd|dd2|dd2_mask|truth)-stride\d+\.\d+",


# ------------------------------------------------------------------------------------ paths


def scene_dir(segment):
    return results("scenes", segment)


def corpus_scene_dirs():
    return [results("corpus", name) for name in CORPUS_SCENES]


def run_model(segment, run_id):
    """The final model file of a run: what the DAG tracks (the run directory keeps checkpoints for resume)."""
    return str(run_dir(RESULTS, segment, run_id) / "model.pt")


def render_dirs(segment, run_id):
    """A run's render directories, one per evaluated trajectory (segment and run may be wildcards)."""
    return [str(render_dir(RESULTS, segment, run_id, t)) for t in TRAJECTORIES]


def all_metrics_files():
    return [str(metrics_file(RESULTS, s, m.run_id)) for s in SEGMENTS for m in RUNS]


def all_features_files():
    return [str(features_file(RESULTS, s, m.run_id)) for s in SEGMENTS for m in RUNS]


def note_model_files():
    """The model files the tables' notes describe (restorers, world models, autoencoder, evaluation models)."""
    files = [restorer_checkpoint(arch) for arch in PLAN.restorers]
    files += [model_path(config, "world_model", arch) for arch in sorted({WORLD_MODEL_OF[r] for r in PLAN.restorers}) if not config["restorer"]["checkpoints"].get(arch)]
    files += [model_path(config, "autoencoder")]
    return sorted(set(files)) + eval_model_files()


def eval_model_files():
    """The evaluation models that the evaluation uses (those not replaced by a configured local file)."""
    kinds = {"detector": "vehicle_detector", "lane_model": "lane_segmenter", "fid_model": "fid_features"}
    return [model_path(config, kind) for key, kind in kinds.items() if config["eval_models"][key] is None]


def restorer_checkpoint(arch):
    return restorer_checkpoint_path(config, arch)


if WEIGHTS_DIR is not None and TARGET == "experiment":
    _check_weight_set(PLAN)  # at parse time: no job starts on a missing, altered or unloadable model file


def write_run_config(values, path, log_path):
    import yaml

    from recondreamer.io import write_text_atomic

    write_text_atomic(path, yaml.safe_dump(dict(values), sort_keys=False))
    with open(log_path, "w") as handle:
        handle.write(f"wrote {path}\n")


def win_rates_file():
    judge = config["preference"]["judge"]
    if judge == "automatic":
        return results("preference", "judge.json")
    if judge == "people":
        return results("preference", "people.json")
    return None


def plan_arguments():
    return " ".join(PLAN.to_arguments())


def final_outputs():
    if TARGET == "foundation":
        return [os.path.join(FOUNDATION["out_dir"], "manifest.json")]
    outputs = [results("tables", f"table{n}.{suffix}") for n in TABLES for suffix in ("csv", "md", "tex", "html")]
    outputs += plot_files()
    outputs += [results("findings.md"), results("findings.html"), results("study"), results("benchmark_summary.html")]
    outputs += clip_files() + [results("run_config.html")]
    return outputs


def plot_files():
    names = ["metric_vs_shift.png", "stride_curve.png", "restorer_bars.png"]
    names += [f"qualitative_{s}.png" for s in SEGMENTS] + [f"pdus_{s}.png" for s in SEGMENTS]
    return [results("plots", name) for name in names]


# ------------------------------------------------------------------------------------ restorer


def pair_dirs():
    dirs = []
    if config["restorer"]["pair_segment_backbones"]:
        dirs += [results("pairs", "segments", s) for s in SEGMENTS]
    dirs += [results("pairs", "corpus", c) for c in PAIR_CORPUS_SCENES]
    dirs += [results("pairs", "cycle", c, t) for c in CYCLE_CORPUS_SCENES for t in config["restorer"]["cycle_trajectories"]]
    return dirs


# ------------------------------------------------------------------------------------ foundation

FOUNDATION_RESTORERS = list(EXPERIMENT["restorer_backbones"])


def published_files():
    """weight-set file name -> the file this DAG trained."""
    files = {"autoencoder.pt": results("models", "autoencoder.pt")}
    files.update({f"world_model_{arch}.pt": results("models", f"world_model_{arch}.pt") for arch in sorted({WORLD_MODEL_OF[r] for r in FOUNDATION_RESTORERS})})
    files.update({f"restorer_{arch}.pt": results("models", f"restorer_{arch}.pt") for arch in FOUNDATION_RESTORERS})
    files.update({name: results("eval_models", name) for name in ("vehicle_detector.pt", "lane_segmenter.pt", "fid_features.pt")})
    return files


# ------------------------------------------------------------------------------------ preference (table 3)


def preference_pairs():
    """(segment, trajectory, ReconDreamer render dir, opponent run id, opponent render dir) of table 3."""
    ours = PLAN.preference_method().run_id
    return [
        (s, t, str(render_dir(RESULTS, s, ours, t)), versus, str(render_dir(RESULTS, s, versus, t)))
        for s in SEGMENTS
        for t in TRAJECTORIES
        for versus in PLAN.preference_versus
    ]


def preference_render_dirs():
    return sorted({d for _, _, a, _, b in preference_pairs() for d in (a, b)})


# ------------------------------------------------------------------------------------ report

TABLE_NAMES = {
    1: "Table 1: method comparison",
    2: "Table 2: versus DriveDreamer4D",
    3: "Table 3: preference win rates",
    4: "Table 4: restorer backbones",
    5: "Table 5: PDUS strides",
}


def table_outputs():
    outputs = []
    for n in TABLES:
        html = results("tables", f"table{n}.html")
        labels = {"table": str(n), "format": "html"}
        outputs.append(report(html, caption=f"../report/table{n}.rst", category="1. Tables", subcategory=TABLE_NAMES[n], labels=labels))
        outputs += [results("tables", f"table{n}.{suffix}") for suffix in ("csv", "md", "tex")]
        outputs.append(results("tables", f"table{n}_sources.csv"))
    return outputs


def figure(name, caption, subcategory, labels):
    return report(results("plots", name), caption=f"../report/{caption}.rst", category="2. Figures", subcategory=subcategory, labels=labels)


def qualitative_methods():
    return [PLAN.baseline(PLAN.ablation_backbone), PLAN.dd4d(config["report"]["dd4d_backbone"]), PLAN.preference_method()]


# The novel-view clips: the first report.clip_segments segments along the qualitative trajectory.
CLIP_SEGMENTS = SEGMENTS[: config["report"]["clip_segments"]]


def clip_files():
    return [results("clips", f"{s}.{suffix}") for s in CLIP_SEGMENTS for suffix in ("gif", "webm", "html")]


def qualitative_render(segment, method):
    """The render folder of ``method`` along the qualitative trajectory (segment may be a wildcard)."""
    return str(render_dir(RESULTS, segment, method.run_id, config["report"]["qualitative_trajectory"]))


def clip_panel_arguments(degraded, restored, recondreamer):
    """'--panel LABEL=DIR' for each folder of a clip, left to right, quoted for the shell (labels have spaces)."""
    baseline = PLAN.baseline(PLAN.ablation_backbone)
    panels = [(f"degraded ({baseline.label})", degraded), ("restored (DriveRestorer)", restored), (f"ReconDreamer ({baseline.label})", recondreamer)]
    return " ".join(f"--panel {shlex.quote(f'{label}={path}')}" for label, path in panels)
