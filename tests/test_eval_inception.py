"""pytorch-fid's FID InceptionV3: state_dict layout of the public weights file, the pytorch-fid
pooling patches, and FID through a user-supplied weights file in the evaluate command.

The full network costs about 6 GFLOP per 299x299 image, so every test runs at most two images.
"""

import hashlib
import json

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from PIL import Image

from recondreamer.cli import main
from recondreamer.errors import CheckpointError, RecondreamerError
from recondreamer.evaluation import inference
from recondreamer.evaluation.evaluate import FID_FEATURES_NOTE, fid_feature_network, load_eval_models, pooled_fid, write_features
from recondreamer.evaluation.inception import FIDInceptionV3, InceptionA, InceptionC, InceptionE
from recondreamer.evaluation.config import DetectorConfig, FeatureNetConfig, LaneSegmenterConfig

# Branches (name, c_out, kernel (h, w)) of torchvision's Inception3 blocks, as pytorch-fid's
# weights file lays them out; "in" is the block's input channel count.
STEM = [("Conv2d_1a_3x3", 3, 32, (3, 3)), ("Conv2d_2a_3x3", 32, 32, (3, 3)), ("Conv2d_2b_3x3", 32, 64, (3, 3)), ("Conv2d_3b_1x1", 64, 80, (1, 1)), ("Conv2d_4a_3x3", 80, 192, (3, 3))]


def _block_a(c_in, pool):
    return [("branch1x1", c_in, 64, (1, 1)), ("branch5x5_1", c_in, 48, (1, 1)), ("branch5x5_2", 48, 64, (5, 5)), ("branch3x3dbl_1", c_in, 64, (1, 1)),
            ("branch3x3dbl_2", 64, 96, (3, 3)), ("branch3x3dbl_3", 96, 96, (3, 3)), ("branch_pool", c_in, pool, (1, 1))]


def _block_b(c_in):
    return [("branch3x3", c_in, 384, (3, 3)), ("branch3x3dbl_1", c_in, 64, (1, 1)), ("branch3x3dbl_2", 64, 96, (3, 3)), ("branch3x3dbl_3", 96, 96, (3, 3))]


def _block_c(c_in, c7):
    return [("branch1x1", c_in, 192, (1, 1)), ("branch7x7_1", c_in, c7, (1, 1)), ("branch7x7_2", c7, c7, (1, 7)), ("branch7x7_3", c7, 192, (7, 1)),
            ("branch7x7dbl_1", c_in, c7, (1, 1)), ("branch7x7dbl_2", c7, c7, (7, 1)), ("branch7x7dbl_3", c7, c7, (1, 7)), ("branch7x7dbl_4", c7, c7, (7, 1)),
            ("branch7x7dbl_5", c7, 192, (1, 7)), ("branch_pool", c_in, 192, (1, 1))]


def _block_d(c_in):
    return [("branch3x3_1", c_in, 192, (1, 1)), ("branch3x3_2", 192, 320, (3, 3)), ("branch7x7x3_1", c_in, 192, (1, 1)), ("branch7x7x3_2", 192, 192, (1, 7)),
            ("branch7x7x3_3", 192, 192, (7, 1)), ("branch7x7x3_4", 192, 192, (3, 3))]


def _block_e(c_in):
    return [("branch1x1", c_in, 320, (1, 1)), ("branch3x3_1", c_in, 384, (1, 1)), ("branch3x3_2a", 384, 384, (1, 3)), ("branch3x3_2b", 384, 384, (3, 1)),
            ("branch3x3dbl_1", c_in, 448, (1, 1)), ("branch3x3dbl_2", 448, 384, (3, 3)), ("branch3x3dbl_3a", 384, 384, (1, 3)), ("branch3x3dbl_3b", 384, 384, (3, 1)),
            ("branch_pool", c_in, 192, (1, 1))]


BLOCKS = {
    "Mixed_5b": _block_a(192, 32), "Mixed_5c": _block_a(256, 64), "Mixed_5d": _block_a(288, 64), "Mixed_6a": _block_b(288),
    "Mixed_6b": _block_c(768, 128), "Mixed_6c": _block_c(768, 160), "Mixed_6d": _block_c(768, 160), "Mixed_6e": _block_c(768, 192),
    "Mixed_7a": _block_d(768), "Mixed_7b": _block_e(1280), "Mixed_7c": _block_e(2048),
}


def expected_shapes() -> dict[str, tuple]:
    convs = [(name, c_in, c_out, k) for name, c_in, c_out, k in STEM]
    convs += [(f"{block}.{name}", c_in, c_out, k) for block, branches in BLOCKS.items() for name, c_in, c_out, k in branches]
    shapes = {"fc.weight": (1008, 2048), "fc.bias": (1008,)}
    for name, c_in, c_out, kernel in convs:
        shapes[f"{name}.conv.weight"] = (c_out, c_in, *kernel)
        for buffer in ("weight", "bias", "running_mean", "running_var"):
            shapes[f"{name}.bn.{buffer}"] = (c_out,)
        shapes[f"{name}.bn.num_batches_tracked"] = ()
    return shapes


