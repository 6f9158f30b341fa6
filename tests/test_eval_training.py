"""train-eval-models on a tiny quick-preset corpus (a few steps: the gates are the benchmark's job)."""

import json

import numpy as np
import pytest
import torch

from recondreamer.cli import main
from recondreamer.evaluation import inference
from recondreamer.evaluation.corpus import load_corpus
from recondreamer.evaluation.training import TrainSettings, train_model


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    from recondreamer.scene import write_scene
    from recondreamer.sources.synthetic import generate_segment

    root = tmp_path_factory.mktemp("corpus")
    for seed in (11, 12):
        write_scene(root / f"c{seed}", generate_segment(seed, "quick"))
    return root


def test_corpus_split_holds_out_whole_scenes(corpus):
    split = load_corpus(corpus, frame_stride=3, holdout_scenes=1)
    assert split.train_scenes and split.heldout_scenes and not set(split.train_scenes) & set(split.heldout_scenes)
    assert {s.scene_id for s in split.heldout} == set(split.heldout_scenes)
    assert {s.trajectory for s in split.train} == {"original", "shift@3", "shift@6", "lane_change"}
    sample = split.train[0]
    assert sample.lane_mask.shape == sample.image.shape[:2] and sample.lane_mask.any()
    # Every NTA-IoU ground-truth box lies fully inside the image.
    boxes = np.concatenate([s.eval_boxes for s in split.train])
    assert len(boxes) and (boxes[:, :2] >= 0).all() and (boxes[:, 2] <= split.width).all() and (boxes[:, 3] <= split.height).all()


@pytest.mark.slow
def test_train_eval_models_command_writes_models_and_gates(corpus, tmp_path):
    out = tmp_path / "models"
    args = ["train-eval-models", "--corpus", str(corpus), "--out", str(out), "--holdout-scenes", "1", "--frame-stride", "6",
            "--detector-steps", "2", "--detector-upsample", "2", "--lane-steps", "2", "--feature-steps", "2", "--batch-size", "2"]
    assert main(args) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert set(metrics["gates"]) == {"vehicle_detector", "lane_segmenter", "fid_features"}
    assert 0.0 <= metrics["gates"]["vehicle_detector"]["ap50"] <= 1.0 and metrics["gates"]["vehicle_detector"]["gate"] == 0.9
    assert 0.0 <= metrics["gates"]["lane_segmenter"]["lane_iou"] <= 1.0 and metrics["gates"]["lane_segmenter"]["gate"] == 0.7
    for kind, name in inference.MODEL_FILES.items():
        loaded = inference.load_model(out / name, kind)
        assert loaded.sha256 == metrics["models"][kind]["sha256"]
        assert (loaded.module.config.input_width, loaded.module.config.input_height) == (96, 64)
    assert inference.load_model(out / "vehicle_detector.pt", "vehicle_detector").module.config.upsample == 2
    assert not list(out.glob("*.resume.pt"))  # resume files go once their model is written
    # The foundation gates score the models on gate scenes the same way: given the held-out
    # scene as the gate scene, they reproduce train-eval-models' numbers.
    from recondreamer.foundation.gates import eval_model_gates

    on_scene = eval_model_gates(out / "metrics.json", out / "vehicle_detector.pt", out / "lane_segmenter.pt", [corpus / "c12"])
    assert on_scene["vehicle_detector"]["scenes"] == metrics["corpus"]["heldout_scenes"]
    assert on_scene["vehicle_detector"]["ap50"] == on_scene["vehicle_detector"]["heldout_corpus"]["ap50"] == metrics["gates"]["vehicle_detector"]["ap50"]
    assert on_scene["lane_segmenter"]["lane_iou"] == metrics["gates"]["lane_segmenter"]["lane_iou"]
    for bad in (["--batch-size", "0"], ["--detector-upsample", "0"]):
        assert main(["train-eval-models", "--corpus", str(corpus), "--out", str(tmp_path / "x"), *bad]) == 1


