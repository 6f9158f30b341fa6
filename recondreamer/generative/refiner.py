"""Pixel refiner: an optional last stage of DriveRestorer that works at full frame resolution.

The diffusion restorer works on latents four times smaller than the frames, and its output
reaches pixels through the frozen decoder (with residual decoding, as a decoded change added to
the render). Most of what a render gets wrong sits on edges (experiments/pairs_error.py), i.e.
at the scale the latents blur. The refiner is a small per-frame convolutional network that sees
the restorer's output, the degraded render and the structure maps at full resolution and
predicts a correction to the restorer's output; with ``temporal_neighbours`` it also sees the
restored and degraded frames just before and after, whose renders show the same surfaces from
nearby viewpoints with different artifacts. It plays the part of StableSR's controllable
feature wrapping (a decoder stage fine-tuned on the diffusion model's outputs with features of the
degraded input), written as a separate network in pixel space so the autoencoder stays untouched.

It is trained after the restorer, on the restorer's own outputs for its training pairs
(``training.train_refiner``), and its last conv is zero-initialised: a fresh refiner returns the
restorer's output unchanged (tested), so it can only start from what the restorer gives.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from recondreamer.generative.autoencoder import PlainResBlock, frames_to_tensor, tensor_to_frames
from recondreamer.generative.config import RefinerConfig
from recondreamer.device import module_device


class PixelChannelNorm(nn.Module):
    """Layer norm over the channels of each pixel, without learned scale or shift.

    Unlike group norm it uses no spatial statistics, so a refiner trained on crops computes the
    same on whole frames. Before the refiner's last SiLU it keeps the features at unit scale:
    without it (``RefinerConfig.output_norm`` False) a refiner could drift into SiLU's flat
    part, where its correction and every gradient vanish (a refiner trained without it ended with
    features around -1000 there and returned its input unchanged). It has no learned scale or shift,
    which training could drive there instead.
    """

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # (N,C,H,W) -> (N,C,H,W)
        return F.layer_norm(x.permute(0, 2, 3, 1), (x.shape[1],)).permute(0, 3, 1, 2)


class PixelRefiner(nn.Module):
    """Two-level UNet in pixel space: (restored, degraded, neighbours, structure) -> refined frame.

    Widths ``w``, ``2w``, ``3w`` at full, half and quarter resolution; ``bottleneck_blocks`` residual
    blocks at quarter resolution (the autoencoder's plain residual blocks: no normalisation, since
    the refiner trains on crops and runs on whole frames). Output: restored + correction, in [-1,1]
    pixel units, the correction clipped to ``config.max_correction`` grey levels when that is set.
    """

    def __init__(self, config: RefinerConfig, structure_channels: int):
        super().__init__()
        self.config = config
        self.structure_channels = structure_channels
        w = config.width
        neighbour_channels = 2 * config.temporal_neighbours * 6  # restored and degraded frames on each side
        self.conv_in = nn.Conv2d(6 + neighbour_channels + structure_channels, w, 3, padding=1)
        self.full_in = PlainResBlock(w)
        self.down_half = nn.Conv2d(w, 2 * w, 3, stride=2, padding=1)
        self.half_in = PlainResBlock(2 * w)
        self.down_quarter = nn.Conv2d(2 * w, 3 * w, 3, stride=2, padding=1)
        self.bottleneck = nn.Sequential(*(PlainResBlock(3 * w) for _ in range(config.bottleneck_blocks)))
        self.up_half = nn.Conv2d(3 * w, 2 * w, 3, padding=1)
        self.half_out = PlainResBlock(2 * w)
        self.up_full = nn.Conv2d(2 * w, w, 3, padding=1)
        self.full_out = PlainResBlock(w)
        self.norm_out = PixelChannelNorm() if config.output_norm else nn.Identity()
        self.conv_out = nn.Conv2d(w, 3, 3, padding=1)
        nn.init.zeros_(self.conv_out.weight)  # a fresh refiner returns the restorer's output
        nn.init.zeros_(self.conv_out.bias)

    def forward(
        self,
        restored: torch.Tensor,  # (N,3,H,W) in [-1,1]: the restorer's output
        degraded: torch.Tensor,  # (N,3,H,W) in [-1,1]: the render it restored
        structure: torch.Tensor | None = None,  # (N,S,H,W) in [0,1]
        neighbours: torch.Tensor | None = None,  # (N,2n,6,H,W) in [-1,1]: ``neighbour_stack``, n = temporal_neighbours
    ) -> torch.Tensor:  # (N,3,H,W) in [-1,1] (not clipped)
        self._check_inputs(restored, degraded, structure, neighbours)
        inputs = [restored, degraded]
        if self.config.temporal_neighbours:
            inputs.append(neighbours.flatten(1, 2))
        if self.structure_channels:
            inputs.append(structure)
        full = self.full_in(self.conv_in(torch.cat(inputs, dim=1)))
        half = self.half_in(self.down_half(F.silu(full)))
        quarter = self.bottleneck(self.down_quarter(F.silu(half)))
        half = self.half_out(half + self.up_half(F.interpolate(quarter, size=half.shape[-2:], mode="nearest")))
        full = self.full_out(full + self.up_full(F.interpolate(half, size=full.shape[-2:], mode="nearest")))
        correction = self.conv_out(F.silu(self.norm_out(full)))
        if self.config.max_correction:
            bound = self.config.max_correction / 127.5  # grey levels -> [-1,1] pixel units
            correction = correction.clamp(-bound, bound)
        return restored + correction

    def _check_inputs(self, restored, degraded, structure, neighbours) -> None:
        if restored.dim() != 4 or restored.shape[1] != 3:
            raise ValueError(f"restored frames must be (N,3,H,W), got {tuple(restored.shape)}")
        if degraded.shape != restored.shape:
            raise ValueError(f"degraded frames have shape {tuple(degraded.shape)}, expected {tuple(restored.shape)} like the restored ones")
        if self.structure_channels:
            expected = (restored.shape[0], self.structure_channels, *restored.shape[2:])
            if structure is None or tuple(structure.shape) != expected:
                got = None if structure is None else tuple(structure.shape)
                raise ValueError(f"the refiner needs structure maps of shape {expected}, got {got}")
        if self.config.temporal_neighbours:
            expected = (restored.shape[0], 2 * self.config.temporal_neighbours, 6, *restored.shape[2:])
            if neighbours is None or tuple(neighbours.shape) != expected:
                got = None if neighbours is None else tuple(neighbours.shape)
                raise ValueError(f"the refiner needs neighbour frames of shape {expected} (temporal_neighbours "
                                 f"{self.config.temporal_neighbours}), got {got}")
        elif neighbours is not None:
            raise ValueError("this refiner sees single frames (temporal_neighbours 0) but was given neighbour frames")


def neighbour_frames(frame: int, length: int, count: int) -> list[int]:
    """The ``count`` frames before and after ``frame`` in a clip of ``length`` frames, in order
    (t-count .. t-1, t+1 .. t+count); past the clip's ends its first or last frame stands in."""
    return [min(max(frame + offset, 0), length - 1) for offset in range(-count, count + 1) if offset != 0]


