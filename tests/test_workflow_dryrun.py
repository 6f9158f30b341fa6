"""The Snakemake workflow at parse time: dry runs of the shipped configs with the expected job
counts per rule, bad configs failing with the schema's message, and the linter."""

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from recondreamer.configs import workflow_config

REPO = Path(__file__).resolve().parents[1]
WORKFLOW_FILES = ("Snakefile", "workflow", "config", "profiles")


def workflow_copy(tmp_path: Path) -> Path:
    """The workflow files in a fresh directory, so that dry runs touch nothing in the checkout."""
    root = tmp_path / "wf"
    root.mkdir()
    for name in WORKFLOW_FILES:
        source = REPO / name
        (shutil.copytree if source.is_dir() else shutil.copy)(source, root / name)
    return root


def snakemake(root: Path, *args: str) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "snakemake", "--nolock", *args]
    return subprocess.run(command, check=False, cwd=root, capture_output=True, text=True, timeout=120)


def job_counts(output: str) -> dict[str, int]:
    """The 'Job stats' table of a dry run: rule -> number of jobs."""
    block = output.split("Job stats:")[1]
    counts = {}
    for line in block.splitlines()[3:]:
        match = re.match(r"^(\w+)\s+(\d+)$", line.strip())
        if not match:
            break
        counts[match.group(1)] = int(match.group(2))
    return counts


def expected_counts(segments: int, corpus: int, pair_corpus: int, pair_segments: bool, judge: bool, synthetic: bool, foundation: bool = True) -> dict[str, int]:
    """Jobs per rule derived from the paper's design, independently of the workflow code;
    ``foundation``: the DAG trains its own foundation models (``foundation.weights: train``)."""
    runs_per_segment = 4 + 3 + 4 + 3 + 4  # baselines, DD4D on 3, ReconDreamer main on 4 backbones, +3 restorers, +4 strides
    runs_per_segment += 1 if synthetic else 0  # table 1's upper bound: the true novel views in the loop
    counts = {
        ("synth_segment" if synthetic else "convert_waymo"): segments,
        "synth_corpus_scene": corpus,
        "train_eval_models": 1,
        "train_autoencoder": 1,
        "pretrain_world_model": 3,  # sd, svd, dd2 (dd2_mask fine-tunes dd2)
        "train_baseline": 4 * segments,
        "train_corpus_recon": pair_corpus,
        "make_pairs_segment": segments if pair_segments else 0,
        "make_pairs_corpus": pair_corpus,
        "train_restorer": 4,
        "generate_dd4d": 3 * segments,  # DriveDreamer4D's 3 trajectories, generated once per segment
        "train_dd4d": 3 * segments,
        "train_recondreamer": 11 * segments,
        "train_recondreamer_truth": segments if synthetic else 0,
        "evaluate": runs_per_segment * segments,  # renders the run along every trajectory, then scores it
        "judge": 1 if judge else 0,
        "study_page": 1,
        "run_config": 1,
        "make_tables": 1,
        "findings": 1,
        "make_plots": 1,
        "pdus_figure": segments,
        "restore_clip": min(segments, 2),  # the novel-view clips of the first report.clip_segments (2) segments
        "novel_view_clip": min(segments, 2),
        "config_page": 1,
        "benchmark_summary": 1,
        "all": 1,
    }
    if not foundation:  # a weight set brings the corpus-trained models and nothing of the corpus is built
        for rule in FOUNDATION_RULES:
            counts[rule] = 0
    counts = {rule: n for rule, n in counts.items() if n}
    counts["total"] = sum(counts.values())
    return counts


FOUNDATION_RULES = ("synth_corpus_scene", "train_eval_models", "train_autoencoder", "pretrain_world_model", "train_corpus_recon", "make_pairs_segment", "make_pairs_corpus", "train_restorer")
FOUNDATION_TRAINING = ("train-autoencoder", "pretrain-world-model", "train-restorer", "train-eval-models", "train-refiner", "make-pairs")