@pytest.fixture(scope="module")
def network():
    torch.manual_seed(0)
    return FIDInceptionV3().eval()


def test_state_dict_has_the_layout_of_the_public_weights_file(network):
    state = network.state_dict()
    assert {k: tuple(v.shape) for k, v in state.items()} == expected_shapes()
    assert state["Conv2d_1a_3x3.conv.weight"].shape == (32, 3, 3, 3)
    assert state["Mixed_7c.branch3x3dbl_3b.conv.weight"].shape == (384, 384, 3, 1)
    assert state["Mixed_6e.branch7x7dbl_5.conv.weight"].shape == (192, 192, 1, 7)
    assert state["fc.weight"].shape == (1008, 2048)
    assert all(m.eps == 0.001 for m in network.modules() if isinstance(m, torch.nn.BatchNorm2d))
    # torchvision documents 27,161,264 parameters for Inception3 (1000 classes, auxiliary
    # classifier); pytorch-fid's network drops the auxiliary classifier and has 1008 classes.
    aux = (768 * 128 + 2 * 128) + (128 * 768 * 5 * 5 + 2 * 768) + (768 * 1000 + 1000)
    expected = 27_161_264 - aux + 8 * 2048 + 8
    assert sum(p.numel() for p in network.parameters()) == expected == 23_850_960


def _pool_branch_input(block: torch.nn.Module, x: torch.Tensor) -> torch.Tensor:
    captured = []
    handle = block.branch_pool.register_forward_hook(lambda module, inputs, output: captured.append(inputs[0]))
    with torch.no_grad():
        block(x)
    handle.remove()
    return captured[0]


def test_pool_branches_follow_pytorch_fid():
    torch.manual_seed(1)
    # Average pools ignore the zero padding (a constant map stays constant at the border) ...
    for block, channels in ((InceptionA(8, pool_features=4), 8), (InceptionC(8, channels_7x7=4), 8), (InceptionE(8, max_pool_branch=False), 8)):
        ones = torch.ones(1, channels, 5, 5)
        assert torch.equal(_pool_branch_input(block.eval(), ones), ones)
    # ... and the last E block max-pools (3x3, stride 1, padding 1).
    x = torch.randn(1, 8, 6, 6)
    pooled = _pool_branch_input(InceptionE(8, max_pool_branch=True).eval(), x)
    assert torch.equal(pooled, F.max_pool2d(x, 3, stride=1, padding=1))
    assert not torch.allclose(pooled, F.avg_pool2d(x, 3, stride=1, padding=1, count_include_pad=False))


def test_features_are_the_2048_d_pool_of_a_299_input(network):
    torch.manual_seed(2)
    images = torch.rand(2, 3, 64, 96)  # [0,1]
    with torch.no_grad():
        features = network(images)
        resized = network(F.interpolate(images, size=(299, 299), mode="bilinear", align_corners=False))
    assert features.shape == (2, 2048)
    assert torch.isfinite(features).all() and (features >= 0).all()  # mean of ReLU outputs
    assert torch.allclose(features, resized, atol=1e-5)  # the network resizes to 299x299 itself


# ---------------------------------------------------------------- through the evaluation code


@pytest.fixture(scope="module")
def setup(tmp_path_factory, network):
    from recondreamer.scene import write_scene
    from recondreamer.sources.synthetic import generate_segment

    root = tmp_path_factory.mktemp("inception")
    write_scene(root / "scene", generate_segment(3, "quick", frames=2))
    torch.manual_seed(0)
    configs = {
        "vehicle_detector": DetectorConfig(input_width=96, input_height=64, widths=(8, 8, 16, 16), neck_width=8),
        "lane_segmenter": LaneSegmenterConfig(input_width=96, input_height=64, widths=(8, 16, 16), blocks=(1, 1)),
        "fid_features": FeatureNetConfig(input_width=96, input_height=64, widths=(8, 8, 16, 16)),
    }
    for kind, config in configs.items():
        inference.save_model(root / "models" / inference.MODEL_FILES[kind], kind, config.build().eval(), {"run": "untrained test model"})
    weights = root / "pt_inception.pth"
    torch.save(network.state_dict(), weights)
    return root, weights


def test_evaluate_with_an_inception_weights_file(setup, network, tmp_path):
    from recondreamer.scene import load_scene

    root, weights = setup
    scene = load_scene(root / "scene")
    frames = np.stack([scene.image(t) for t in range(scene.num_frames)])  # (2,64,96,3)
    renders = tmp_path / "renders"
    renders.mkdir()
    for t, frame in enumerate(frames):
        Image.fromarray(frame).save(renders / f"{t:03d}.png")
    out = tmp_path / "metrics.json"
    args = ["evaluate", "--scene", str(root / "scene"), "--models", str(root / "models"), "--fid-model", str(weights)]
    assert main([*args, "--trajectory", "original", "--renders", str(renders), "--out", str(out)]) == 0

    doc = json.loads(out.read_text())
    sha = hashlib.sha256(weights.read_bytes()).hexdigest()
    assert doc["settings"]["fid_feature_network"].startswith(f"pytorch-fid InceptionV3 (local file, sha256 {sha})")
    described = doc["settings"]["models"]["fid_features"]
    assert described["kind"] == "fid_inception" and described["feature_dim"] == 2048 and described["sha256"] == sha
    fid = doc["trajectories"]["original"]["fid"]
    assert fid["fid"] == pytest.approx(0.0, abs=1e-6)
    features = np.load(out.with_suffix(".features.npz"))
    assert features["reference"].shape == (2, 2048)
    # The file's weights were used: the features equal the in-memory network's on the same frames.
    with torch.no_grad():
        direct = network(torch.from_numpy(frames).permute(0, 3, 1, 2).float() / 255.0).double().numpy()
    np.testing.assert_allclose(features["reference"], direct, rtol=1e-5, atol=1e-6)
    assert str(features["feature_network"]) == doc["settings"]["fid_feature_network"]


