"""Unit tests of the reconstruction building blocks (no training)."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest
import torch

from recondreamer.errors import RecondreamerError
from recondreamer.configs import from_dict, to_dict
from recondreamer.recon.config import LossConfig, ReconConfig, make_config
from recondreamer.recon.data import TrainingSet, TrainingView, lidar_depth_map
from recondreamer.recon.density import (
    DensityController,
    build_optimizer,
    edit_rows,
    exponential_lr,
)
from recondreamer.recon.gaussians import matrix_to_quat, quat_multiply, quat_slerp
from recondreamer.recon.losses import view_loss
from recondreamer.recon.pvg import PVGModel
from recondreamer.splat.projection import quats_to_rotmats


def random_quats(n: int, seed: int = 0) -> torch.Tensor:
    q = torch.randn(n, 4, generator=torch.Generator().manual_seed(seed))
    return q / q.norm(dim=1, keepdim=True)


def test_matrix_to_quat_inverts_rotation_matrix():
    q = random_quats(64)
    back = matrix_to_quat(quats_to_rotmats(q))
    same = torch.minimum(
        (back - q).abs().amax(1), (back + q).abs().amax(1)
    )  # q and -q are one rotation
    assert same.max() < 1e-5


def test_quat_multiply_composes_rotations():
    a, b = random_quats(16, 1), random_quats(16, 2)
    expected = quats_to_rotmats(a) @ quats_to_rotmats(b)
    assert torch.allclose(quats_to_rotmats(quat_multiply(a, b)), expected, atol=1e-5)


def test_slerp_halfway_about_z_axis():
    def about_z(angle):
        return torch.tensor([[math.cos(angle / 2), 0.0, 0.0, math.sin(angle / 2)]])

    mid = quat_slerp(about_z(0.2), about_z(1.0), torch.tensor([0.5]))
    assert torch.allclose(mid, about_z(0.6), atol=1e-6)


def test_config_round_trip_and_unknown_names():
    config = make_config("s3", "quick", iterations=7)
    back = from_dict(ReconConfig, to_dict(config))
    assert to_dict(back) == to_dict(config)
    assert (
        back.iterations == 7
        and back.net.hexplane_resolutions == config.net.hexplane_resolutions
    )
    with pytest.raises(RecondreamerError, match="unknown reconstruction model"):
        make_config("nerf")
    with pytest.raises(RecondreamerError, match="unknown preset"):
        make_config("street", "huge")
    with pytest.raises(RecondreamerError, match="ReconConfig: unknown field"):
        from_dict(ReconConfig, {**to_dict(config), "bogus": 1})


def test_exponential_lr_endpoints_and_midpoint():
    assert exponential_lr(0, 100, 1e-2, 1e-4) == pytest.approx(1e-2)
    assert exponential_lr(100, 100, 1e-2, 1e-4) == pytest.approx(1e-4)
    assert exponential_lr(50, 100, 1e-2, 1e-4) == pytest.approx(1e-3)


def tiny_pvg(num: int = 6) -> PVGModel:
    config = make_config("pvg", "quick")
    spec = {
        "num_gaussians": num,
        "time_range": [0.0, 1.0],
        "center": [0.0, 0.0, 0.0],
        "extent": 10.0,
    }
    model = PVGModel(spec, config.net)
    with torch.no_grad():
        for param in model.gaussians.params.values():
            param.copy_(
                torch.arange(param.numel(), dtype=torch.float32).reshape(param.shape)
                / param.numel()
            )
    return model


def test_pvg_vibration_and_lifespan_formulas():
    model = tiny_pvg(1)
    p = model.gaussians.params
    with torch.no_grad():
        p["means"].copy_(torch.tensor([[1.0, 2.0, 3.0]]))
        p["velocity"].copy_(torch.tensor([[0.1, 0.0, 0.0]]))
        p["peak_time"].fill_(0.3)
        p["log_lifespan"].fill_(math.log(0.2))
        p["logit_opacities"].fill_(0.0)
    cycle = model.net.pvg_cycle
    g = model.gaussians_at(0.35)
    expected_x = (
        1.0
        + cycle
        / (2 * math.pi)
        * math.sin(2 * math.pi * 0.05 / cycle)
        * 0.1
        * model.extent
    )
    assert g["means"][0, 0].item() == pytest.approx(expected_x, rel=1e-6)
    assert g["opacities"][0].item() == pytest.approx(
        0.5 * math.exp(-0.5 * (0.05 / 0.2) ** 2), rel=1e-6
    )


def test_edit_rows_keeps_adam_moments_of_surviving_rows():
    model = tiny_pvg(6)
    optimizer = build_optimizer(model, make_config("pvg", "quick").optim)
    loss = sum((p**2).sum() for p in model.gaussians.params.values())
    loss.backward()
    optimizer.step()
    old = model.gaussians.params["velocity"]
    old_moment = optimizer.state[old]["exp_avg"].clone()
    keep = torch.tensor([True, False, True, True, False, True])
    new_rows = {
        name: torch.ones((2,) + p.shape[1:])
        for name, p in model.gaussians.params.items()
    }
    edit_rows(model, optimizer, keep, new_rows)
    param = model.gaussians.params["velocity"]
    assert param.shape[0] == 6
    assert torch.equal(param.data[:4], old.data[keep]) and torch.equal(
        param.data[4:], torch.ones(2, 3)
    )
    state = optimizer.state[param]
    assert (
        torch.equal(state["exp_avg"][:4], old_moment[keep])
        and not state["exp_avg"][4:].any()
    )
    assert old not in optimizer.state and any(
        param is q for group in optimizer.param_groups for q in group["params"]
    )


def test_densification_respects_gaussian_cap_and_prunes_transparent():
    model = tiny_pvg(6)
    config = make_config("pvg", "quick")
    config.densify.max_gaussians = 8
    optimizer = build_optimizer(model, config.optim)
    controller = DensityController(config.densify, 100, 6)
    with torch.no_grad():
        model.gaussians.params["logit_opacities"].copy_(
            torch.tensor([2.0, 2.0, 2.0, 2.0, 2.0, -10.0])
        )
        model.gaussians.params["log_scales"].fill_(math.log(0.01))
    # Four Gaussians over the threshold but budget for two; the last one is transparent.
    controller.accumulate(
        torch.tensor(
            [[1.0, 0.0], [0.5, 0.0], [0.2, 0.0], [0.1, 0.0], [0.0, 0.0], [0.0, 0.0]]
        ),
        torch.ones(6, dtype=torch.int32),
        2,
        2,
    )
    report = controller.densify_and_prune(
        model, optimizer, torch.Generator().manual_seed(0)
    )
    assert report == {"cloned": 2, "split": 0, "pruned": 1, "total": 7}
    assert len(model.gaussians) == 7 and len(controller.grad_sum) == 7


def make_view(depth=None, weight=1.0, source="original") -> TrainingView:
    image = np.full((8, 10, 3), 128, dtype=np.uint8)
    return TrainingView(
        np.eye(4), 0.0, image, depth=depth, source=source, weight=weight
    )


def test_training_set_sampling_follows_weights():
    data = TrainingSet(
        np.eye(3), 10, 8, [make_view(weight=1.0), make_view(weight=3.0, source="novel")]
    )
    counts = np.bincount(
        [
            0 if data.sample(np.random.default_rng(i)).source == "original" else 1
            for i in range(2000)
        ]
    )
    assert abs(counts[1] / 2000 - 0.75) < 0.04
    data.set_source_weight("novel", 1.0)
    assert np.allclose(data.probabilities(), [0.5, 0.5])
    assert data.remove_source("novel") == 1 and data.sources() == {"original": 1}
    with pytest.raises(RecondreamerError, match="image must be"):
        data.add(TrainingView(np.eye(4), 0.0, np.zeros((4, 4, 3), np.uint8)))


def test_lidar_depth_map_keeps_nearest_point_per_pixel():
    K = np.array([[10.0, 0, 5], [0, 10.0, 4], [0, 0, 1]])
    points = np.array(
        [[0.0, 0.0, 4.0], [0.0, 0.0, 2.0], [0.0, 0.0, -3.0]]
    )  # two on the axis, one behind
    depth = lidar_depth_map(points, K, np.eye(4), 10, 8)
    assert depth[4, 5] == pytest.approx(2.0) and np.count_nonzero(depth) == 1


def test_depth_free_view_has_no_depth_term():
    rgb = torch.rand(8, 10, 3)
    render = {"rgb": rgb, "depth": torch.full((8, 10), 5.0), "alpha": torch.ones(8, 10)}
    target = torch.rand(8, 10, 3)
    with_depth, parts = view_loss(
        render, target, np.full((8, 10), 2.0, np.float32), None, LossConfig(depth=1.0)
    )
    without, parts_free = view_loss(render, target, None, None, LossConfig(depth=1.0))
    assert parts["depth"] == pytest.approx(1.5) and "depth" not in parts_free
    assert float(with_depth - without) == pytest.approx(1.5)


def test_reproducibility_notes_say_what_a_run_promises(monkeypatch):
    from recondreamer.recon.reproducibility import reproducibility

    model = tiny_pvg(1)
    monkeypatch.delenv("MKL_CBWR", raising=False)
    notes = reproducibility(make_config("pvg", "quick"), model)
    assert notes["repeats"].endswith("and at any other thread count") and notes["threads"] == torch.get_num_threads()
    assert "reference backend" in reproducibility(make_config("pvg", "quick", backend="torch"), model)["repeats"]
    # A model with shared networks (deformable, s3): MKL's products split by thread count unless strict.
    monkeypatch.setattr(model, "field_parameters", lambda: [torch.nn.Parameter(torch.zeros(1))])
    assert "MKL_CBWR=AUTO,STRICT" in reproducibility(make_config("deformable", "quick"), model)["repeats"]
    monkeypatch.setenv("MKL_CBWR", "AUTO,STRICT")
    assert reproducibility(make_config("deformable", "quick"), model)["repeats"].endswith("at any other thread count")
    cuda = reproducibility(make_config("pvg", "quick", device="cuda"), model)
    assert cuda["repeats"].startswith("not bit-reproducible") and "atomic" in cuda["repeats"]


def test_deterministic_option_turns_on_torchs_deterministic_mode(monkeypatch):
    from recondreamer.recon.reproducibility import reproducibility, use_deterministic_algorithms

    monkeypatch.setenv("CUBLAS_WORKSPACE_CONFIG", ":16:8")  # a user's own setting wins
    previous = torch.are_deterministic_algorithms_enabled(), torch.is_deterministic_algorithms_warn_only_enabled()
    try:
        use_deterministic_algorithms()
        assert torch.are_deterministic_algorithms_enabled() and torch.is_deterministic_algorithms_warn_only_enabled()
        assert reproducibility(make_config("pvg", "quick"), tiny_pvg(1))["deterministic_algorithms"]
    finally:
        torch.use_deterministic_algorithms(previous[0], warn_only=previous[1])
    assert os.environ["CUBLAS_WORKSPACE_CONFIG"] == ":16:8"
