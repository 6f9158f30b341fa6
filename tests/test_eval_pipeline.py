"""Evaluation on a tiny synthetic scene: geometric ground truth, oracle models, the evaluate command, bad inputs."""

import json

import numpy as np
import pytest
import torch
from PIL import Image

from recondreamer.cli import main
from recondreamer.errors import CheckpointError
from recondreamer.evaluation import frechet, gates, inference, lanes, nta_iou
from recondreamer.evaluation.config import DetectorConfig, FeatureNetConfig, LaneSegmenterConfig
from recondreamer.frames_io import FrameError, read_frame_folder
from recondreamer.evaluation.training import detector_targets
from recondreamer.scene.structure import project_boxes_2d
from recondreamer.scene.types import Box


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    from recondreamer.scene import write_scene
    from recondreamer.sources.synthetic import generate_segment

    path = tmp_path_factory.mktemp("eval") / "scene"
    write_scene(path, generate_segment(3, "quick"))
    return path


@pytest.fixture(scope="module")
def scene(scene_dir):
    from recondreamer.scene import load_scene

    return load_scene(scene_dir)


@pytest.fixture(scope="module")
def tiny_models(tmp_path_factory):
    """Untrained small networks saved as model files (the metric code does not care how good they are)."""
    torch.manual_seed(0)
    out = tmp_path_factory.mktemp("models")
    configs = {
        "vehicle_detector": DetectorConfig(input_width=96, input_height=64, widths=(8, 8, 16, 16), neck_width=8),
        "lane_segmenter": LaneSegmenterConfig(input_width=96, input_height=64, widths=(8, 16, 16), blocks=(1, 1)),
        "fid_features": FeatureNetConfig(input_width=96, input_height=64, widths=(8, 8, 16, 16)),
    }
    for kind, config in configs.items():
        inference.save_model(out / inference.MODEL_FILES[kind], kind, config.build().eval(), {"run": "untrained test model"})
    return out


def _gt_boxes(scene, trajectory):
    cams = scene.trajectory(trajectory)
    return [nta_iou.ground_truth_boxes_2d(scene.boxes(t), scene.K, cams[t], scene.width, scene.height) for t in range(scene.num_frames)]


def _write_frames(directory, frames):
    directory.mkdir(parents=True, exist_ok=True)
    for t, frame in enumerate(frames):
        Image.fromarray(frame).save(directory / f"{t:03d}.png")
    return directory


# ---------------------------------------------------------------- NTA-IoU ground truth


def test_ground_truth_filter_on_hand_made_boxes():
    cam_to_world = np.array([[0, 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 1.5], [0, 0, 0, 1]], float)  # looks along +x
    K = np.array([[100.0, 0, 120], [0, 100.0, 80], [0, 0, 1]])

    def box(x, y, label="vehicle", points=50):
        pose = np.eye(4)
        pose[:3, 3] = [x, y, 0.75]
        return Box(f"{x},{y},{label}", label, np.array([4.0, 2.0, 1.5]), pose, points)

    kept = nta_iou.ground_truth_boxes_2d(
        [box(20, 0), box(20, 0, points=9), box(20, 0, "pedestrian"), box(-20, 0), box(20, 30), box(5, -4)], K, cam_to_world, 240, 160
    )
    assert kept.shape == (1, 4)  # only the first: few points / pedestrian / behind / outside / cut by the border
    # Independent check of the first box: corners at x in [18, 22], y in [-1, 1], z in [0, 1.5].
    u = [120 + 100 * (-y) / x for x in (18, 22) for y in (-1, 1)]
    v = [80 + 100 * (1.5 - z) / x for x in (18, 22) for z in (0, 1.5)]
    assert kept[0] == pytest.approx([min(u), min(v), max(u), max(v)])


def test_nta_iou_of_oracle_detections_is_one_and_drops_for_unshifted_cameras(scene):
    truth = _gt_boxes(scene, "shift@3")
    assert sum(len(b) for b in truth) > 0
    oracle = nta_iou.nta_iou(truth, truth, scene.width, scene.height)
    assert oracle["nta_iou"] == pytest.approx(1.0)
    # A "render" that did not move the camera puts every vehicle where the original camera saw it.
    stale = []
    for t in range(scene.num_frames):
        vehicles = [b for b in scene.boxes(t) if b.label == "vehicle"]
        seen = project_boxes_2d(vehicles, scene.K, scene.cam_to_world[t], scene.width, scene.height)
        stale.append(np.array([b.xyxy for b in seen if b.in_front], float).reshape(-1, 4))
    assert nta_iou.nta_iou(truth, stale, scene.width, scene.height)["nta_iou"] < 0.5
    # Slightly jittered detections keep a high but lower score.
    jitter = [b + 1.0 for b in truth]
    assert 0.5 < nta_iou.nta_iou(truth, jitter, scene.width, scene.height)["nta_iou"] < 1.0