def neighbour_stack(
    restored: np.ndarray,  # (T,H,W,3) uint8: a restored clip
    degraded: np.ndarray,  # (T,H,W,3) uint8: the renders it was restored from
    frame: int,
    count: int,
    rows: slice = slice(None),
    cols: slice = slice(None),
) -> torch.Tensor:  # (2*count,6,h,w) in [-1,1]: restored then degraded channels of each neighbour
    """The refiner's ``neighbours`` input for one frame of a clip (``rows``/``cols``: a crop of it)."""
    indices = neighbour_frames(frame, len(restored), count)
    return torch.cat([frames_to_tensor(restored[indices, rows, cols]), frames_to_tensor(degraded[indices, rows, cols])], dim=1)


@torch.no_grad()
def refine_frames(
    refiner: PixelRefiner,
    restored: np.ndarray,  # (T,H,W,3) uint8
    degraded: np.ndarray,  # (T,H,W,3) uint8
    structure: torch.Tensor | None,  # (T,S,H,W) float in [0,1], or None for a refiner without structure
    batch_frames: int = 8,
) -> np.ndarray:  # (T,H,W,3) uint8
    """Refine a restored clip frame by frame (``batch_frames`` at a time, to bound memory; a
    refiner with temporal neighbours sees the clip's frames around each one)."""
    device = module_device(refiner)
    refiner.eval()
    count = refiner.config.temporal_neighbours
    out = []
    for start in range(0, len(restored), batch_frames):
        frames = slice(start, start + batch_frames)
        maps = None if structure is None or not refiner.structure_channels else structure[frames].to(device)
        neighbours = None
        if count:
            neighbours = torch.stack([neighbour_stack(restored, degraded, t, count) for t in range(*frames.indices(len(restored)))]).to(device)
        refined = refiner(frames_to_tensor(restored[frames]).to(device), frames_to_tensor(degraded[frames]).to(device), maps, neighbours)
        out.append(tensor_to_frames(refined))
    return np.concatenate(out)
