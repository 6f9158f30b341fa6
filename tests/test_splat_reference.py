"""The pure-torch reference rasterizer against hand computations and independent estimates."""

from __future__ import annotations

import math

import pytest
import torch
from op_tester import BaseTester

from recondreamer.splat import RasterizeInputError, rasterize
from recondreamer.splat.projection import LOW_PASS, project_gaussians
from recondreamer.splat.reference import composite_reference
from recondreamer.splat.sh import sh_basis

WIDTH, HEIGHT = 32, 24


def camera(dtype=torch.float32):
    K = torch.tensor([[30.0, 0.0, 16.0], [0.0, 30.0, 12.0], [0.0, 0.0, 1.0]], dtype=dtype)
    return torch.eye(4, dtype=dtype), K


def facing_gaussians(centres, sigmas, opacities, colors, dtype=torch.float32):
    """Isotropic Gaussians with identity rotation; centres (N,3) in camera = world frame."""
    n = len(centres)
    return {
        "means": torch.tensor(centres, dtype=dtype),
        "quats": torch.tensor([[1.0, 0.0, 0.0, 0.0]] * n, dtype=dtype),
        "scales": torch.tensor([[s, s, s] for s in sigmas], dtype=dtype),
        "opacities": torch.tensor(opacities, dtype=dtype),
        "colors": torch.tensor(colors, dtype=dtype),
    }


def good_inputs():
    viewmat, K = camera()
    return {
        "means": torch.zeros(2, 3) + torch.tensor([0.0, 0.0, 3.0]),
        "quats": torch.tensor([[1.0, 0, 0, 0]] * 2),
        "scales": torch.full((2, 3), 0.1),
        "opacities": torch.full((2,), 0.5),
        "colors": torch.rand(2, 3),
        "viewmat": viewmat,
        "K": K,
        "width": WIDTH,
        "height": HEIGHT,
        "background": None,
        "backend": "torch",
    }


BAD_INPUTS = [
    ("means", torch.zeros(2, 2)),
    ("means", torch.zeros(2, 3, dtype=torch.int64)),
    ("means", torch.tensor([[0.0, 0.0, float("nan")]] * 2)),
    ("quats", torch.zeros(3, 4)),
    ("quats", torch.zeros(2, 4)),
    ("quats", torch.ones(2, 4, dtype=torch.float64)),
    ("scales", torch.full((2, 3), -0.1)),
    ("scales", torch.full((2, 3), float("inf"))),
    ("opacities", torch.full((2, 1), 0.5)),
    ("opacities", torch.full((2,), 1.5)),
    ("colors", torch.rand(2, 4)),
    ("colors", torch.rand(2, 5, 3)),
    ("colors", [[0.0, 0.0, 0.0]] * 2),
    ("viewmat", torch.eye(3)),
    ("viewmat", torch.zeros(4, 4)),
    ("K", torch.eye(4)),
    ("K", torch.tensor([[30.0, 1.0, 16.0], [0.0, 30.0, 12.0], [0.0, 0.0, 1.0]])),
    ("K", torch.tensor([[-30.0, 0.0, 16.0], [0.0, 30.0, 12.0], [0.0, 0.0, 1.0]])),
    ("width", 0),
    ("width", 32.0),
    ("height", -4),
    ("background", torch.zeros(4)),
    ("background", torch.tensor([0.0, float("nan"), 0.0])),
    ("backend", "opengl"),
]