def test_ntl_iou_of_the_true_lane_mask_is_one_and_drops_for_the_wrong_camera(scene):
    novel = scene.trajectory("shift@3")
    truth = [lanes.lane_mask(scene.map_polylines, scene.K, novel[t], scene.width, scene.height) for t in range(scene.num_frames)]
    assert all(m.any() for m in truth)
    assert lanes.ntl_iou(truth, truth)["lane_iou"] == 1.0
    stale = [lanes.lane_mask(scene.map_polylines, scene.K, scene.cam_to_world[t], scene.width, scene.height) for t in range(scene.num_frames)]
    result = lanes.ntl_iou(stale, truth)
    assert result["lane_iou"] < 0.5 and result["ntl_iou"] < 0.8


# ---------------------------------------------------------------- models, targets, gates


@pytest.mark.parametrize("upsample", [1, 2])
def test_detector_targets_decode_back_to_the_boxes(upsample):
    config = DetectorConfig(input_width=96, input_height=64, widths=(8, 8, 16, 16), neck_width=8, upsample=upsample)
    model = config.build().eval()
    boxes = np.array([[10.0, 12.0, 30.0, 28.0], [50.0, 20.0, 90.0, 50.0]])
    heat, size, offset, _ = detector_targets([boxes], 16 * upsample, 24 * upsample, model.stride)
    logits = torch.logit(heat.clamp(1e-4, 1 - 1e-4))[:, None]
    decoded, scores = model.decode({"heatmap_logits": logits, "log_size": size, "offset": offset}, 0.5)[0]
    order = decoded[:, 0].argsort()
    assert decoded[order].numpy() == pytest.approx(boxes, abs=1e-3)
    assert len(scores) == 2


def test_model_output_shapes():
    images = torch.rand(2, 3, 64, 96) * 255
    det = DetectorConfig(input_width=96, input_height=64).build()(images)
    assert det["heatmap_logits"].shape == (2, 1, 16, 24) and det["log_size"].shape == (2, 2, 16, 24)
    seg = LaneSegmenterConfig(input_width=96, input_height=64).build()(images)
    assert seg["lane_logits"].shape == (2, 2, 64, 96) and seg["area_logits"].shape == (2, 2, 64, 96)
    fid = FeatureNetConfig(input_width=96, input_height=64).build()
    assert fid(images).shape == (2, 9, 64, 96) and fid.features(images).shape == (2, 48 + 96 + 128)


def test_upsampling_detector_has_a_finer_heat_map():
    images = torch.rand(1, 3, 64, 96) * 255
    model = DetectorConfig(input_width=96, input_height=64, upsample=2).build()
    assert model.stride == 2 and model(images)["heatmap_logits"].shape == (1, 1, 32, 48)


def test_a_model_file_of_another_code_version_is_refused_naming_the_file(tmp_path):
    path = tmp_path / "vehicle_detector.pt"
    inference.save_model(path, "vehicle_detector", DetectorConfig(input_width=96, input_height=64).build(), training={})
    assert inference.load_model(path, "vehicle_detector").module.config.upsample == 1
    payload = torch.load(path, weights_only=True)
    del payload["config"]["upsample"]  # a file written before the field existed
    torch.save(payload, path)
    with pytest.raises(CheckpointError, match=r"vehicle_detector.pt: DetectorConfig: missing field\(s\) \['upsample'\]"):
        inference.load_model(path, "vehicle_detector")


def test_average_precision_with_ignored_vehicles():
    gt = [np.array([[0, 0, 10, 10]], float)]
    ignore = [np.array([[50, 50, 60, 60]], float)]
    perfect = [(np.array([[0, 0, 10, 10], [50, 50, 60, 60]], float), np.array([0.9, 0.8]))]
    assert gates.average_precision_50(perfect, gt, ignore)["ap50"] == pytest.approx(1.0)
    # A higher-scored false positive halves precision at full recall: AP = 0.5.
    with_fp = [(np.array([[0, 0, 10, 10], [100, 100, 110, 110]], float), np.array([0.5, 0.9]))]
    assert gates.average_precision_50(with_fp, gt, ignore)["ap50"] == pytest.approx(0.5)
    assert gates.average_precision_50([(np.zeros((0, 4)), np.zeros(0))], gt, ignore)["ap50"] == 0.0


