"""The fused C++ projection + SH pass (``cpu_kernel.project_cpu``) against the torch oracle
(``project_gaussians`` followed by ``evaluate_colors``): every output and the gradients of all
inputs under random upstream gradients on every output, so each term of the hand-written
backward is exercised directly, not only through the compositor.

Tolerances: op_tester's, elementwise. The float32 kernel sums its SH terms and chains its
Jacobian products in another order than autograd, so the comparison of all outputs and gradients
uses the low-tolerance entries; in float64 those equal the plain ones (the kernel follows the
oracle's formulas; only the order of a few sums differs).
"""

from __future__ import annotations

import math

import pytest
import torch
from op_tester import BaseTester

from recondreamer.splat import rasterize
from recondreamer.splat.cpu_kernel import project_cpu
from recondreamer.splat.projection import project_gaussians
from recondreamer.splat.sh import evaluate_colors

WIDTH, HEIGHT = 40, 30


def camera(dtype: torch.dtype):
    K = torch.tensor([[36.0, 0.0, 20.3], [0.0, 34.0, 14.6], [0.0, 0.0, 1.0]], dtype=dtype)
    angle = 0.2
    viewmat = torch.eye(4, dtype=dtype)
    viewmat[:3, :3] = torch.tensor(
        [[math.cos(angle), -math.sin(angle), 0.0], [math.sin(angle), math.cos(angle), 0.0], [0.0, 0.0, 1.0]],
        dtype=dtype,
    ) @ torch.tensor(
        [[1.0, 0.0, 0.0], [0.0, math.cos(0.3), math.sin(0.3)], [0.0, -math.sin(0.3), math.cos(0.3)]], dtype=dtype
    )
    viewmat[:3, 3] = torch.tensor([0.3, -0.2, 1.0], dtype=dtype)
    return viewmat, K


def gaussians(count: int, dtype: torch.dtype, sh_coefficients: int | None, seed: int = 0):
    """Random Gaussians around the view, with some behind the camera, at the near plane and far
    outside the field of view (where the Jacobian's view-angle clamp is active)."""
    g = torch.Generator().manual_seed(seed)
    viewmat, _ = camera(torch.float64)
    camera_space = torch.randn(count, 3, generator=g, dtype=torch.float64) * torch.tensor([2.0, 1.5, 1.0])
    camera_space[:, 2] += 5.0
    camera_space[:4, 2] = torch.tensor([-2.0, 0.0, 0.005, 0.02])  # behind / at / just past the near plane
    camera_space[4:8, 0] = torch.tensor([40.0, -40.0, 3.0, -3.0])  # far outside left/right: clamped tx
    camera_space[8:10, 1] = torch.tensor([30.0, -30.0])  # far outside top/bottom: clamped ty
    rotation, translation = viewmat[:3, :3], viewmat[:3, 3]
    means = (camera_space - translation) @ rotation  # world = R^T (cam - t)
    quats = torch.randn(count, 4, generator=g, dtype=torch.float64) * 2.0
    scales = torch.exp(torch.empty(count, 3, dtype=torch.float64).uniform_(math.log(0.01), math.log(0.8), generator=g))
    if sh_coefficients is None:
        colors = torch.rand(count, 3, generator=g, dtype=torch.float64)
    else:
        colors = torch.randn(count, sh_coefficients, 3, generator=g, dtype=torch.float64) * 0.5
    return [t.to(dtype) for t in (means, quats, scales, colors)]


def outputs_and_grads(project, inputs, viewmat, K, active=None):
    """Run one projection, back-propagate fixed random weights on every differentiable output.

    ``active``: optional (4,N) bool, which Gaussians get a nonzero weight on means2d, conics,
    depths and rgb (in that order); None = all."""
    params = [t.detach().clone().requires_grad_() for t in inputs]
    projected, rgb = project(*params, viewmat, K)
    g = torch.Generator().manual_seed(3)
    loss = 0.0
    for index, tensor in enumerate((projected.means2d, projected.conics, projected.depths, rgb)):
        weights = torch.randn(tensor.shape, generator=g, dtype=torch.float64).to(tensor.dtype)
        if active is not None:
            weights = weights * active[index].reshape((-1,) + (1,) * (tensor.dim() - 1)).to(weights.dtype)
        loss = loss + (tensor * weights).sum()
    loss.backward()
    values = {
        "means2d": projected.means2d,
        "conics": projected.conics,
        "depths": projected.depths,
        "rgb": rgb,
        "radii": projected.radii,
        "visible": projected.visible,
        "in_front": projected.in_front,
    }
    values = {name: value.detach() for name, value in values.items()}
    for name, tensor in zip(("means", "quats", "scales", "colors"), params):
        values[f"grad_{name}"] = tensor.grad
    return values