class TestRasterizeReference(BaseTester):
    """``rasterize(backend="torch")``: closed forms, compositing rules, gradients, input checks."""

    def test_correctness_single_gaussian_closed_form(self):
        viewmat, K = camera(torch.float64)
        # On the optical axis the EWA Jacobian is diag(f/z): the splat is isotropic.
        K[0, 2], K[1, 2] = 15.3, 11.6
        g = facing_gaussians([[0.0, 0.0, 4.0]], [0.2], [0.8], [[0.9, 0.4, 0.1]], torch.float64)
        out = rasterize(**g, viewmat=viewmat, K=K, width=WIDTH, height=HEIGHT, backend="torch")
        u, v = 15.3, 11.6
        variance = (30 * 0.2 / 4) ** 2 + LOW_PASS
        ys, xs = torch.meshgrid(
            torch.arange(HEIGHT, dtype=torch.float64) + 0.5,
            torch.arange(WIDTH, dtype=torch.float64) + 0.5,
            indexing="ij",
        )
        alpha = 0.8 * torch.exp(-0.5 * ((xs - u) ** 2 + (ys - v) ** 2) / variance)
        alpha = torch.where(alpha >= 1 / 255, alpha, torch.zeros_like(alpha))
        self.assert_close(out["alpha"], alpha)
        self.assert_close(out["rgb"], alpha[..., None] * torch.tensor([0.9, 0.4, 0.1], dtype=torch.float64))
        hit = alpha > 0
        self.assert_close(out["depth"][hit], torch.full_like(alpha[hit], 4.0))
        assert torch.all(out["depth"][~hit] == 0)
        assert out["radii"].tolist() == [math.ceil(3 * math.sqrt(variance))]
        self.assert_close(out["means2d"], torch.tensor([[u, v]], dtype=torch.float64))

    def test_correctness_depth_order_and_early_stop_rule(self):
        # Three wide Gaussians on the optical axis: alphas at the centre pixel 0.99, 0.5, 0.99.
        # After two, T = 0.005; the third would leave T = 5e-5 <= 1e-4, so it is not composited.
        viewmat, K = camera(torch.float64)
        centres = [[0.0, 0.0, 9.0], [0.0, 0.0, 3.0], [0.0, 0.0, 6.0]]  # given out of depth order
        colors = [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
        g = facing_gaussians(centres, [3.0, 1.0, 2.0], [1.0, 1.0, 0.5], colors, torch.float64)
        K_centred = K.clone()
        K_centred[0, 2], K_centred[1, 2] = 16.5, 12.5  # pixel (16, 12) centre on the axis
        out = rasterize(**g, viewmat=viewmat, K=K_centred, width=WIDTH, height=HEIGHT, backend="torch")
        rgb = out["rgb"][12, 16]
        self.assert_close(rgb, torch.tensor([0.99, 0.01 * 0.5, 0.0], dtype=torch.float64))
        self.assert_close(out["alpha"][12, 16], torch.tensor(0.995, dtype=torch.float64))
        expected_depth = (0.99 * 3.0 + 0.005 * 6.0) / 0.995
        self.assert_close(out["depth"][12, 16], torch.tensor(expected_depth, dtype=torch.float64))

    def test_correctness_background_fills_transmittance(self):
        viewmat, K = camera()
        g = facing_gaussians([[0.0, 0.0, 4.0]], [0.2], [0.7], [[0.2, 0.3, 0.4]])
        background = torch.tensor([0.1, 0.5, 1.0])
        plain = rasterize(**g, viewmat=viewmat, K=K, width=WIDTH, height=HEIGHT, backend="torch")
        filled = rasterize(
            **g, viewmat=viewmat, K=K, width=WIDTH, height=HEIGHT, background=background, backend="torch"
        )
        self.assert_close(filled["rgb"], plain["rgb"] + (1 - plain["alpha"])[..., None] * background)

    def test_correctness_sh_degree_zero_equals_rgb(self):
        torch.manual_seed(1)
        viewmat, K = camera()
        means = torch.randn(20, 3) + torch.tensor([0.0, 0.0, 5.0])
        quats, scales, opacities = torch.randn(20, 4), torch.rand(20, 3) * 0.3, torch.rand(20)
        rgb = torch.rand(20, 3)
        sh = ((rgb - 0.5) / 0.28209479177387814)[:, None, :]
        a = rasterize(means, quats, scales, opacities, rgb, viewmat, K, WIDTH, HEIGHT, backend="torch")
        b = rasterize(means, quats, scales, opacities, sh, viewmat, K, WIDTH, HEIGHT, backend="torch")
        self.assert_close(b["rgb"], a["rgb"])

    def test_gradcheck(self):
        torch.manual_seed(3)
        dtype = torch.float64
        viewmat, K = camera(dtype)
        K = K * torch.tensor([[0.3], [0.3], [1.0]], dtype=dtype)  # 10x8 image
        means = torch.randn(4, 3, dtype=dtype) * 0.5 + torch.tensor([0.0, 0.0, 4.0], dtype=dtype)
        quats = torch.randn(4, 4, dtype=dtype)
        scales = torch.rand(4, 3, dtype=dtype) * 0.3 + 0.1
        opacities = torch.rand(4, dtype=dtype) * 0.5 + 0.3
        colors = torch.randn(4, 4, 3, dtype=dtype).mul(0.3)  # SH degree 1
        background = torch.rand(3, dtype=dtype)

        def render(means, quats, scales, opacities, colors, background):
            out = rasterize(means, quats, scales, opacities, colors, viewmat, K, 10, 8, background, backend="torch")
            return out["rgb"], out["depth"], out["alpha"]

        self.gradcheck(render, (means, quats, scales, opacities, colors, background))

    @pytest.mark.parametrize("name,value", BAD_INPUTS)
    def test_exception_names_the_argument(self, name, value):
        inputs = good_inputs()
        inputs[name] = value
        with pytest.raises(ValueError, match=name):
            rasterize(**inputs)

    def test_exception_meta_device_before_any_work(self):
        inputs = good_inputs()
        inputs["colors"] = torch.rand(2, 3, device="meta")
        with pytest.raises(RasterizeInputError, match="colors"):
            rasterize(**inputs)

    def test_cardinality_behind_camera_and_empty_scenes_render_nothing(self):
        viewmat, K = camera()
        g = facing_gaussians([[0.0, 0.0, -3.0], [0.0, 0.0, 0.005]], [0.5, 0.5], [1.0, 1.0], [[1.0, 1.0, 1.0]] * 2)
        out = rasterize(**g, viewmat=viewmat, K=K, width=WIDTH, height=HEIGHT, backend="torch")
        assert torch.all(out["alpha"] == 0) and torch.all(out["rgb"] == 0)
        assert out["radii"].tolist() == [0, 0] and out["visible"].tolist() == [False, False]
        empty = {k: v[:0] for k, v in g.items()}
        out = rasterize(**empty, viewmat=viewmat, K=K, width=WIDTH, height=HEIGHT, backend="torch")
        assert out["rgb"].shape == (HEIGHT, WIDTH, 3) and torch.all(out["alpha"] == 0)
        assert out["means2d"].shape == (0, 2)


class TestProjectGaussians(BaseTester):
    """``project_gaussians``: the EWA splat against the projection of samples of the 3D Gaussian."""

    def test_correctness_projected_covariance_matches_projected_samples(self):
        torch.manual_seed(0)
        viewmat, K = camera(torch.float64)
        angle = 0.4
        viewmat[:3, :3] = torch.tensor(
            [[math.cos(angle), 0, math.sin(angle)], [0, 1, 0], [-math.sin(angle), 0, math.cos(angle)]],
            dtype=torch.float64,
        )
        mean = torch.tensor([[-1.0, 0.3, 5.0]], dtype=torch.float64)
        quat = torch.tensor([[0.9, 0.2, -0.3, 0.1]], dtype=torch.float64)
        scale = torch.tensor([[0.05, 0.02, 0.08]], dtype=torch.float64)
        projected = project_gaussians(mean, quat, scale, viewmat, K, WIDTH, HEIGHT)
        # Sample the 3D Gaussian, project every sample exactly, measure the 2D covariance.
        from recondreamer.splat.projection import quats_to_rotmats

        samples = mean + (torch.randn(200_000, 3, dtype=torch.float64) * scale) @ quats_to_rotmats(quat)[0].T
        cam = samples @ viewmat[:3, :3].T + viewmat[:3, 3]
        uv = torch.stack([30 * cam[:, 0] / cam[:, 2] + 16, 30 * cam[:, 1] / cam[:, 2] + 12], dim=-1)
        empirical = torch.cov(uv.T) + LOW_PASS * torch.eye(2, dtype=torch.float64)
        a, b, c = projected.conics[0]
        conic = torch.stack([torch.stack([a, b]), torch.stack([b, c])])
        # Sampling error of 200k samples and the first-order (EWA) projection, not rounding.
        torch.testing.assert_close(torch.linalg.inv(conic), empirical, rtol=0.03, atol=0.01)
        torch.testing.assert_close(projected.means2d[0], uv.mean(0), rtol=0, atol=0.02)


class TestSHBasis(BaseTester):
    """``sh_basis``: real spherical harmonics up to degree 3."""

    def test_correctness_orthonormal_on_the_sphere(self):
        n = 40_000  # Fibonacci sphere: near-uniform directions
        i = torch.arange(n, dtype=torch.float64) + 0.5
        z = 1 - 2 * i / n
        phi = math.pi * (1 + 5**0.5) * i
        r = torch.sqrt(1 - z * z)
        directions = torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], dim=-1)
        basis = sh_basis(directions, 16)  # (n,16)
        gram = 4 * math.pi * basis.T @ basis / n
        # Quadrature error of the Fibonacci sphere, not rounding.
        torch.testing.assert_close(gram, torch.eye(16, dtype=torch.float64), rtol=0, atol=2e-3)