@pytest.mark.parametrize(("configfile", "scene_preset", "iterations", "shipped"), [("config/config.yaml", "compact", "--iterations 700", True), ("config/full.yaml", "default", None, False)])
def test_synthetic_configs_dry_run_job_counts(tmp_path, configfile, scene_preset, iterations, shipped):
    """The default (compact, on the shipped weight set) and full-size (training its own models)
    synthetic configs build the same experiment DAG at different sizes."""
    root = workflow_copy(tmp_path)
    result = snakemake(root, "-n", "--quiet", "rules", "--configfile", configfile)
    assert result.returncode == 0, result.stderr
    assert job_counts(result.stdout + result.stderr) == expected_counts(8, 24, 4, True, judge=True, synthetic=True, foundation=not shipped)
    everything = snakemake(root, "-n", "--printshellcmds", "--configfile", configfile).stdout
    trained = [command for command in FOUNDATION_TRAINING if f"recondreamer {command} " in everything]
    assert trained == ([] if shipped else [c for c in FOUNDATION_TRAINING if c not in ("train-refiner",)])
    shell = snakemake(root, "-n", "--printshellcmds", "--configfile", configfile, "--until", "train_baseline").stdout
    synth = [line for line in shell.splitlines() if "recondreamer synth " in line]
    train = [line for line in shell.splitlines() if "recondreamer train-recon " in line]
    assert len(synth) == 8 and all(f"--preset {scene_preset} " in line for line in synth)
    assert len(train) == 4 * 8 and all((iterations in line) if iterations else ("--iterations" not in line) for line in train)


def test_paper_waymo_config_dry_run_job_counts(tmp_path):
    root = workflow_copy(tmp_path)
    paper = yaml.safe_load((root / "config" / "paper-waymo.yaml").read_text())
    records = root / "resources" / "waymo"
    records.mkdir(parents=True)
    for spec in paper["waymo"]["segments"].values():
        (records / spec["file"]).write_bytes(b"")  # placeholders: a dry run only checks that they exist
    result = snakemake(root, "-n", "--quiet", "rules", "--configfile", "config/paper-waymo.yaml")
    assert result.returncode == 0, result.stderr
    assert job_counts(result.stdout + result.stderr) == expected_counts(8, 64, 16, True, judge=False, synthetic=False)
    # The frame ranges of the paper's supplement reach the converter.
    shell = snakemake(root, "-n", "--printshellcmds", "--configfile", "config/paper-waymo.yaml", "--until", "convert_waymo")
    assert "segment-10359308928573410754_720_000_740_000_with_camera_labels.tfrecord --out results/paper-waymo/scenes/10359308928573410754 --start 120 --end 159" in shell.stdout
    # Reconstructions train on the GPU with gsplat, DriveDreamer4D reads the videos generated once per segment.
    shell = snakemake(root, "-n", "--printshellcmds", "--configfile", "config/paper-waymo.yaml", "--until", "train_dd4d")
    train = [line for line in shell.stdout.splitlines() if re.search(r"recondreamer train-(recon|dd4d|recondreamer) ", line)]
    assert train and all("--backend gsplat --device cuda" in line for line in train)
    assert all("--generated results/paper-waymo/dd4d_generated/" in line for line in train if "train-dd4d" in line)
    # evaluate renders the runs on the GPU too.
    shell = snakemake(root, "-n", "--printshellcmds", "--configfile", "config/paper-waymo.yaml", "--until", "evaluate")
    evaluate = [line for line in shell.stdout.splitlines() if "recondreamer evaluate " in line]
    assert len(evaluate) == 18 * 8 and all(" --run results/paper-waymo/runs/" in line and " --device cuda " in line for line in evaluate)


def test_local_restorer_checkpoint_replaces_training_that_restorer(tmp_path):
    root = workflow_copy(tmp_path)
    (root / "my_restorer.pt").write_bytes(b"")  # a dry run only checks that it exists
    config = yaml.safe_load((root / "config" / "quick.yaml").read_text())
    config["restorer"]["checkpoints"] = {"dd2_mask": "my_restorer.pt"}
    (root / "local.yaml").write_text(yaml.safe_dump(config))
    plain = job_counts(snakemake(root, "-n", "--quiet", "rules", "--configfile", "config/quick.yaml").stdout)
    result = snakemake(root, "-n", "--quiet", "rules", "--configfile", "local.yaml")
    assert result.returncode == 0, result.stderr
    assert job_counts(result.stdout) == {**plain, "train_restorer": plain["train_restorer"] - 1,
                                         "total": plain["total"] - 1}
    shell = snakemake(root, "-n", "--printshellcmds", "--configfile", "local.yaml", "--until", "train_recondreamer").stdout
    commands = [line for line in shell.splitlines() if "recondreamer train-recondreamer" in line]
    assert any("dd2_mask" in line for line in commands)
    assert all(("--restorer my_restorer.pt" in line) == ("-dd2_mask-" in line) for line in commands)
    config["restorer"]["checkpoints"] = {"dd2_mask": "absent.pt"}
    (root / "local.yaml").write_text(yaml.safe_dump(config))
    result = snakemake(root, "-n", "--quiet", "rules", "--configfile", "local.yaml")
    assert result.returncode != 0 and "restorer.checkpoints.dd2_mask: file absent.pt not found" in result.stdout + result.stderr