def torch_projection(means, quats, scales, colors, viewmat, K):
    return project_gaussians(means, quats, scales, viewmat, K, WIDTH, HEIGHT), evaluate_colors(colors, means, viewmat)


def fused_projection(means, quats, scales, colors, viewmat, K):
    return project_cpu(means, quats, scales, colors, viewmat, K, WIDTH, HEIGHT)


class TestProjectCPU(BaseTester):
    """``project_cpu``: the fused projection + SH pass, against ``project_gaussians`` + ``evaluate_colors``."""

    @pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
    @pytest.mark.parametrize("sh_coefficients", [None, 1, 4, 9, 16])
    def test_correctness(self, dtype, sh_coefficients):
        viewmat, K = camera(dtype)
        inputs = gaussians(64, dtype, sh_coefficients, seed=sh_coefficients or 0)
        expected = outputs_and_grads(torch_projection, inputs, viewmat, K)
        actual = outputs_and_grads(fused_projection, inputs, viewmat, K)
        assert not bool(expected["in_front"][:3].any()) and bool(expected["in_front"][3:].all())
        assert not bool(expected["visible"][4:6].any())  # the clamped ones are off screen
        for name, want in expected.items():
            got = actual[name]
            assert got.shape == want.shape and got.dtype == want.dtype, name
            if want.dtype in (torch.bool, torch.int32):
                assert torch.equal(got, want), name
                continue
            # Culled Gaussians keep finite placeholder values in both implementations: compare all.
            self.assert_close(got, want, low_tolerance=True, msg=name)

    @pytest.mark.parametrize("sh_coefficients", [None, 9])
    def test_correctness_without_incoming_gradient(self, sh_coefficients):
        # The fused backward skips a Gaussian whose incoming gradients are all zero (no output depends
        # on it); one nonzero incoming gradient on any single output must still reach the inputs.
        viewmat, K = camera(torch.float64)
        inputs = gaussians(64, torch.float64, sh_coefficients, seed=8)
        pattern = torch.arange(64) % 6  # 0: none, 1-4: only one output, 5: all outputs
        active = torch.stack([(pattern == k + 1) | (pattern == 5) for k in range(4)])  # (4,N)
        expected = outputs_and_grads(torch_projection, inputs, viewmat, K, active)
        actual = outputs_and_grads(fused_projection, inputs, viewmat, K, active)
        for name in ("grad_means", "grad_quats", "grad_scales") + (("grad_colors",) if sh_coefficients else ()):
            want, got = expected[name], actual[name]
            assert bool((got[pattern == 0] == 0).all()), name
            self.assert_close(got, want, msg=name)
        in_front = expected["in_front"]
        for k in range(1, 5):  # each output alone moves the means of the Gaussians in front
            if k < 4 or sh_coefficients:
                assert bool((expected["grad_means"][(pattern == k) & in_front].abs().sum(-1) > 0).any()), k

    def test_correctness_dark_sh_colours_clamp(self):
        # Strongly negative degree-0 coefficients: the colour clamps at 0 and passes no gradient.
        # Both sides evaluate the same SH sum and clamp: they agree to the rounding of O(1) numbers.
        viewmat, K = camera(torch.float64)
        means, quats, scales, colors = gaussians(16, torch.float64, 4, seed=5)
        colors[:8, 0, :] = -5.0
        expected = outputs_and_grads(torch_projection, [means, quats, scales, colors], viewmat, K)
        actual = outputs_and_grads(fused_projection, [means, quats, scales, colors], viewmat, K)
        assert bool((expected["rgb"][:8] == 0).all())
        torch.testing.assert_close(actual["rgb"], expected["rgb"], rtol=0, atol=1e-12)
        torch.testing.assert_close(actual["grad_colors"], expected["grad_colors"], rtol=0, atol=1e-12)
        assert bool((actual["grad_colors"][:8] == 0).all())

    def test_camera_gradients_fall_back_to_the_torch_projection(self):
        # The fused pass treats viewmat and K as constants; a caller that asks for their gradients
        # gets the torch projection, with the same image and the same camera gradient as "torch".
        viewmat, K = camera(torch.float64)
        means, quats, scales, colors = gaussians(40, torch.float64, None, seed=2)
        opacities = torch.rand(40, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
        grads = {}
        for backend in ("torch", "cpu"):
            pose = viewmat.clone().requires_grad_()
            out = rasterize(means, quats, scales, opacities, colors, pose, K, WIDTH, HEIGHT, backend=backend)
            out["rgb"].sum().backward()
            grads[backend] = pose.grad
        assert grads["cpu"] is not None and grads["cpu"].abs().sum() > 0
        self.assert_close(grads["cpu"], grads["torch"])