class TestCompositeReference(BaseTester):
    """``composite_reference``: the block cull against every pixel seeing every splat."""

    def test_correctness_block_cull_is_exact(self):
        torch.manual_seed(2)
        n = 300
        means2d = torch.rand(n, 2, dtype=torch.float64) * torch.tensor([WIDTH + 20.0, HEIGHT + 20.0]) - 10
        conic_l = torch.randn(n, 2, 2, dtype=torch.float64) * 0.5
        cov = conic_l @ conic_l.transpose(1, 2) * 4 + 0.3 * torch.eye(2, dtype=torch.float64)
        inv = torch.linalg.inv(cov)
        conics = torch.stack([inv[:, 0, 0], inv[:, 0, 1], inv[:, 1, 1]], dim=-1)
        colors, opacities, depths = (
            torch.rand(n, 3, dtype=torch.float64),
            torch.rand(n, dtype=torch.float64),
            torch.rand(n, dtype=torch.float64),
        )
        inputs = [t.requires_grad_() for t in (means2d, conics, colors, opacities, depths)]
        weights = torch.randn(HEIGHT, WIDTH, 5, dtype=torch.float64)
        results = []
        for block_size in (0, 8):  # 0: every pixel sees every splat
            for t in inputs:
                t.grad = None
            rgb, depth, alpha = composite_reference(*inputs, WIDTH, HEIGHT, block_size=block_size)
            loss = (rgb * weights[..., :3]).sum() + (depth * weights[..., 3]).sum() + (alpha * weights[..., 4]).sum()
            loss.backward()
            results.append([rgb, depth, alpha] + [t.grad.clone() for t in inputs])
        # The cull skips only splats that contribute nothing to a block: equal up to the rounding of O(1) sums.
        for full, blocks in zip(*results):
            torch.testing.assert_close(full, blocks, rtol=0, atol=1e-12)