def test_refiner_steps_add_a_refiner_to_every_trained_restorer_and_the_runs_use_it(tmp_path):
    root = workflow_copy(tmp_path)
    config = yaml.safe_load((root / "config" / "quick.yaml").read_text())
    config["restorer"]["refiner_steps"] = 40
    config["restorer"]["refiner_neighbours"] = 2
    config["restorer"]["checkpoints"] = {"dd2": "my_dd2.pt"}  # a local restorer is used as it is
    (root / "my_dd2.pt").write_bytes(b"")
    (root / "refine.yaml").write_text(yaml.safe_dump(config))
    plain = job_counts(snakemake(root, "-n", "--quiet", "rules", "--configfile", "config/quick.yaml").stdout)
    result = snakemake(root, "-n", "--quiet", "rules", "--configfile", "refine.yaml")
    assert result.returncode == 0, result.stderr
    assert job_counts(result.stdout) == {**plain, "train_restorer": plain["train_restorer"] - 1, "train_refiner": plain["train_restorer"] - 1,
                                         "total": plain["total"] + plain["train_restorer"] - 2}
    shell = snakemake(root, "-n", "--printshellcmds", "--configfile", "refine.yaml", "--until", "train_recondreamer").stdout
    refine = re.findall(r"recondreamer train-refiner --restorer \S+restorer_(\w+)\.pt .*?--out \S+restorer_(\w+)_refined\.pt --steps 40 --temporal-neighbours 2 --seed 0", shell)
    assert sorted(refine) == sorted((arch, arch) for arch in ("sd", "svd", "dd2_mask"))
    runs = [line for line in shell.splitlines() if "recondreamer train-recondreamer" in line]
    assert runs and all(re.search(r"--restorer (my_dd2\.pt|\S+_refined\.pt) ", line) for line in runs)


def test_cycle_pairs_add_a_cycle_per_scene_and_drive_and_every_restorer_trains_on_them(tmp_path):
    root = workflow_copy(tmp_path)
    config = yaml.safe_load((root / "config" / "quick.yaml").read_text())
    config["restorer"]["cycle_corpus_scenes"] = 2  # corpus-000 (also a pairs scene) and corpus-001
    config["restorer"]["cycle_trajectories"] = ["shift@3", "shift@6"]
    (root / "cycle.yaml").write_text(yaml.safe_dump(config))
    plain = job_counts(snakemake(root, "-n", "--quiet", "rules", "--configfile", "config/quick.yaml").stdout)
    result = snakemake(root, "-n", "--quiet", "rules", "--configfile", "cycle.yaml")
    assert result.returncode == 0, result.stderr
    # corpus-001 needs its Street Gaussians run (run A of its cycles); corpus-000 has one already.
    assert job_counts(result.stdout) == {**plain, "make_cycle_pairs_corpus": 4, "train_corpus_recon": plain["train_corpus_recon"] + 1,
                                         "total": plain["total"] + 5}
    shell = snakemake(root, "-n", "--printshellcmds", "--configfile", "cycle.yaml", "--until", "train_restorer").stdout
    cycles = re.findall(r"recondreamer make-cycle-pairs --run \S+/corpus_runs/(corpus-\d+)/street --scene \S+/corpus/\1 "
                        r"--trajectory (\S+) --cycle-run \S+/cycle_runs/\1/\2 --out \S+/pairs/cycle/\1/\2 --preset quick", shell)
    assert sorted(cycles) == [(scene, drive) for scene in ("corpus-000", "corpus-001") for drive in ("shift@3", "shift@6")]
    trainings = [line for line in shell.splitlines() if "recondreamer train-restorer" in line]
    assert len(trainings) == 4 and all(line.count("/pairs/cycle/corpus-") == 4 for line in trainings)
    config["restorer"]["cycle_corpus_scenes"] = 0  # the default: the paper's pairs only
    (root / "cycle.yaml").write_text(yaml.safe_dump(config))
    shell = snakemake(root, "-n", "--printshellcmds", "--configfile", "cycle.yaml", "--until", "train_restorer").stdout
    assert "make-cycle-pairs" not in shell and "/pairs/cycle/" not in shell


