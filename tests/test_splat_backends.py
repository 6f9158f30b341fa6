"""Every fast backend against the pure-torch reference: outputs and gradients.

Tolerances (max abs difference, relative to 1 + the largest magnitude of the reference value):
float64 1e-9 (the kernels follow the reference's arithmetic; only summation order differs),
float32 2e-4 for images and gradients (float32 rounding, the kernel's own exp to a few ulp).
gsplat (CUDA only; untested where no GPU is present) computes in float32, clamps alpha at 0.999
and bounds supports its own way: its scenes keep opacity <= 0.98 and the tolerance is 2e-3.
These bounds are relative to the whole tensor's scale, not elementwise as op_tester's table: a
gradient entry sums a splat's contributions over every pixel it covers, and its float32 rounding
follows the largest entries of its tensor rather than its own size.
"""

from __future__ import annotations

import math

import pytest
import torch
from op_tester import BaseTester

from recondreamer.splat import rasterize

# Max abs error over a tensor, relative to 1 + the largest magnitude of its reference (see above).
SCALED_TOLERANCE = {torch.float64: 1e-9, torch.float32: 2e-4}
GSPLAT_TOLERANCE = 2e-3
GSPLAT_MAX_OPACITY = 0.98
BACKENDS = [
    "cpu",
    pytest.param(
        "gsplat",
        marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="gsplat backend needs a CUDA device"),
    ),
]


def camera(width: int, height: int, dtype: torch.dtype):
    K = torch.tensor([[0.9 * width, 0.0, width / 2 + 0.3], [0.0, 0.9 * width, height / 2 - 0.2], [0.0, 0.0, 1.0]])
    viewmat = torch.eye(4)
    angle = 0.1  # a slightly rotated, translated camera
    viewmat[:3, :3] = torch.tensor(
        [[math.cos(angle), 0.0, math.sin(angle)], [0.0, 1.0, 0.0], [-math.sin(angle), 0.0, math.cos(angle)]]
    )
    viewmat[:3, 3] = torch.tensor([0.2, -0.1, 0.5])
    return viewmat.to(dtype), K.to(dtype)


def random_scene(count: int, seed: int, dtype: torch.dtype, sh_coefficients: int | None = None, spread: float = 1.0):
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(count, 3, generator=g) * torch.tensor([2.0, 1.2, 1.0]) * spread
    means[:, 2] += 6.0
    quats = torch.randn(count, 4, generator=g)
    scales = torch.exp(torch.empty(count, 3).uniform_(math.log(0.02), math.log(0.5), generator=g))
    opacities = torch.rand(count, generator=g)
    if sh_coefficients is None:
        colors = torch.rand(count, 3, generator=g)
    else:
        colors = torch.randn(count, sh_coefficients, 3, generator=g) * 0.4
    return [t.to(dtype) for t in (means, quats, scales, opacities, colors)]


def render_with_grads(backend, scene, viewmat, K, width, height, background=None):
    """Render, back-propagate a fixed random loss, return outputs and gradients by name."""
    params = [t.detach().clone().to(_device(backend)).requires_grad_() for t in scene]
    bg = None if background is None else background.detach().clone().to(_device(backend)).requires_grad_()
    out = rasterize(*params, viewmat.to(_device(backend)), K.to(_device(backend)), width, height, bg, backend=backend)
    out["means2d"].retain_grad()
    g = torch.Generator().manual_seed(7)
    weights = torch.randn(height, width, 5, generator=g).to(out["rgb"].dtype).to(_device(backend))
    loss = (out["rgb"] * weights[..., :3]).sum() + (out["depth"] * weights[..., 3]).sum() * 0.1
    loss = loss + (out["alpha"] * weights[..., 4]).sum()
    loss.backward()
    result = {name: out[name].detach().cpu() for name in ("rgb", "depth", "alpha", "radii", "visible")}
    result["grad_means2d"] = _grad(out["means2d"])
    for name, tensor in zip(("means", "quats", "scales", "opacities", "colors"), params):
        result[f"grad_{name}"] = _grad(tensor)
    if bg is not None:
        result["grad_background"] = _grad(bg)
    return result


def _device(backend: str) -> str:
    return "cuda" if backend == "gsplat" else "cpu"


def _grad(tensor: torch.Tensor) -> torch.Tensor:
    return torch.zeros_like(tensor).cpu() if tensor.grad is None else tensor.grad.detach().cpu()


