"""SSIM of a render against a fixed target, with an analytic gradient: the training-loss fast path.

Same definition as ``kornia.metrics.ssim`` (the reference twin, ``losses.ssim_loss``): an 11x11
Gaussian window of sigma 1.5 applied separably with reflect padding, C1 = 0.01^2, C2 = 0.03^2,
the SSIM map averaged over pixels and channels. Two things make it cheaper per training step:

- the target's local mean and variance are computed once per training view (``SSIMTarget``);
- the render's three moment maps (mean, mean of squares, mean of products with the target) are
  blurred in one batched call, and the backward pass is one batched call of the transposed blur
  plus elementwise terms, instead of autograd through five blurs and the SSIM arithmetic.

The blur along an axis of n samples is the (n,n) matrix that applies the window with reflect
padding, so the transposed blur of the backward pass is a matrix transpose.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import torch

SSIM_SIGMA = 1.5  # Gaussian window of kornia.metrics.ssim (Wang et al. 2004)
SSIM_C1 = 0.01**2  # stabilisers for a dynamic range of 1
SSIM_C2 = 0.03**2
SSIM_EPS = 1e-12  # kornia adds it to the denominator


@functools.lru_cache(maxsize=32)
def reflect_blur_matrix(
    size: int, window: int, device: str = "cpu", dtype: torch.dtype = torch.float32
) -> torch.Tensor:
    """(size,size) matrix M with ``M @ signal`` = the signal blurred by the Gaussian window with
    reflect padding (kornia's ``filter2d_separable`` along one axis)."""
    from kornia.filters import get_gaussian_kernel1d

    radius = window // 2
    if size <= radius:
        raise ValueError(
            f"SSIM needs images larger than {radius} pixels per side, got {size}"
        )
    # (window,)
    kernel = get_gaussian_kernel1d(window, SSIM_SIGMA, dtype=torch.float64)[0]
    rows = torch.arange(size)
    matrix = torch.zeros(size, size, dtype=torch.float64)
    for tap in range(window):
        source = rows + tap - radius
        # Reflect without repeating the edge sample, as torch's "reflect" padding does.
        source = torch.where(source < 0, -source, source)
        source = torch.where(source >= size, 2 * (size - 1) - source, source)
        matrix.index_put_((rows, source), kernel[tap].expand(size), accumulate=True)
    return matrix.to(device=device, dtype=dtype)


def blur(maps: torch.Tensor, window: int) -> torch.Tensor:  # (C,H,W) -> (C,H,W)
    rows = reflect_blur_matrix(maps.shape[1], window, str(maps.device), maps.dtype)
    cols = reflect_blur_matrix(maps.shape[2], window, str(maps.device), maps.dtype)
    return rows @ maps @ cols.T


# (C,H,W) -> (C,H,W): the adjoint of ``blur``, for the backward pass
def blur_transposed(maps: torch.Tensor, window: int) -> torch.Tensor:
    rows = reflect_blur_matrix(maps.shape[1], window, str(maps.device), maps.dtype)
    cols = reflect_blur_matrix(maps.shape[2], window, str(maps.device), maps.dtype)
    return rows.T @ maps @ cols


@dataclass
class SSIMTarget:
    """A target image and its local statistics: computed once, reused every step it is drawn."""

    image: torch.Tensor  # (H,W,3) in [0,1]
    channels: torch.Tensor  # (3,H,W) the same image, channels first
    mean: torch.Tensor  # (3,H,W) blurred image
    variance: torch.Tensor  # (3,H,W) blurred square minus squared mean
    window: int

    @classmethod
    def from_image(cls, image: torch.Tensor, window: int) -> SSIMTarget:
        """``image`` (H,W,3) in [0,1]."""
        image = image.detach()
        channels = image.permute(2, 0, 1).contiguous()  # (3,H,W)
        moments = blur(torch.cat((channels, channels * channels)), window)  # (6,H,W)
        mean, mean_square = moments[:3], moments[3:]
        return cls(image, channels, mean, mean_square - mean * mean, window)


class _MeanSSIM(torch.autograd.Function):
    """Mean SSIM of ``pred`` (3,H,W) against a fixed target; gradient with respect to ``pred``."""

    @staticmethod
    def forward(ctx, pred: torch.Tensor, target: SSIMTarget) -> torch.Tensor:
        y, mu_y, var_y = target.channels, target.mean, target.variance
        moments = blur(
            torch.cat((pred, pred * pred, pred * y)), target.window
        )  # (9,H,W)
        mu_x, mean_xx, mean_xy = moments[:3], moments[3:6], moments[6:]
        a1 = 2 * mu_x * mu_y + SSIM_C1
        a2 = 2 * (mean_xy - mu_x * mu_y) + SSIM_C2
        b1 = mu_x * mu_x + mu_y * mu_y + SSIM_C1
        b2 = (mean_xx - mu_x * mu_x) + var_y + SSIM_C2
        denominator = b1 * b2 + SSIM_EPS
        ssim_map = a1 * a2 / denominator  # (3,H,W)
        ctx.save_for_backward(pred, mu_x, a1, a2, b1, b2, denominator, ssim_map)
        ctx.target = target
        return ssim_map.mean()

    @staticmethod
    def backward(ctx, grad_output: torch.Tensor):
        pred, mu_x, a1, a2, b1, b2, denominator, ssim_map = ctx.saved_tensors
        target = ctx.target
        y, mu_y = target.channels, target.mean
        scale = grad_output / ssim_map.numel()
        # d ssim_map / d (mu_x, mean_xx, mean_xy), per pixel, from the four factors above.
        d_mu = (2 * mu_y * (a2 - a1) + 2 * mu_x * ssim_map * (b1 - b2)) / denominator
        d_xx = -ssim_map * b1 / denominator
        d_xy = 2 * a1 / denominator
        back = blur_transposed(scale * torch.cat((d_mu, d_xx, d_xy)), target.window)
        grad_pred = back[:3] + 2 * pred * back[3:6] + y * back[6:]
        return grad_pred, None


def mean_ssim(pred: torch.Tensor, target: SSIMTarget) -> torch.Tensor:
    """Mean SSIM (scalar) of ``pred`` (H,W,3) in [0,1] against ``target``; differentiable in ``pred``."""
    return _MeanSSIM.apply(pred.permute(2, 0, 1), target)
