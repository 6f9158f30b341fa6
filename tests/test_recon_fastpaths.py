"""Fast paths of the reconstruction trainer against their reference twins.

SSIM with cached target statistics and an analytic gradient against kornia's SSIM under
autograd; cached per-view targets against converting the view afresh.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from op_tester import BaseTester

from recondreamer.recon.data import TargetCache, TrainingView, downsample_targets
from recondreamer.recon.losses import image_tensor, ssim_loss
from recondreamer.recon.sky import pixel_ray_directions
from recondreamer.recon.ssim import SSIMTarget, mean_ssim, reflect_blur_matrix
from recondreamer.scene.cameras import rasterizer_intrinsics

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def image_pair(height: int, width: int, dtype=torch.float32, seed: int = 0):
    generator = torch.Generator().manual_seed(seed)
    target = torch.rand(height, width, 3, generator=generator, dtype=dtype)
    noise = 0.15 * torch.randn(height, width, 3, generator=generator, dtype=dtype)
    return (target + noise).clamp(0, 1), target


class TestReflectBlurMatrix(BaseTester):
    """``reflect_blur_matrix``: a separable Gaussian blur with reflect padding as a matrix product."""

    def test_correctness(self):
        from kornia.filters import filter2d_separable, get_gaussian_kernel1d

        signal = torch.rand(2, 3, 17, 23, dtype=torch.float64)
        kernel = get_gaussian_kernel1d(11, 1.5, dtype=torch.float64)
        expected = filter2d_separable(signal, kernel, kernel, border_type="reflect")
        rows = reflect_blur_matrix(17, 11, dtype=torch.float64)
        cols = reflect_blur_matrix(23, 11, dtype=torch.float64)
        self.assert_close(rows @ signal @ cols.T, expected)
        # Rows sum to one (a weighted mean), and the matrix is not symmetric at the borders.
        self.assert_close(rows.sum(1), torch.ones(17, dtype=torch.float64))
        assert not torch.allclose(rows, rows.T)

    def test_exception(self):
        with pytest.raises(ValueError, match="larger than 5"):
            reflect_blur_matrix(5, 11)


class TestMeanSSIM(BaseTester):
    """``mean_ssim`` with cached target statistics and its analytic gradient, against kornia's SSIM
    under autograd (``ssim_loss``). Gradients of a mean over n values are O(1/n): they are compared
    multiplied by n, at the order-one size op_tester's tolerances assume."""

    @staticmethod
    def reference(pred, target):
        """kornia's SSIM loss at ``pred`` and its gradient."""
        pred = pred.clone().requires_grad_(True)
        loss = ssim_loss(pred, target, 11)
        loss.backward()
        return loss.detach(), pred.grad

    @pytest.mark.parametrize("size", [(40, 56), (23, 31)])
    def test_correctness(self, size):
        pred, target = image_pair(*size, dtype=torch.float64)
        loss_ref, grad_ref = self.reference(pred, target)
        fast = pred.clone().requires_grad_(True)
        loss_fast = 1.0 - mean_ssim(fast, SSIMTarget.from_image(target, 11))
        loss_fast.backward()
        assert 0.05 < loss_ref.item() < 0.95  # a pair that is neither equal nor unrelated
        self.assert_close(loss_fast.detach(), loss_ref)
        self.assert_close(fast.grad * pred.numel(), grad_ref * pred.numel())

    @pytest.mark.parametrize("size", [(40, 56), (23, 31)])
    def test_dtype_float32(self, size):
        # float32, as in training: the float64 reference's value and gradient to float rounding.
        pred, target = image_pair(*size, dtype=torch.float64)
        loss_ref, grad_ref = self.reference(pred, target)
        pred32, target32 = pred.float().requires_grad_(True), target.float()
        value32 = mean_ssim(pred32, SSIMTarget.from_image(target32, 11))
        value32.backward()
        self.assert_close(1.0 - value32.detach(), loss_ref.float())
        # Each gradient entry gathers window sums in which E[x^2] - E[x]^2 cancels: low tolerance.
        self.assert_close(pred32.grad * pred.numel(), (-grad_ref * pred.numel()).float(), low_tolerance=True)

    def test_gradcheck(self):
        pred, target = image_pair(13, 15, dtype=torch.float64, seed=3)
        cached = SSIMTarget.from_image(target, 7)
        self.gradcheck(lambda x: mean_ssim(x, cached), pred)

    def test_correctness_identical_images(self):
        _, target = image_pair(13, 15, dtype=torch.float64, seed=3)
        same = mean_ssim(target, SSIMTarget.from_image(target, 11))
        self.assert_close(same, torch.tensor(1.0, dtype=torch.float64))


def make_view(seed: int, height: int = 16, width: int = 24, depth: bool = True):
    rng = np.random.default_rng(seed)
    cam_to_world = np.eye(4)
    cam_to_world[:3, 3] = rng.normal(size=3)
    return TrainingView(
        cam_to_world=cam_to_world,
        timestamp=0.1 * seed,
        image=rng.integers(0, 256, (height, width, 3), dtype=np.uint8),
        depth=rng.uniform(0, 20, (height, width)).astype(np.float32) if depth else None,
        sky_mask=rng.random((height, width)) > 0.7,
    )


class TestTargetCache(BaseTester):
    """``TargetCache``: per-view training targets converted once and kept within a byte budget."""

    def test_correctness_matches_fresh_conversion_and_reuses_entries(self):
        K = np.array([[20.0, 0, 11.5], [0, 20.0, 7.5], [0, 0, 1]])
        view = make_view(1)
        cache = TargetCache(ssim_window=11)
        full, coarse = cache.get(view, K, 1), cache.get(view, K, 2)
        image = image_tensor(view.image)
        assert torch.equal(full.image.image, image)
        assert torch.equal(full.depth, torch.from_numpy(view.depth))
        assert torch.equal(full.sky_mask, torch.from_numpy(view.sky_mask))
        small, small_depth, small_sky, small_K = downsample_targets(
            image, view.depth, view.sky_mask, K, 2
        )
        assert torch.equal(coarse.image.image, small) and coarse.image.image.shape == (
            8,
            12,
            3,
        )
        assert torch.equal(coarse.depth, torch.from_numpy(small_depth))
        assert torch.equal(coarse.sky_mask, torch.from_numpy(small_sky))
        self.assert_close(coarse.K, small_K)
        directions = pixel_ray_directions(
            torch.tensor(view.cam_to_world, dtype=torch.float32),
            rasterizer_intrinsics(torch.tensor(small_K, dtype=torch.float32)),
            12,
            8,
        )
        assert torch.equal(coarse.ray_directions, directions)
        assert cache.get(view, K, 1) is full  # drawn again: the same tensors
        free = cache.get(make_view(2, depth=False), K, 1)
        assert free.depth is None  # depth-free views stay depth-free

    def test_evicts_least_recently_used_beyond_its_budget(self):
        K = np.array([[20.0, 0, 11.5], [0, 20.0, 7.5], [0, 0, 1]])
        views = [make_view(seed) for seed in range(3)]
        one_entry = TargetCache(ssim_window=11).get(views[0], K).nbytes()
        cache = TargetCache(ssim_window=11, max_bytes=2 * one_entry)
        first = cache.get(views[0], K)
        cache.get(views[1], K)
        cache.get(views[0], K)  # views[1] is now the least recently used
        cache.get(views[2], K)
        assert len(cache.entries) == 2 and cache.bytes <= 2 * one_entry
        assert cache.get(views[0], K) is first
        assert (id(views[1]), 1) not in cache.entries
