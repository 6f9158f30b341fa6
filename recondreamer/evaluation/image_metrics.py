"""PSNR and SSIM against the true novel views, over the whole image or inside a mask.

SSIM is kornia's (11x11 Gaussian window, sigma 1.5, 'same' padding), computed on [0,1] RGB and
averaged over channels; the masked SSIM averages the SSIM map over the masked pixels. The
masked PSNR uses the mean squared error over the masked pixels (all three channels).
"""

from __future__ import annotations

import numpy as np

SSIM_WINDOW = 11


def _to_unit(image: np.ndarray) -> np.ndarray:  # (H,W,3) integer 0-255 | float [0,1] -> float64 [0,1]
    image = np.asarray(image)
    return image.astype(np.float64) / 255.0 if np.issubdtype(image.dtype, np.integer) else image.astype(np.float64)


def _check_pair(render: np.ndarray, truth: np.ndarray) -> None:
    if render.shape != truth.shape:
        raise ValueError(f"render {render.shape} and truth {truth.shape} differ in size")


def psnr(render: np.ndarray, truth: np.ndarray, mask: np.ndarray | None = None) -> float | None:
    """PSNR in dB of (H,W,3) images; inside ``mask`` (H,W) bool when given (None if it is empty).

    Identical images give +inf, reported as such rather than capped.
    """
    _check_pair(render, truth)
    squared = (_to_unit(render) - _to_unit(truth)) ** 2  # (H,W,3)
    if mask is not None:
        mask = np.asarray(mask, bool)
        if not mask.any():
            return None
        squared = squared[mask]
    return psnr_from_mse(float(squared.mean()))


def psnr_from_mse(mse: float) -> float:
    """PSNR in dB of a mean squared error of [0,1] images; +inf for 0."""
    return float("inf") if mse == 0.0 else float(-10.0 * np.log10(mse))


def ssim_map(render: np.ndarray, truth: np.ndarray) -> np.ndarray:  # (H,W,3) x2 -> (H,W)
    """Per-pixel SSIM averaged over the colour channels."""
    import kornia
    import torch

    _check_pair(render, truth)
    a = torch.from_numpy(_to_unit(render)).permute(2, 0, 1)[None]  # (1,3,H,W)
    b = torch.from_numpy(_to_unit(truth)).permute(2, 0, 1)[None]
    return kornia.metrics.ssim(a, b, SSIM_WINDOW, max_val=1.0)[0].mean(0).numpy()


def ssim(render: np.ndarray, truth: np.ndarray, mask: np.ndarray | None = None) -> float | None:
    """Mean SSIM over the image, or over ``mask`` (H,W) bool (None if it is empty)."""
    values = ssim_map(render, truth)
    if mask is None:
        return float(values.mean())
    mask = np.asarray(mask, bool)
    return float(values[mask].mean()) if mask.any() else None
