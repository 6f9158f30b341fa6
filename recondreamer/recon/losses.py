"""Reconstruction losses: L1 RGB + SSIM + LiDAR depth + sky opacity.

``view_loss`` is the per-view objective of the paper: ``l1 RGB + l2 Depth + l3 SSIM`` for
original data, and depth-free for views without depth (generated novel-trajectory frames).
Training computes SSIM with ``ssim.mean_ssim`` (target statistics precomputed, analytic
gradient); ``ssim_loss`` here is its reference twin, kornia's SSIM under autograd.
"""

from __future__ import annotations

import kornia
import numpy as np
import torch
import torch.nn.functional as F

from recondreamer.recon.config import LossConfig
from recondreamer.recon.ssim import SSIMTarget, mean_ssim


def image_tensor(
    image,
) -> torch.Tensor:  # (H,W,3) uint8 array -> (H,W,3) float in [0,1]
    return torch.from_numpy(np.array(image, dtype=np.float32)) / 255.0


def ssim_loss(pred: torch.Tensor, target: torch.Tensor, window: int) -> torch.Tensor:
    """1 - mean SSIM of two (H,W,3) images in [0,1], by kornia (reference of ``mean_ssim``)."""
    ssim = kornia.metrics.ssim(
        pred.permute(2, 0, 1)[None], target.permute(2, 0, 1)[None], window
    )
    return 1.0 - ssim.mean()


def depth_loss(
    pred: torch.Tensor, alpha: torch.Tensor, target: torch.Tensor, min_alpha: float
) -> torch.Tensor | None:
    """Mean relative L1 |d - d_lidar| / d_lidar over pixels with a LiDAR point and alpha >= min_alpha.

    ``pred`` is the rendered expected depth (H,W); relative error keeps near and far points
    comparable. None when no pixel qualifies.
    """
    mask = (target > 0) & (alpha.detach() >= min_alpha)
    if not bool(mask.any()):
        return None
    return ((pred[mask] - target[mask]).abs() / target[mask]).mean()


def sky_loss(alpha: torch.Tensor, sky_mask: torch.Tensor) -> torch.Tensor:
    """BCE of the accumulated opacity against "not sky": Gaussians must not cover the sky."""
    return F.binary_cross_entropy(alpha.clamp(1e-5, 1 - 1e-5), (~sky_mask).float())


def view_loss(
    render: dict, image: torch.Tensor | SSIMTarget, depth, sky_mask, config: LossConfig
) -> tuple[torch.Tensor, dict[str, float]]:
    """Total loss of one rendered view and its parts (floats, for logging).

    ``image`` (H,W,3) float, or its ``SSIMTarget`` (the trainer passes cached ones, whose
    window is ``config.ssim_window``); ``depth`` (H,W) float array/tensor or None (no depth loss
    at all); ``sky_mask`` (H,W) bool array/tensor or None.
    """
    rgb = render["rgb"]
    target = (
        image
        if isinstance(image, SSIMTarget)
        else SSIMTarget.from_image(image, config.ssim_window)
    )
    l1 = (rgb - target.image).abs().mean()
    d_ssim = 1.0 - mean_ssim(rgb, target)
    total = config.rgb * l1 + config.ssim * d_ssim
    parts = {"l1": float(l1.detach()), "ssim": float(d_ssim.detach())}
    if depth is not None and config.depth > 0:
        term = depth_loss(
            render["depth"],
            render["alpha"],
            torch.as_tensor(depth, dtype=torch.float32, device=rgb.device),
            config.depth_min_alpha,
        )
        if term is not None:
            total = total + config.depth * term
            parts["depth"] = float(term.detach())
    if sky_mask is not None and config.sky > 0:
        term = sky_loss(
            render["alpha"],
            torch.as_tensor(sky_mask, dtype=torch.bool, device=rgb.device),
        )
        total = total + config.sky * term
        parts["sky"] = float(term.detach())
    return total, parts