def _bad_config(root: Path, edit) -> str:
    config = workflow_config("config/quick.yaml", root=root)
    edit(config)
    (root / "bad.yaml").write_text(yaml.safe_dump(config))
    result = snakemake(root, "-n", "--quiet", "rules", "--configfile", "bad.yaml")
    assert result.returncode != 0
    return result.stdout + result.stderr


def test_bad_configs_fail_at_parse_time_with_the_schema_message(tmp_path):
    root = workflow_copy(tmp_path)
    message = _bad_config(root, lambda c: c["experiment"]["recon_backbones"].append("nerf"))
    assert "'nerf' is not one of ['street', 'pvg', 'deformable', 's3']" in message
    message = _bad_config(root, lambda c: c["experiment"].update(strides=[0.5, -1.5, 6.0]))
    assert "-1.5 is less than or equal to the minimum of 0" in message

    def missing_segment_file(config):
        config["source"] = "waymo"
        config["preference"]["judge"] = "none"
        config["waymo"] = {"tfrecord_dir": "resources/waymo", "segments": {"seg": {"file": "absent.tfrecord", "start": 0, "end": 39}}}

    message = _bad_config(root, missing_segment_file)
    assert "missing segment file(s)" in message and "resources/waymo/absent.tfrecord" in message
    message = _bad_config(root, lambda c: c["restorer"].update(cycle_corpus_scenes=99))
    assert "restorer.cycle_corpus_scenes exceeds synthetic.corpus.num_scenes" in message
    message = _bad_config(root, lambda c: c["restorer"].update(cycle_corpus_scenes=1, cycle_trajectories=[]))
    assert "restorer.cycle_trajectories is empty" in message


def test_lint_reports_nothing(tmp_path):
    """Snakemake's linter on the whole workflow (every rule has log, benchmark and a conda env)."""
    root = workflow_copy(tmp_path)
    result = snakemake(root, "--lint")
    text = result.stdout + result.stderr
    assert result.returncode == 0, text
    assert re.findall(r"^\s+\* (.+?):?$", text, flags=re.MULTILINE) == []
    assert "Congratulations, your workflow is in a good condition!" in text


def test_slurm_profile_gives_gpu_rules_a_gpu_and_memory_growing_with_attempts(tmp_path):
    """The slurm profile's resources, evaluated by Snakemake (without the executor plugin, not installed here)."""
    root = workflow_copy(tmp_path)
    profile = yaml.safe_load((root / "profiles" / "slurm" / "config.yaml").read_text())
    assert profile["executor"] == "slurm" and profile["retries"] >= 1
    assert all("attempt" in str(resources["mem_mb"]) for resources in profile["set-resources"].values())
    local = {key: value for key, value in profile.items() if key != "executor"}
    (root / "slurm-local").mkdir()
    (root / "slurm-local" / "config.yaml").write_text(yaml.safe_dump(local))
    result = snakemake(root, "-n", "--workflow-profile", "slurm-local", "--configfile", "config/quick.yaml", "--until", "train_baseline", "synth_corpus_scene")
    assert result.returncode == 0, result.stderr
    text = result.stdout + result.stderr
    jobs = re.findall(r"^(?:local)?rule (\w+):.*?resources: ([^\n]+)", text, flags=re.MULTILINE | re.DOTALL)
    by_rule = {rule: resources for rule, resources in jobs}
    first_attempt_mb = {  # the profile's "N * attempt" expressions on attempt 1
        rule: int(str(resources["mem_mb"]).split("*")[0])
        for rule, resources in [("default", profile["default-resources"]), *profile["set-resources"].items()]
    }
    assert "gpu=1" in by_rule["train_baseline"]
    assert f"mem_mb={first_attempt_mb['train_baseline']}," in by_rule["train_baseline"]
    assert "gpu=1" not in by_rule["synth_corpus_scene"]
    assert f"mem_mb={first_attempt_mb['default']}," in by_rule["synth_corpus_scene"]
    assert first_attempt_mb["train_baseline"] != first_attempt_mb["default"]  # the rule's own line, not the default


