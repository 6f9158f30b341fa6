"""Fast paths of the reconstruction trainer against their reference twins.

SSIM with cached target statistics and an analytic gradient against kornia's SSIM under
autograd; cached per-view targets against converting the view afresh.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

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


def test_blur_matrix_matches_reflect_padded_convolution():
    from kornia.filters import filter2d_separable, get_gaussian_kernel1d

    signal = torch.rand(2, 3, 17, 23, dtype=torch.float64)
    kernel = get_gaussian_kernel1d(11, 1.5, dtype=torch.float64)
    expected = filter2d_separable(signal, kernel, kernel, border_type="reflect")
    rows = reflect_blur_matrix(17, 11, dtype=torch.float64)
    cols = reflect_blur_matrix(23, 11, dtype=torch.float64)
    assert torch.allclose(rows @ signal @ cols.T, expected, atol=1e-12)
    # Rows sum to one (a weighted mean), and the matrix is not symmetric at the borders.
    assert torch.allclose(rows.sum(1), torch.ones(17, dtype=torch.float64))
    assert not torch.allclose(rows, rows.T)
    with pytest.raises(ValueError, match="larger than 5"):
        reflect_blur_matrix(5, 11)


@pytest.mark.parametrize("size", [(40, 56), (23, 31)])
def test_fast_ssim_matches_kornia_value_and_gradient(size):
    pred, target = image_pair(*size, dtype=torch.float64)
    reference = pred.clone().requires_grad_(True)
    fast = pred.clone().requires_grad_(True)
    loss_ref = ssim_loss(reference, target, 11)
    loss_ref.backward()
    loss_fast = 1.0 - mean_ssim(fast, SSIMTarget.from_image(target, 11))
    loss_fast.backward()
    assert 0.05 < loss_ref.item() < 0.95  # a pair that is neither equal nor unrelated
    assert torch.allclose(loss_fast, loss_ref, atol=1e-12)
    assert torch.allclose(fast.grad, reference.grad, rtol=1e-8, atol=1e-14)
    # float32, as in training: same value and gradient to float rounding.
    pred32, target32 = pred.float().requires_grad_(True), target.float()
    value32 = mean_ssim(pred32, SSIMTarget.from_image(target32, 11))
    value32.backward()
    assert abs((1.0 - value32).item() - loss_ref.item()) < 1e-5
    assert torch.allclose(pred32.grad.double(), -reference.grad, atol=1e-7)


def test_fast_ssim_gradcheck_and_identity():
    pred, target = image_pair(13, 15, dtype=torch.float64, seed=3)
    cached = SSIMTarget.from_image(target, 7)
    pred.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: mean_ssim(x, cached), (pred,))
    same = mean_ssim(target, SSIMTarget.from_image(target, 11))
    assert abs(float(same) - 1.0) < 1e-6


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


def test_target_cache_matches_fresh_conversion_and_reuses_entries():
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
    assert np.allclose(coarse.K, small_K)
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


def test_target_cache_evicts_least_recently_used_beyond_its_budget():
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