def assert_matches_reference(backend, scene, viewmat, K, width, height, background=None):
    tolerance = SCALED_TOLERANCE[scene[0].dtype]
    if backend == "gsplat":
        tolerance = GSPLAT_TOLERANCE
        scene = scene[:3] + [scene[3] * GSPLAT_MAX_OPACITY] + scene[4:]
    expected = render_with_grads("torch", scene, viewmat, K, width, height, background)
    actual = render_with_grads(backend, scene, viewmat, K, width, height, background)
    assert set(actual) == set(expected)
    for name, want in expected.items():
        got = actual[name]
        assert got.shape == want.shape, name
        if name in ("radii", "visible"):
            assert torch.equal(got, want), name
            continue
        assert_scaled_close(got, want, tolerance, name)
    return expected


def assert_scaled_close(got: torch.Tensor, want: torch.Tensor, tolerance: float, name: str) -> None:
    """Max abs error <= tolerance * (1 + the largest magnitude of ``want``)."""
    scale = 1.0 + (want.abs().max().item() if want.numel() else 0.0)
    error = (got - want).abs().max().item() if want.numel() else 0.0
    assert error <= tolerance * scale, f"{name}: max abs error {error:.3g} (scale {scale:.3g})"


def edge_scene(kind: str, dtype: torch.dtype):
    """Small hand-made scenes that stress one rule each."""
    means, quats, scales, opacities, colors = random_scene(12, seed=11, dtype=torch.float64)
    if kind == "behind_camera":
        means[:6, 2] = torch.tensor([-3.0, -0.5, 0.0, 0.005, 0.02, -10.0]) - 0.5  # camera at z=-0.5
    elif kind == "border":
        means[:, 0] = torch.linspace(-4.5, 4.5, 12)  # centres beyond both sides of the view
        scales[:] = 0.6
    elif kind == "thin":
        scales[:, 0] = 1e-4
        scales[:, 2] = 1e-4
        scales[:, 1] = 2.0
    elif kind == "large":
        scales[:4] = 20.0
        opacities[:4] = 0.3
    elif kind == "zero_opacity":
        opacities[::2] = 0.0
        opacities[1::4] = 1.0
    elif kind == "saturated":  # many opaque splats: early termination decides every pixel
        means = torch.randn(12, 3, dtype=torch.float64) * 0.05 + torch.tensor([0.0, 0.0, 5.5], dtype=torch.float64)
        means[:, 2] += torch.arange(12, dtype=torch.float64) * 0.1
        scales[:] = 1.5
        opacities[:] = 0.97
    return [t.to(dtype) for t in (means, quats, scales, opacities, colors)]


class TestRasterizeBackends(BaseTester):
    """``rasterize`` on each fast backend against ``backend="torch"``: outputs and gradients."""

    @pytest.mark.parametrize("backend", BACKENDS)
    @pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
    @pytest.mark.parametrize("size", [(32, 24), (37, 21)])
    def test_correctness(self, backend, dtype, size):
        width, height = size
        viewmat, K = camera(width, height, dtype)
        scene = random_scene(150, seed=width, dtype=dtype)
        expected = assert_matches_reference(backend, scene, viewmat, K, width, height)
        assert expected["alpha"].max() > 0.5  # the scene does cover the image

    @pytest.mark.parametrize("backend", BACKENDS)
    @pytest.mark.parametrize("sh_coefficients", [1, 4, 9, 16])
    def test_correctness_sh_degrees(self, backend, sh_coefficients):
        viewmat, K = camera(32, 24, torch.float64)
        scene = random_scene(60, seed=sh_coefficients, dtype=torch.float64, sh_coefficients=sh_coefficients)
        assert_matches_reference(backend, scene, viewmat, K, 32, 24)

    @pytest.mark.parametrize("backend", BACKENDS)
    def test_correctness_background_gradient(self, backend):
        viewmat, K = camera(32, 24, torch.float64)
        scene = random_scene(40, seed=3, dtype=torch.float64)
        expected = assert_matches_reference(
            backend, scene, viewmat, K, 32, 24, torch.tensor([0.3, 0.6, 0.9], dtype=torch.float64)
        )
        assert expected["grad_background"].abs().sum() > 0

    @pytest.mark.parametrize("backend", BACKENDS)
    @pytest.mark.parametrize("kind", ["behind_camera", "border", "thin", "large", "zero_opacity", "saturated"])
    @pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
    def test_correctness_edge_cases(self, backend, kind, dtype):
        viewmat, K = camera(32, 24, dtype)
        assert_matches_reference(backend, edge_scene(kind, dtype), viewmat, K, 32, 24)

    @pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
    def test_correctness_dense_multi_tile_scene_with_early_termination(self, dtype):
        # 5x4 tiles (the last column and row partial, an odd height for the 2-row pixel groups),
        # opaque splats: most pixels finish early, so the forward pass skips finished groups and the
        # backward pass starts at each pixel's last splat and visits only the groups the forward
        # pass listed for each (splat, tile).
        width, height = 70, 51
        viewmat, K = camera(width, height, dtype)
        means, quats, scales, opacities, colors = random_scene(400, seed=21, dtype=torch.float64, spread=0.8)
        scales, opacities = scales * 3.0, 0.6 + 0.4 * opacities
        scene = [t.to(dtype) for t in (means, quats, scales, opacities, colors)]
        expected = assert_matches_reference("cpu", scene, viewmat, K, width, height)
        assert (expected["alpha"] > 0.999).float().mean() > 0.5  # most pixels are (nearly) opaque

    @pytest.mark.parametrize("backend", BACKENDS)
    @pytest.mark.parametrize("count", [0, 1])
    def test_cardinality_tiny_counts(self, backend, count):
        viewmat, K = camera(32, 24, torch.float64)
        scene = random_scene(count, seed=5, dtype=torch.float64, spread=0.2)
        assert_matches_reference(backend, scene, viewmat, K, 32, 24)

    @pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
    def test_cpu_kernel_is_bit_identical_at_any_thread_count(self, dtype):
        # Every splat's gradient is summed over its tiles in one fixed order, so the outputs and all
        # gradients are bit-identical at 1, 2 and 4 threads, run after run. 20k splats: more than one
        # task of the gradient sum (8192 splats each). One run in torch's deterministic mode, which
        # fills uninitialised memory with NaN: every per-entry gradient row must be written.
        width, height = 64, 48
        viewmat, K = camera(width, height, dtype)
        scene = random_scene(20_000, seed=9, dtype=dtype)
        threads = torch.get_num_threads()
        deterministic = torch.are_deterministic_algorithms_enabled()
        runs = []
        try:
            for count in (1, 2, 4, 2):
                torch.set_num_threads(count)
                runs.append(render_with_grads("cpu", scene, viewmat, K, width, height))
            torch.use_deterministic_algorithms(True)
            runs.append(render_with_grads("cpu", scene, viewmat, K, width, height))
        finally:
            torch.use_deterministic_algorithms(deterministic)
            torch.set_num_threads(threads)
        assert runs[0]["grad_means"].abs().sum() > 0
        for run in runs[1:]:
            for name, value in runs[0].items():
                assert torch.equal(run[name], value), name