def test_restorer_steps_and_crop_reach_every_fine_tuning_alike(tmp_path):
    root = workflow_copy(tmp_path)
    config = yaml.safe_load((root / "config" / "quick.yaml").read_text())
    config["restorer"].update(steps=35, crop=[0, 0])
    (root / "steps.yaml").write_text(yaml.safe_dump(config))
    shell = snakemake(root, "-n", "--printshellcmds", "--configfile", "steps.yaml", "--until", "train_restorer").stdout
    steps = dict(re.findall(r"train-restorer --arch (\w+) .*?--steps (\d+) --crop 0 0 ", shell))
    assert steps == {"sd": "35", "svd": "35", "dd2": "35", "dd2_mask": "35"}


def test_foundation_config_dry_run_builds_every_foundation_model_and_its_gates(tmp_path):
    root = workflow_copy(tmp_path)
    result = snakemake(root, "-n", "--quiet", "rules", "--configfile", "config/foundation.yaml")
    assert result.returncode == 0, result.stderr
    expected = {
        "synth_corpus_scene": 120, "synth_gate_scene": 4, "train_gate_recon": 4, "make_gate_pairs": 4,
        # Street Gaussians runs on all 120 scenes (the cycles' run A, four lateral drives each), the three other backbones on the 16 pairs scenes.
        "train_corpus_recon": 120 + 16 * 3, "make_pairs_corpus": 16, "make_cycle_pairs_corpus": 120 * 4,
        "train_autoencoder": 1, "pretrain_world_model": 3,
        "train_restorer": 4, "train_eval_models": 1, "foundation_gates": 1, "publish_weights": 1, "all": 1,
    }
    assert job_counts(result.stdout + result.stderr) == {**expected, "total": sum(expected.values())}
    shell = snakemake(root, "-n", "--printshellcmds", "--configfile", "config/foundation.yaml").stdout
    restorers = dict(re.findall(r"train-restorer --arch (\w+) .*?--steps (\d+) ", shell))
    assert restorers == {"sd": "3000", "svd": "3000", "dd2": "3000", "dd2_mask": "3000"}  # one budget for every backbone
    assert len(re.findall(r"recondreamer pretrain-world-model --arch (sd|svd|dd2) ", shell)) == 3
    assert "recondreamer train-autoencoder " in shell and "recondreamer train-eval-models " in shell
    assert re.search(r"recondreamer make-pairs --run \S+gate_runs/gate-000/street .*--trajectories original shift@3 shift@6", shell)
    assert "recondreamer weights publish " in shell and "--out weights " in shell
    # Every restorer learns from the cycle pairs of every corpus scene, along both lateral drives.
    for arch, pairs in re.findall(r"train-restorer --arch (\w+) .*?--pairs (.*?) --out ", shell):
        assert len(re.findall(r"pairs/cycle/corpus-\d+/shift@[36]", pairs)) == 240, arch
    # Restoration pairs come from corpus reconstructions by all four backbones, never from an evaluation segment.
    assert "make_pairs_segment" not in shell and "train-recon --scene results/foundation/scenes/" not in shell


def test_foundation_seeds_are_checked_at_parse_time(tmp_path):
    root = workflow_copy(tmp_path)
    config = yaml.safe_load((root / "config" / "foundation.yaml").read_text())
    for edit, message in (
        (lambda c: c["foundation"].update(gate_seeds=[10003]), "foundation.gate_seeds [10003] overlap the corpus or evaluation seeds"),
        (lambda c: c["foundation"].update(reserved_seeds=[10005]), "synthetic.corpus seeds overlap the evaluation seeds (segments, foundation.reserved_seeds) [10005]"),
        (lambda c: c["foundation"].update(weights="shipped"), "target 'foundation' trains the foundation models: set foundation.weights to 'train'"),
    ):
        bad = yaml.safe_load(yaml.safe_dump(config))
        edit(bad)
        (root / "bad.yaml").write_text(yaml.safe_dump(bad))
        result = snakemake(root, "-n", "--quiet", "rules", "--configfile", "bad.yaml")
        assert result.returncode != 0 and message in result.stdout + result.stderr, result.stdout + result.stderr


def test_a_missing_weight_set_stops_the_run_at_parse_time(tmp_path):
    root = workflow_copy(tmp_path)
    config = yaml.safe_load((root / "config" / "quick.yaml").read_text())
    config["foundation"] = {"weights": "absent-weights"}
    (root / "set.yaml").write_text(yaml.safe_dump(config))
    result = snakemake(root, "-n", "--quiet", "rules", "--configfile", "set.yaml")
    assert result.returncode != 0
    assert "absent-weights/manifest.json: weight-set manifest not found (the folder does not exist)" in result.stdout + result.stderr


