"""Weight sets: publishing with a manifest, verification (missing, altered, wrong-architecture
files), the `weights verify` command, and where runs find their models."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from recondreamer.cli import main
from recondreamer.configs import to_dict
from recondreamer.evaluation import inference
from recondreamer.evaluation.config import (
    DetectorConfig,
    FeatureNetConfig,
    LaneSegmenterConfig,
)
from recondreamer.generative.scoring import flicker
from recondreamer.foundation.weights import (
    MANIFEST,
    WEIGHT_FILES,
    WeightsError,
    publish_weight_set,
    read_manifest,
    sha256_file,
    shipped_weights_dir,
    verify_weight_set,
)
from recondreamer.provenance import record_command
from recondreamer.report.layout import (
    model_path,
    restorer_checkpoint_path,
    weight_set_dir,
)
from recondreamer.generative.autoencoder import Autoencoder
from recondreamer.generative.checkpoint import save_checkpoint
from recondreamer.generative.config import (
    AutoencoderConfig,
    DiffusionConfig,
    TrainConfig,
    UNetConfig,
)
from recondreamer.generative.diffusion import NoiseSchedule
from recondreamer.generative.inference import load_restorer, restore_clip
from recondreamer.generative.models import (
    GenerativeModel,
    autoencoder_payload,
    model_config_dict,
)
from recondreamer.generative.unet import LatentUNet

H, W = 32, 48
STRUCTURE = ("boxes", "lanes", "edges")
GATES = {
    "gate_seeds": [20000],
    "corpus_seeds": [10000, 10003],
    "restorers": {"dd2_mask": {"shift@3": {"clips": 1, "render_psnr": 20.0, "restored_psnr": 22.5, "gain_db": 2.5,
                                           "render_flicker": 6.0, "restored_flicker": 5.0}, "gate_db": 2.0, "passed": True}},
    "autoencoder": {"psnr_db": 31.0, "gate_db": 30.0, "passed": True, "scenes": 1},
    "eval_models": {
        "vehicle_detector": {"ap50": 0.91, "ap50_per_scene": {"gate-000": 0.91}, "gate": 0.9, "passed": True, "scenes": ["gate-000"],
                             "heldout_corpus": {"ap50": 0.88, "ap50_per_scene": {"corpus-003": 0.88}, "scenes": ["corpus-003"]}},
        "lane_segmenter": {"lane_iou": 0.8, "gate": 0.7, "passed": True, "scenes": ["gate-000"], "heldout_corpus": {"lane_iou": 0.82, "scenes": ["corpus-003"]}},
    },
    "recipe": ["residual target"],
}


def tiny_restorer() -> GenerativeModel:
    torch.manual_seed(0)
    config = UNetConfig(
        arch="dd2_mask", channels=(8, 16), attention_levels=(False, True), temporal_levels=(True, True), num_heads=2,
        time_embed_dim=16, structure_channels=len(STRUCTURE), structure_hidden=4, degraded_condition=True,
    )
    unet = LatentUNet(config)
    with torch.no_grad():
        for parameter in unet.parameters():
            parameter.normal_(0.0, 0.1)
    diffusion = DiffusionConfig(sample_steps=2, target_space="residual", residual_scale=0.5)
    return GenerativeModel(
        kind="restorer", arch="dd2_mask", unet=unet.eval(), autoencoder=Autoencoder(AutoencoderConfig(hidden_channels=(8, 8, 8))).eval(),
        schedule=NoiseSchedule(diffusion), unet_config=config, diffusion_config=diffusion,
        train_config=TrainConfig(window=4, crop=(0, 0), batch_size=2), structure_channels=STRUCTURE, frame_size=(H, W),
    )


@pytest.fixture(scope="module")
def trained_files(tmp_path_factory):
    """Small model files as the training commands write them (untrained: verification does not care)."""
    out = tmp_path_factory.mktemp("trained")
    record_command(["train-restorer", "--arch", "dd2_mask", "--steps", "3"])
    restorer = tiny_restorer()
    save_checkpoint(out / "restorer.pt", "restorer", "dd2_mask", model_config_dict(restorer), restorer.unet.state_dict(),
                    autoencoder=autoencoder_payload(restorer.autoencoder), metrics={"steps": 3, "cpu_ms_per_step": 10.0})
    autoencoder = restorer.autoencoder
    save_checkpoint(out / "autoencoder.pt", "autoencoder", "autoencoder", to_dict(autoencoder.config),
                    autoencoder.state_dict(), metrics={"heldout_psnr": 12.0})
    configs = {
        "vehicle_detector": DetectorConfig(input_width=96, input_height=64, widths=(8, 8, 16, 16), neck_width=8),
        "lane_segmenter": LaneSegmenterConfig(input_width=96, input_height=64, widths=(8, 16, 16), blocks=(1, 1)),
        "fid_features": FeatureNetConfig(input_width=96, input_height=64, widths=(8, 8, 16, 16)),
    }
    for kind, config in configs.items():
        inference.save_model(out / f"{kind}.pt", kind, config.build().eval(), {"run": {"steps": 1}})
    return {
        "restorer_dd2_mask.pt": out / "restorer.pt",
        "autoencoder.pt": out / "autoencoder.pt",
        "vehicle_detector.pt": out / "vehicle_detector.pt",
        "lane_segmenter.pt": out / "lane_segmenter.pt",
        "fid_features.pt": out / "fid_features.pt",
    }


@pytest.fixture
def weight_set(tmp_path, trained_files):
    out = tmp_path / "weights"
    publish_weight_set(trained_files, GATES, "quick", out)
    return out


class TestPublish:
    def test_manifest_lists_every_file_with_hash_config_command_budget_and_gates(self, weight_set, trained_files):
        manifest = read_manifest(weight_set)
        assert set(manifest["files"]) == set(trained_files)
        entry = manifest["files"]["restorer_dd2_mask.pt"]
        assert entry["sha256"] == sha256_file(weight_set / "restorer_dd2_mask.pt") == sha256_file(trained_files["restorer_dd2_mask.pt"])
        assert entry["kind"] == "restorer" and entry["arch"] == "dd2_mask"
        assert entry["config"]["unet"]["channels"] == [8, 16]
        assert entry["command"] == "recondreamer train-restorer --arch dd2_mask --steps 3"
        assert entry["training"]["steps"] == 3 and entry["gates"]["passed"] is True
        assert manifest["files"]["vehicle_detector.pt"]["gates"]["ap50"] == 0.91
        assert manifest["corpus"] == {"seeds": [10000, 10003], "preset": "quick"} and manifest["gate_scenes"]["seeds"] == [20000]
        assert manifest["code_version"]
        report = (weight_set / "GATES.md").read_text()
        assert "| dd2_mask | shift@3 | 1 | 20.00 | 22.50 | +2.50 |" in report and "- residual target" in report
        assert "| vehicle detector | AP50, 1 gate scene(s) | 0.910 | 0.9 | yes |" in report
        assert "| vehicle detector (beside the gate) | AP50, held-out corpus scenes | 0.880 | | |" in report
        assert "Detector AP50 per scene: gate-000 0.910, corpus-003 0.880." in report

    def test_republishing_rewrites_only_the_files_that_changed(self, weight_set, trained_files, tmp_path):
        for name in trained_files:
            os.utime(weight_set / name, ns=(1, 1))  # as if published long ago
        changed = tmp_path / "detector.pt"
        torch.save({**torch.load(trained_files["vehicle_detector.pt"], weights_only=False), "training": {"steps": 99}}, changed)
        manifest = publish_weight_set({**trained_files, "vehicle_detector.pt": changed}, GATES, "quick", weight_set)
        assert (weight_set / "vehicle_detector.pt").stat().st_mtime_ns != 1
        assert all((weight_set / name).stat().st_mtime_ns == 1 for name in trained_files if name != "vehicle_detector.pt")
        assert manifest["files"]["vehicle_detector.pt"]["sha256"] == sha256_file(changed)
        verify_weight_set(weight_set)  # raises on any mismatch

    def test_unknown_name_missing_source_or_old_gates_fail_before_writing(self, tmp_path, trained_files):
        with pytest.raises(WeightsError, match="restorer_xyz.pt: not a file of a weight set"):
            publish_weight_set({"restorer_xyz.pt": trained_files["autoencoder.pt"]}, GATES, "quick", tmp_path / "a")
        with pytest.raises(WeightsError, match="nothing.pt: file not found"):
            publish_weight_set({"autoencoder.pt": tmp_path / "nothing.pt"}, GATES, "quick", tmp_path / "b")
        older = {**GATES, "eval_models": {kind: {k: v for k, v in gate.items() if k != "heldout_corpus"} for kind, gate in GATES["eval_models"].items()}}
        with pytest.raises(WeightsError, match=r"lacks eval_models.vehicle_detector.heldout_corpus, eval_models.lane_segmenter.heldout_corpus: .*older foundation-gates"):
            publish_weight_set({"autoencoder.pt": trained_files["autoencoder.pt"]}, older, "quick", tmp_path / "c")
        assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists() and not (tmp_path / "c").exists()


class TestVerify:
    def test_an_intact_set_verifies(self, weight_set):
        assert set(verify_weight_set(weight_set)["files"]) == {p.name for p in weight_set.glob("*.pt")}

    def test_missing_file_is_named(self, weight_set):
        (weight_set / "lane_segmenter.pt").unlink()
        with pytest.raises(WeightsError, match=r"lane_segmenter.pt: missing"):
            verify_weight_set(weight_set)

    def test_altered_file_is_named(self, weight_set):
        with open(weight_set / "restorer_dd2_mask.pt", "ab") as handle:
            handle.write(b"\0")
        with pytest.raises(WeightsError, match=r"restorer_dd2_mask.pt: altered: sha256"):
            verify_weight_set(weight_set)

    def test_file_of_an_architecture_the_code_cannot_load_is_named(self, weight_set, trained_files):
        # A detector file saved under the restorer's name, its manifest hash updated: the hash passes, the load does not.
        shutil.copyfile(trained_files["vehicle_detector.pt"], weight_set / "restorer_dd2_mask.pt")
        manifest = json.loads((weight_set / MANIFEST).read_text())
        manifest["files"]["restorer_dd2_mask.pt"]["sha256"] = sha256_file(weight_set / "restorer_dd2_mask.pt")
        (weight_set / MANIFEST).write_text(json.dumps(manifest))
        with pytest.raises(WeightsError, match=r"restorer_dd2_mask.pt: an architecture this code cannot load as restorer dd2_mask"):
            verify_weight_set(weight_set)

    def test_state_dict_of_other_shapes_is_named(self, weight_set):
        payload = torch.load(weight_set / "autoencoder.pt", weights_only=False)
        first = next(iter(payload["state"]))
        payload["state"][first] = torch.zeros(3)
        torch.save(payload, weight_set / "autoencoder.pt")
        manifest = json.loads((weight_set / MANIFEST).read_text())
        manifest["files"]["autoencoder.pt"]["sha256"] = sha256_file(weight_set / "autoencoder.pt")
        (weight_set / MANIFEST).write_text(json.dumps(manifest))
        with pytest.raises(WeightsError, match=r"autoencoder.pt: an architecture this code cannot load"):
            verify_weight_set(weight_set)

    def test_only_the_named_files_are_checked(self, weight_set):
        (weight_set / "lane_segmenter.pt").unlink()
        verify_weight_set(weight_set, ["restorer_dd2_mask.pt"])
        with pytest.raises(WeightsError, match=r"restorer_sd.pt: not listed"):
            verify_weight_set(weight_set, ["restorer_sd.pt"])

    def test_missing_or_foreign_manifest(self, tmp_path, weight_set):
        with pytest.raises(WeightsError, match=r"manifest.json: weight-set manifest not found"):
            verify_weight_set(tmp_path)
        (weight_set / MANIFEST).write_text(json.dumps({"format": "other"}))
        with pytest.raises(WeightsError, match=r"not a recondreamer weight-set manifest"):
            verify_weight_set(weight_set)

    def test_command_exit_codes_and_messages(self, weight_set, capsys):
        assert main(["weights", "verify", str(weight_set)]) == 0
        assert "5 files verified" in capsys.readouterr().out
        (weight_set / "fid_features.pt").unlink()
        assert main(["weights", "verify", str(weight_set)]) == 1
        assert "fid_features.pt: missing" in capsys.readouterr().err


class TestPublishedRestorer:
    def test_loads_and_restores_a_tiny_clip_deterministically(self, weight_set):
        verify_weight_set(weight_set, ["restorer_dd2_mask.pt"])
        restorer = load_restorer(weight_set / "restorer_dd2_mask.pt")
        rng = np.random.default_rng(0)
        frames = rng.integers(0, 256, size=(5, H, W, 3), dtype=np.uint8)
        structure = rng.integers(0, 256, size=(5, len(STRUCTURE), H, W), dtype=np.uint8)
        first = restore_clip(restorer, frames, structure, window=4, overlap=1)
        assert first.shape == frames.shape and first.dtype == np.uint8
        assert np.array_equal(first, restore_clip(load_restorer(weight_set / "restorer_dd2_mask.pt"), frames, structure, window=4, overlap=1))


class TestShippedSet:
    """The weight set in the repository, as the default config uses it."""

    def test_every_file_verifies_and_loads(self):
        manifest = verify_weight_set(shipped_weights_dir())
        assert set(manifest["files"]) == {spec.name for spec in WEIGHT_FILES}
        total = sum(p.stat().st_size for p in shipped_weights_dir().iterdir() if p.is_file())
        assert total <= 64 * 2**20

    def test_trained_on_no_evaluation_seed_of_the_default_configs(self):
        manifest = read_manifest(shipped_weights_dir())
        first, last = manifest["corpus"]["seeds"]
        seen = set(range(first, last + 1)) | set(manifest["gate_scenes"]["seeds"])
        repo = Path(__file__).resolve().parents[1]
        default = yaml.safe_load((repo / "config" / "config.yaml").read_text())
        foundation = yaml.safe_load((repo / "config" / "foundation.yaml").read_text())
        evaluation = set(default["synthetic"]["segments"].values()) | set(foundation["foundation"]["reserved_seeds"])
        assert default["foundation"]["weights"] == "shipped"
        assert not seen & evaluation

    def test_restorer_restores_a_clip_deterministically(self):
        restorer = load_restorer(shipped_weights_dir() / "restorer_dd2_mask.pt")
        height, width = restorer.frame_size
        rng = np.random.default_rng(0)
        frames = rng.integers(0, 256, size=(5, height, width, 3), dtype=np.uint8)
        structure = rng.integers(0, 256, size=(5, len(restorer.structure_channels), height, width), dtype=np.uint8)
        first = restore_clip(restorer, frames, structure, window=4, overlap=1)
        assert first.shape == frames.shape and first.dtype == np.uint8 and not np.array_equal(first, frames)
        again = restore_clip(load_restorer(shipped_weights_dir() / "restorer_dd2_mask.pt"), frames, structure, window=4, overlap=1)
        assert np.array_equal(first, again)


class TestModelPaths:
    def config(self, weights, **restorer):
        return {"results_dir": "res", "foundation": {"weights": weights}, "restorer": {"checkpoints": {}, "refiner_steps": 0, **restorer}}

    def test_sources(self, tmp_path):
        assert weight_set_dir(self.config("train")) is None
        assert weight_set_dir(self.config("shipped")) == shipped_weights_dir()
        assert weight_set_dir(self.config(str(tmp_path))) == tmp_path
        assert model_path(self.config("train"), "restorer", "sd") == "res/models/restorer_sd.pt"
        assert model_path(self.config("train"), "fid_features") == "res/eval_models/fid_features.pt"
        assert model_path(self.config(str(tmp_path)), "world_model", "dd2") == str(tmp_path / "world_model_dd2.pt")

    def test_restorer_precedence(self, tmp_path):
        assert restorer_checkpoint_path(self.config(str(tmp_path), checkpoints={"sd": "own.pt"}), "sd") == "own.pt"
        assert restorer_checkpoint_path(self.config("train", refiner_steps=5), "sd") == "res/models/restorer_sd_refined.pt"
        assert restorer_checkpoint_path(self.config(str(tmp_path)), "dd2") == str(tmp_path / "restorer_dd2.pt")

    def test_shipped_set_is_package_data(self):
        assert (shipped_weights_dir() / "__init__.py").is_file()


class TestFlicker:
    def test_zero_for_the_truth_and_positive_for_independent_noise(self):
        rng = np.random.default_rng(0)
        truth = rng.integers(0, 256, size=(4, 8, 8, 3), dtype=np.uint8)
        assert flicker(truth, truth) == 0.0
        noisy = np.clip(truth.astype(int) + rng.integers(-20, 21, size=truth.shape), 0, 255).astype(np.uint8)
        assert flicker(noisy, truth) > 5.0
        # A constant offset does not flicker.
        assert flicker(np.clip(truth.astype(int) // 2 + 10, 0, 255).astype(np.uint8), truth // 2) == 0.0


class TestPackaging:
    def test_a_regular_install_carries_and_finds_the_shipped_set(self, tmp_path):
        """A wheel holds every file of recondreamer/weights/, and the installed package finds them."""
        import subprocess
        import sys
        import zipfile

        repo = Path(__file__).resolve().parents[1]
        build = subprocess.run([sys.executable, "-m", "pip", "wheel", str(repo), "--no-deps", "--no-build-isolation", "-q", "-w", str(tmp_path / "wheel")],
                               check=False, capture_output=True, text=True, timeout=300)
        assert build.returncode == 0, build.stderr
        wheel = next((tmp_path / "wheel").glob("recondreamer-*.whl"))
        shipped = {p.relative_to(repo).as_posix() for p in (repo / "recondreamer" / "weights").iterdir() if p.is_file() and p.suffix != ".pyc"}
        assert shipped and shipped <= set(zipfile.ZipFile(wheel).namelist())
        install = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(tmp_path / "site"), str(wheel)],
                                 check=False, capture_output=True, text=True, timeout=300)
        assert install.returncode == 0, install.stderr
        found = subprocess.run([sys.executable, "-c", "from recondreamer.foundation.weights import shipped_weights_dir; print(shipped_weights_dir())"],
                               check=False, capture_output=True, text=True, cwd=tmp_path, env={"PYTHONPATH": str(tmp_path / "site"), "PATH": "/usr/bin:/bin"})
        assert found.returncode == 0, found.stderr
        folder = Path(found.stdout.strip())
        assert folder == tmp_path / "site" / "recondreamer" / "weights"
        assert {p.name for p in folder.iterdir() if p.is_file()} >= {Path(name).name for name in shipped}