def test_training_resumes_from_its_checkpoint(corpus, tmp_path):
    from recondreamer.evaluation.config import FeatureNetConfig
    from recondreamer.evaluation.training import feature_loss
    from recondreamer.training_loop import resume_path

    samples = load_corpus(corpus, frame_stride=6, holdout_scenes=1).train
    settings = TrainSettings(steps=4, batch_size=2, checkpoint_every=2, log_every=1)
    calls = []

    def failing_loss(model, batch):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt  # stands in for a kill during step 3
        return feature_loss(model, batch)

    config = FeatureNetConfig(input_width=96, input_height=64, widths=(8, 8, 16, 16))
    torch.manual_seed(0)
    with pytest.raises(KeyboardInterrupt):
        train_model("features", config.build(), failing_loss, samples, settings, tmp_path / "model.pt", degrade=False)
    assert resume_path(tmp_path / "model.pt").is_file()
    calls.clear()
    resumed = config.build()
    train_model("features", resumed, lambda m, b: (calls.append(1), feature_loss(m, b))[1], samples, settings, tmp_path / "model.pt", degrade=False)
    assert len(calls) == 2  # steps 3 and 4 only
    # The same run without interruption ends with the same weights (batches are seeded per step).
    torch.manual_seed(0)
    straight = config.build()
    train_model("features", straight, feature_loss, samples, settings, tmp_path / "other.pt", degrade=False)
    for a, b in zip(resumed.state_dict().values(), straight.state_dict().values()):
        assert torch.allclose(a.float(), b.float(), atol=1e-5)


def test_batch_crops_and_flips_boxes_and_masks_alike():
    from recondreamer.evaluation.corpus import FrameSample
    from recondreamer.evaluation.training import make_batch

    height, width = 40, 64
    mask = np.zeros((height, width), bool)
    mask[10:25, 30:50] = True  # the box below, as pixels
    box = np.array([[30.0, 10.0, 50.0, 25.0]])
    sample = FrameSample("s", "original", 0, np.zeros((height, width, 3), np.uint8), box, box, np.zeros((0, 4)), mask, None, None, None)
    for seed in range(6):
        batch = make_batch([sample], np.random.default_rng(seed), degrade=False, crop=(32, 32))
        assert batch.images.shape == (1, 3, 32, 32)
        cropped = batch.masks([mask])[0].numpy().astype(bool)
        boxes = batch.boxes(0, box)
        if not cropped.any():
            assert len(boxes) == 0
            continue
        ys, xs = np.nonzero(cropped)
        assert boxes[0] == pytest.approx([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1])


def test_lane_target_is_the_visible_marking_and_the_map_mask_is_kept_for_the_gate(corpus):
    from recondreamer.evaluation.lanes import lane_mask
    from recondreamer.scene import load_scene

    split = load_corpus(corpus, frame_stride=3, holdout_scenes=1)
    sample = split.train[0]
    scene = next(scene for scene in map(load_scene, sorted(corpus.iterdir())) if scene.scene_id == sample.scene_id)
    marking = scene.semantic_classes.index("lane_marking")
    assert np.array_equal(sample.lane_mask, sample.semantics == marking)
    cams = scene.trajectory(sample.trajectory)
    assert np.array_equal(sample.map_lane_mask, lane_mask(scene.map_polylines, scene.K, cams[sample.t], scene.width, scene.height))
    assert not np.array_equal(sample.lane_mask, sample.map_lane_mask)


def test_fid_features_pool_three_scales():
    from recondreamer.evaluation.config import FeatureNetConfig

    config = FeatureNetConfig(input_width=32, input_height=32, widths=(4, 6, 8, 10))
    model = config.build().eval()
    images = torch.rand(3, 3, 32, 32) * 255
    features = model.features(images)
    assert features.shape == (3, config.feature_dim) == (3, 6 + 8 + 10)
    x4, x8, x16 = model.encode(images)
    assert torch.allclose(features, torch.cat([x4.mean((2, 3)), x8.mean((2, 3)), x16.mean((2, 3))], dim=1))