def test_a_jobs_own_parse_checks_the_hashes_and_the_main_parse_also_loads(tmp_path):
    """A job's parse (``--mode remote``: the batch and srun steps of every SLURM job) skips loading
    the models but still refuses an altered file; the main process's parse refuses it too."""
    from recondreamer.foundation.weights import sha256_file, shipped_weights_dir

    root = workflow_copy(tmp_path)
    weights = shutil.copytree(shipped_weights_dir(), tmp_path / "my-weights")
    (root / "set.yaml").write_text(yaml.safe_dump({"foundation": {"weights": str(weights)}}))
    for mode in ([], ["--mode", "remote"]):
        assert snakemake(root, "-n", "--quiet", "rules", "--configfile", "set.yaml", *mode).returncode == 0, mode
    altered = weights / "restorer_dd2_mask.pt"
    data = bytearray(altered.read_bytes())
    data[-1] ^= 0xFF
    altered.write_bytes(bytes(data))
    for mode in ([], ["--mode", "remote"]):
        result = snakemake(root, "-n", "--quiet", "rules", "--configfile", "set.yaml", *mode)
        assert result.returncode != 0, mode
        assert f"{altered}: altered: sha256" in result.stdout + result.stderr, mode
    # Bytes no code can load, listed with their own hash: only the main process, which loads the models, refuses them.
    altered.write_bytes(b"not a checkpoint")
    manifest = json.loads((weights / "manifest.json").read_text())
    manifest["files"][altered.name]["sha256"] = sha256_file(altered)
    (weights / "manifest.json").write_text(json.dumps(manifest))
    main = snakemake(root, "-n", "--quiet", "rules", "--configfile", "set.yaml")
    assert main.returncode != 0 and f"{altered}: an architecture this code cannot load" in main.stdout + main.stderr
    assert snakemake(root, "-n", "--quiet", "rules", "--configfile", "set.yaml", "--mode", "remote").returncode == 0


def test_restorer_timestep_power_pixel_loss_weight_ema_decay_and_depth_reach_every_fine_tuning_and_only_when_set(tmp_path):
    root = workflow_copy(tmp_path)
    config = yaml.safe_load((root / "config" / "quick.yaml").read_text())
    assert "timestep_power" not in config["restorer"]
    quick_shell = snakemake(root, "-n", "--printshellcmds", "--configfile", "config/quick.yaml", "--until", "train_restorer").stdout
    assert "train-restorer" in quick_shell and "--timestep-power" not in quick_shell
    # The default config trains no restorer: it uses the shipped weight set.
    assert "train-restorer" not in snakemake(root, "-n", "--printshellcmds").stdout
    config["restorer"]["timestep_power"] = 50
    (root / "power.yaml").write_text(yaml.safe_dump(config))
    shell = snakemake(root, "-n", "--printshellcmds", "--configfile", "power.yaml", "--until", "train_restorer").stdout
    powers = dict(re.findall(r"train-restorer --arch (\w+) .*?--timestep-power (\S+)", shell))
    assert powers == {"sd": "50", "svd": "50", "dd2": "50", "dd2_mask": "50"}
    assert "--pixel-loss-weight" not in shell  # null: the command's default (no image-space loss)
    assert "--ema-decay" not in shell  # null: the command's default (the last weights)
    assert "--blocks-per-level" not in shell  # null: the world model's depth
    config["restorer"]["pixel_loss_weight"] = 20
    config["restorer"]["ema_decay"] = 0.995
    config["restorer"]["blocks_per_level"] = 2
    (root / "pixel.yaml").write_text(yaml.safe_dump(config))
    shell = snakemake(root, "-n", "--printshellcmds", "--configfile", "pixel.yaml", "--until", "train_restorer").stdout
    weights = dict(re.findall(r"train-restorer --arch (\w+) .*?--pixel-loss-weight (\S+)", shell))
    assert weights == {"sd": "20", "svd": "20", "dd2": "20", "dd2_mask": "20"}
    decays = dict(re.findall(r"train-restorer --arch (\w+) .*?--ema-decay (\S+)", shell))
    assert decays == {"sd": "0.995", "svd": "0.995", "dd2": "0.995", "dd2_mask": "0.995"}
    depths = dict(re.findall(r"train-restorer --arch (\w+) .*?--blocks-per-level (\S+)", shell))
    assert depths == {"sd": "2", "svd": "2", "dd2": "2", "dd2_mask": "2"}