def test_detector_gate_reports_ap50_per_scene():
    gt = [np.array([[0, 0, 10, 10]], float)] * 2
    ignore = [np.zeros((0, 4))] * 2
    found = (np.array([[0, 0, 10, 10]], float), np.array([0.9]))
    missed = (np.array([[100, 100, 110, 110]], float), np.array([0.8]))
    result = gates.detector_gate([found, missed], gt, ignore, 200, 200, 0.5, scene_ids=["scene-a", "scene-b"])
    assert result["ap50_per_scene"] == {"scene-a": pytest.approx(1.0), "scene-b": 0.0}
    assert result["ap50"] == pytest.approx(0.5)  # pooled: half the vehicles found, at precision 1
    assert "ap50_per_scene" not in gates.detector_gate([found, missed], gt, ignore, 200, 200, 0.5)
    with pytest.raises(ValueError, match="scene_ids must name every frame"):
        gates.detector_gate([found, missed], gt, ignore, 200, 200, 0.5, scene_ids=["scene-a"])


# ---------------------------------------------------------------- evaluate command and bad inputs


def test_evaluate_command_writes_every_metric(scene, scene_dir, tiny_models, tmp_path):
    truth = np.stack([scene.novel_image("shift@3", t) for t in range(scene.num_frames)])
    original = np.stack([scene.image(t) for t in range(scene.num_frames)])
    rng = np.random.default_rng(0)
    noisy = lambda images, s: np.clip(images + rng.normal(0, s, images.shape), 0, 255).astype(np.uint8)  # noqa: E731
    dirs = {
        "shift@3": _write_frames(tmp_path / "truth", truth),
        "original": _write_frames(tmp_path / "original", original),
        "shift@6": _write_frames(tmp_path / "noisy6", noisy(np.stack([scene.novel_image("shift@6", t) for t in range(scene.num_frames)]), 40)),
    }
    out = tmp_path / "metrics.json"
    args = ["evaluate", "--scene", str(scene_dir), "--models", str(tiny_models), "--out", str(out)]
    for name, directory in dirs.items():
        args += ["--trajectory", name, "--renders", str(directory)]
    assert main(args) == 0
    doc = json.loads(out.read_text())
    per = doc["trajectories"]
    assert per["original"]["fid"]["fid"] == pytest.approx(0.0, abs=1e-6)  # FID(X, X) = 0
    assert per["shift@3"]["truth"]["ssim"]["mean"] == pytest.approx(1.0)
    assert per["shift@3"]["truth"]["psnr"]["num_identical_frames"] == scene.num_frames
    assert per["shift@6"]["truth"]["psnr"]["mean"] < 30 and per["shift@6"]["truth"]["psnr_lanes"]["num_frames"] > 0
    for name in dirs:
        assert set(per[name]) >= {"nta_iou", "ntl_iou", "fid", "kid", "truth"}
    assert per["original"]["kid"]["kid"] < per["shift@6"]["kid"]["kid"]
    settings = doc["settings"]
    assert len(settings["models"]["vehicle_detector"]["sha256"]) == 64
    assert settings["nta_iou"]["match_distance_px"] == pytest.approx(2.0)  # 96x64 is 1/5 of 480x320
    assert "not pytorch-fid's InceptionV3" in settings["fid_feature_network"]
    assert doc["fid_pooled"]["num_samples"][0] == 3 * scene.num_frames
    pooled = tmp_path / "pooled.json"
    features = dict(np.load(out.with_suffix(".features.npz")))
    assert main(["fid-pool", str(out.with_suffix(".features.npz")), "--out", str(pooled), "--trajectory", "shift@6"]) == 0
    result = json.loads(pooled.read_text())
    expected = frechet.pooled_fid_from_features(features["render:shift@6"], features["reference"])
    assert result["fid"] == pytest.approx(expected["fid"]) and result["fid_dim"] == expected["fid_dim"]
    assert result["kid"] == pytest.approx(frechet.kid_from_features(features["render:shift@6"], features["reference"])["kid"])
    assert result["num_samples"] == [scene.num_frames, scene.num_frames] and result["trajectory"] == "shift@6"
    assert main(["fid-pool", str(out.with_suffix(".features.npz")), "--out", str(pooled)]) == 0
    assert json.loads(pooled.read_text())["num_samples"] == [3 * scene.num_frames, scene.num_frames]