def test_fid_pool_records_the_feature_network_and_refuses_mixtures(setup, tmp_path):
    # Small made-up features: a Frechet distance of 2048-d features costs seconds, and pooling does not look at the dimension.
    root, weights = setup
    rng = np.random.default_rng(0)
    features = {"reference": rng.normal(size=(6, 4)), "shift@3": rng.normal(size=(6, 4))}
    inception = inference.load_fid_model(weights)
    corpus = inference.load_fid_model(root / "models" / "fid_features.pt")
    write_features(tmp_path / "a.npz", "scene_a", features, inception)
    write_features(tmp_path / "b.npz", "scene_b", features, inception)
    write_features(tmp_path / "c.npz", "scene_c", features, corpus)
    pooled = pooled_fid([tmp_path / "a.npz", tmp_path / "b.npz"])
    assert pooled["fid_feature_network"] == fid_feature_network(inception) and pooled["num_scenes"] == 2
    assert pooled["fid_feature_network"].startswith(f"pytorch-fid InceptionV3 (local file, sha256 {inception.sha256})")
    assert pooled_fid([tmp_path / "c.npz"])["fid_feature_network"] == FID_FEATURES_NOTE
    with pytest.raises(RecondreamerError, match="2 different feature networks"):
        pooled_fid([tmp_path / "a.npz", tmp_path / "c.npz"])


def test_default_feature_network_is_the_corpus_one(setup):
    root, _ = setup
    models = load_eval_models(root / "models")
    assert models.features.kind == "fid_features"
    assert "not pytorch-fid's InceptionV3" in models.describe()["fid_features"]["note"]


def test_weights_saved_without_batch_counters_load(setup, network, tmp_path):
    # Files written by old torch versions lack BatchNorm's num_batches_tracked buffers.
    state = {k: v for k, v in network.state_dict().items() if not k.endswith("num_batches_tracked")}
    torch.save(state, tmp_path / "old.pth")
    loaded = inference.load_fid_model(tmp_path / "old.pth")
    assert loaded.kind == "fid_inception"
    assert torch.equal(loaded.module.state_dict()["Mixed_7c.branch_pool.conv.weight"], state["Mixed_7c.branch_pool.conv.weight"])


def test_wrong_files_give_clear_errors(setup, network, tmp_path, capsys):
    root, _ = setup
    state = network.state_dict()
    broken = {k: v for k, v in state.items() if k != "fc.bias"}
    torch.save(broken, tmp_path / "missing.pth")
    with pytest.raises(CheckpointError, match=r"missing\.pth: an Inception state_dict, but not pytorch-fid's FID InceptionV3.*fc\.bias"):
        inference.load_fid_model(tmp_path / "missing.pth")
    torchvision_like = {**state, "fc.weight": torch.zeros(1000, 2048), "fc.bias": torch.zeros(1000)}
    torch.save(torchvision_like, tmp_path / "torchvision.pth")
    with pytest.raises(CheckpointError, match="size mismatch for fc.weight"):
        inference.load_fid_model(tmp_path / "torchvision.pth")
    torch.save({"weight": torch.zeros(3)}, tmp_path / "other.pth")
    with pytest.raises(CheckpointError, match=r"other\.pth: neither a recondreamer FID feature model .* nor a pytorch-fid InceptionV3"):
        inference.load_fid_model(tmp_path / "other.pth")
    with pytest.raises(CheckpointError, match="holds a 'vehicle_detector' model, expected 'fid_features'"):
        inference.load_fid_model(root / "models" / "vehicle_detector.pt")
    (tmp_path / "text.pth").write_text("not a checkpoint")
    with pytest.raises(CheckpointError, match="not a readable torch checkpoint"):
        inference.load_fid_model(tmp_path / "text.pth")
    with pytest.raises(CheckpointError, match="not found"):
        inference.load_fid_model(tmp_path / "absent.pth")
    # The command line turns it into one line and exit code 1.
    args = ["evaluate", "--scene", str(root / "scene"), "--models", str(root / "models"), "--fid-model", str(tmp_path / "missing.pth")]
    assert main([*args, "--trajectory", "original", "--renders", str(tmp_path), "--out", str(tmp_path / "m.json")]) == 1
    assert "missing.pth" in capsys.readouterr().err
