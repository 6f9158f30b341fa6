"""The tables' notes name every stand-in of the config that produced them, the recipe changes on
in the run's restorers, the training budgets, and table 5's updates and reach per stride."""

import copy

import pytest
import torch
import yaml

from recondreamer.report.notes import pdus_reach, run_notes, state_parameters


def _config(results):
    config = yaml.safe_load(open("config/config.yaml"))
    config["results_dir"] = str(results)
    config["foundation"] = {"weights": "train"}  # the fixture's model files stand where a DAG trains them
    config.setdefault("methods", {})
    return config


def _save(path, state, **payload):
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"state": state, **payload}, path)


@pytest.fixture()
def run(tmp_path):
    models = tmp_path / "models"
    restorer_config = {"diffusion": {"target_space": "residual", "prediction": "v"}, "train": {"steps": 500, "timestep_power": 3.0}, "restore": {"samples": 4, "sample_steps": 10, "strength": 1.0}}
    for arch, size in (("sd", 1000), ("svd", 2000), ("dd2", 3000), ("dd2_mask", 3000)):
        _save(models / f"restorer_{arch}.pt", {"w": torch.zeros(size)}, config=restorer_config, metrics={"total_steps": 500}, training_scenes=[f"s{i}" for i in range(12)])
    for arch in ("sd", "svd", "dd2"):
        _save(models / f"world_model_{arch}.pt", {"w": torch.zeros(10)}, config={"train": {"steps": 500}})
    _save(models / "autoencoder.pt", {"w": torch.zeros(50)}, config={"steps": 2000})
    for name in ("vehicle_detector.pt", "lane_segmenter.pt", "fid_features.pt"):
        path = tmp_path / "eval_models" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        torch.save({"state_dict": {"w": torch.zeros(40000), "bn.running_mean": torch.zeros(9)}, "training": {"run": {"steps": 1000}, "train_scenes": ["a", "b"]}}, path)
    return _config(tmp_path)


def test_every_stand_in_is_named_with_its_size(run):
    notes = run_notes(run)
    text = " ".join(notes[1])
    for name in ("Stable Diffusion: a stand-in, a 0.00 M-parameter latent UNet", "Stable Video Diffusion: a stand-in", "DriveDreamer-2: a stand-in",
                 "DriveDreamer-2+Mask: a stand-in", "NTA-IoU detector: a stand-in for YOLO11x, a CenterNet-style CNN of 0.04 M parameters, trained 1000 steps on 2",
                 "stand-in for TwinLiteNet", "stand-in for InceptionV3", "Stable Diffusion's VAE"):
        assert name in text, name
    assert "fine-tuned 500 steps as DriveRestorer on pairs of 12 scene(s)" in text
    assert "residual target" in text and "v-prediction" in text and "4 noise draws averaged per window" in text and "t^2" in text
    assert "every reconstruction (baseline, DriveDreamer4D, ReconDreamer) 700 iterations" in text
    assert "DriveRestorer fine-tuning steps: sd 500, svd 500, dd2 500, dd2_mask 500" in text
    assert "never novel-view truth" in text
    assert notes[1] == notes[2] == notes[4]


def test_cycle_pairs_and_novel_view_truth_are_named_as_additions_to_the_recipe(run, tmp_path):
    models = tmp_path / "models"
    for arch in ("sd", "svd", "dd2", "dd2_mask"):
        payload = torch.load(models / f"restorer_{arch}.pt")
        payload["pair_kinds"] = ["cycle:shift@3", "cycle:shift@6", "snapshot"]
        torch.save(payload, models / f"restorer_{arch}.pt")
    run["restorer"].update(cycle_corpus_scenes=40, cycle_trajectories=["shift@3", "shift@6"])
    text = " ".join(run_notes(run)[1])
    assert "cycle pairs: reconstructions trained on renders of the lateral drives shift@3, shift@6" in text
    assert "cycles on 40 corpus scene(s) along shift@3, shift@6" in text and "never novel-view truth" in text
    payload["pair_kinds"] = ["snapshot", "truth:shift@6"]  # dd2_mask alone learned from novel-view truth
    torch.save(payload, models / "restorer_dd2_mask.pt")
    text = " ".join(run_notes(run)[1])
    assert "novel-view truth pairs along shift@6 (beyond the paper" in text and "never novel-view truth" not in text


def test_the_default_config_names_the_shipped_weight_set_and_its_budgets(tmp_path):
    from recondreamer.foundation.weights import read_manifest, shipped_weights_dir

    config = yaml.safe_load(open("config/config.yaml"))
    config["results_dir"] = str(tmp_path)
    text = " ".join(run_notes(config)[1])
    code_version = read_manifest(shipped_weights_dir())["code_version"]
    # named by the code version that trained it, not by the install path: two clones write the same tables
    assert f"trained once on the synthetic corpus, from the shipped weight set (trained by code version {code_version[:7]})" in text
    assert str(shipped_weights_dir()) not in text
    steps = read_manifest(shipped_weights_dir())["files"]["restorer_dd2_mask.pt"]["training"]["total_steps"]
    assert f"dd2_mask {steps}" in text


def test_users_own_files_are_named_as_theirs(run, tmp_path):
    config = copy.deepcopy(run)
    config["eval_models"]["detector"] = str(tmp_path / "yolo.pt")
    config["restorer"]["checkpoints"] = {"dd2_mask": str(tmp_path / "models" / "restorer_dd2_mask.pt")}
    text = " ".join(run_notes(config)[1])
    assert f"NTA-IoU detector: the user's file {tmp_path / 'yolo.pt'} in place of YOLO11x" in text
    assert f"DriveDreamer-2+Mask: a stand-in, a 0.00 M-parameter latent UNet (the user's file {tmp_path / 'models' / 'restorer_dd2_mask.pt'})" in text


def test_table5_states_each_strides_updates_and_reach(run):
    note = run_notes(run)[5][-1]
    assert note.startswith("PDUS updates and reach per stride:")
    assert "0.5 m: 4 update(s) at 0.5, 1, 1.5, 2 m, reach 2 m" in note
    assert "1.5 m: 4 update(s) at 1.5, 3, 4.5, 6 m, reach 6 m" in note
    assert "6.0 m: 4 update(s) at 6, 6, 6, 6 m, reach 6 m" in note
    assert pdus_reach(1.0, 700, None, None) == [1.0, 2.0, 3.0, 4.0]


def test_parameter_count_leaves_out_batch_norm_statistics():
    state = {"conv.weight": torch.zeros(3, 4), "bn.running_mean": torch.zeros(4), "bn.running_var": torch.zeros(4), "bn.num_batches_tracked": torch.zeros(())}
    assert state_parameters(state) == 12


def test_reconstructions_on_cuda_are_said_not_to_repeat(run):
    assert not any("atomic" in line for line in run_notes(run)[1])  # CPU reconstructions repeat: no note
    run["recon"]["device"] = "cuda"
    assert any("gsplat's backward pass adds gradients with atomic operations" in line for line in run_notes(run)[1])