class TestCompositeCPU(BaseTester):
    """``composite_cpu`` with a keep mask against ``composite_reference`` on the kept splats."""

    @pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
    def test_correctness_keep_mask(self, dtype):
        # composite_cpu(..., keep) composites only the kept splats (rasterize passes the in-front
        # mask this way) and gives the others zero gradients.
        from recondreamer.splat.cpu_kernel import composite_cpu
        from recondreamer.splat.reference import composite_reference

        width, height = 40, 30
        g = torch.Generator().manual_seed(4)
        count = 120
        axes = torch.randn(count, 2, 2, generator=g, dtype=torch.float64) * 2.0
        covariances = axes @ axes.transpose(1, 2) + 0.3 * torch.eye(2, dtype=torch.float64)
        inverse = torch.linalg.inv(covariances)
        fields = [
            torch.rand(count, 2, generator=g, dtype=torch.float64) * torch.tensor([width, height], dtype=torch.float64),
            torch.stack([inverse[:, 0, 0], inverse[:, 0, 1], inverse[:, 1, 1]], dim=-1),
            torch.rand(count, 3, generator=g, dtype=torch.float64),
            torch.rand(count, generator=g, dtype=torch.float64),
            torch.rand(count, generator=g, dtype=torch.float64) * 10 + 1,
        ]
        fields = [t.to(dtype) for t in fields]
        keep = torch.rand(count, generator=g) < 0.7
        weights = torch.randn(height, width, 5, generator=g, dtype=torch.float64).to(dtype)

        def loss(rgb, depth, alpha):
            rgb_term = (rgb * weights[..., :3]).sum()
            return rgb_term + (depth * weights[..., 3]).sum() * 0.1 + (alpha * weights[..., 4]).sum()

        actual_inputs = [t.clone().requires_grad_() for t in fields]
        actual = composite_cpu(*actual_inputs, width, height, keep)
        loss(*actual).backward()
        expected_inputs = [t.clone().requires_grad_() for t in fields]
        expected = composite_reference(*(t[keep] for t in expected_inputs), width, height)
        loss(*expected).backward()
        tolerance = SCALED_TOLERANCE[dtype]
        for name, got, want in zip(("rgb", "depth", "alpha"), actual, expected):
            assert_scaled_close(got, want, tolerance, name)
        for index, (got, want) in enumerate(zip(actual_inputs, expected_inputs)):
            assert_scaled_close(got.grad, want.grad, tolerance, f"gradient of field {index}")
            assert torch.all(got.grad[~keep] == 0), f"gradient of field {index} outside keep"