def test_evaluate_with_run_renders_then_scores_like_render_and_evaluate(scene, scene_dir, tiny_models, tmp_path):
    """--run renders in the same process: frames as 'render' writes them, metrics as scoring those frames."""
    from recondreamer.recon import make_config, train_scene

    config = make_config("street", "quick", iterations=4, backend="cpu")
    config.snapshot_steps = ()
    config.init.max_lidar_points = 300
    run = tmp_path / "run"
    train_scene(scene, config, run)
    trajectories = ("shift@3", "lane_change")
    separate, together = tmp_path / "separate", tmp_path / "together"
    for name in trajectories:
        assert main(["render", "--run", str(run), "--scene", str(scene_dir), "--trajectory", name, "--out", str(separate / name)]) == 0
    common = ["evaluate", "--scene", str(scene_dir), "--models", str(tiny_models)]

    def pairs(root):
        return [arg for name in trajectories for arg in ("--trajectory", name, "--renders", str(root / name))]

    assert main([*common, *pairs(separate), "--out", str(tmp_path / "separate.json")]) == 0
    assert main([*common, "--run", str(run), "--device", "cpu", "--threads", "1", *pairs(together), "--out", str(tmp_path / "together.json")]) == 0
    for name in trajectories:
        assert sorted(p.name for p in (together / name).iterdir()) == sorted(p.name for p in (separate / name).iterdir())
        for t in range(scene.num_frames):
            assert np.array_equal(np.asarray(Image.open(together / name / f"{t:03d}.png")), np.asarray(Image.open(separate / name / f"{t:03d}.png")))
    metrics = [json.loads((tmp_path / f"{which}.json").read_text())["trajectories"] for which in ("separate", "together")]
    assert metrics[0] == metrics[1]
    # A bad trajectory is refused before any frame is rendered.
    assert main([*common, "--run", str(run), "--trajectory", "shift@3", "--renders", str(tmp_path / "bad" / "a"),
                 "--trajectory", "sideways", "--renders", str(tmp_path / "bad" / "b"), "--out", str(tmp_path / "bad.json")]) == 1
    assert not (tmp_path / "bad").exists() and not (tmp_path / "bad.json").exists()
    if not torch.cuda.is_available():  # a device that is not there is named before any work
        assert main([*common, "--run", str(run), "--device", "cuda", *pairs(tmp_path / "cuda"), "--out", str(tmp_path / "cuda.json")]) == 1
        assert not (tmp_path / "cuda").exists()


def test_fid_through_the_feature_network_grows_with_noise(scene, tiny_models):
    model = inference.load_model(tiny_models / "fid_features.pt", "fid_features").module
    from recondreamer.evaluation.frechet import fid_from_features

    original = np.stack([scene.image(t) for t in range(scene.num_frames)])
    reference = inference.fid_features(model, original)
    rng = np.random.default_rng(1)
    values = [
        fid_from_features(inference.fid_features(model, np.clip(original + rng.normal(0, s, original.shape), 0, 255).astype(np.uint8)), reference)["fid"]
        for s in (5, 20, 60)
    ]
    assert values[0] < values[1] < values[2]


def test_bad_renders_give_errors_naming_the_file(scene, scene_dir, tiny_models, tmp_path, capsys):
    frames = np.stack([scene.image(t) for t in range(scene.num_frames)])
    missing = _write_frames(tmp_path / "missing", frames)
    (missing / "004.png").unlink()
    with pytest.raises(FrameError, match="004.png"):
        read_frame_folder(missing, scene.num_frames, (scene.width, scene.height))
    wrong = _write_frames(tmp_path / "wrong", frames)
    Image.fromarray(frames[2][:32]).save(wrong / "002.png")
    with pytest.raises(FrameError, match=r"002.png: frame is 96x32"):
        read_frame_folder(wrong, scene.num_frames, (scene.width, scene.height))
    code = main(["evaluate", "--scene", str(scene_dir), "--renders", str(missing), "--trajectory", "shift@3", "--models", str(tiny_models), "--out", str(tmp_path / "m.json")])
    assert code == 1 and "004.png" in capsys.readouterr().err
    assert not (tmp_path / "m.json").exists()
    with pytest.raises(CheckpointError, match="holds a 'lane_segmenter' model"):
        inference.load_model(tiny_models / "lane_segmenter.pt", "vehicle_detector")
    with pytest.raises(CheckpointError, match="not found"):
        inference.load_model(tmp_path / "none.pt", "vehicle_detector")


def test_judge_command_prefers_the_true_view(scene, scene_dir, tmp_path):
    truth = np.stack([scene.novel_image("shift@3", t) for t in range(scene.num_frames)])
    blurred = np.stack([np.asarray(Image.fromarray(f).resize((24, 16)).resize((96, 64))) for f in truth])
    good, bad = _write_frames(tmp_path / "good", truth), _write_frames(tmp_path / "bad", blurred)
    out = tmp_path / "judge.json"
    clip = ["--clip", str(scene_dir), "shift@3", f"good={good}", f"bad={bad}"]
    assert main(["judge", *clip, *clip[:3], f"bad={bad}", f"good={good}", "--out", str(out)]) == 0
    pairs = {(p["method"], p["versus"]): p for p in json.loads(out.read_text())["pairs"]}
    assert pairs[("good", "bad")]["per_trajectory"]["shift@3"] == {"wins": 2, "losses": 0, "ties": 0, "comparisons": 2, "win_rate": 1.0}
    assert main(["judge", "--clip", str(scene_dir), "shift@9", f"good={good}", f"bad={bad}", "--out", str(out)]) == 1
