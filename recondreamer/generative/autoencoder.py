"""The latent autoencoder (the paper's encoder E and its decoder): frames <-> small latents.

A plain deterministic convolutional autoencoder without normalisation layers, so it can be
trained on random crops and applied to whole frames alike. Latents are standardised per channel
(mean/std measured on the training corpus and stored as buffers) so the diffusion models see
roughly unit-variance inputs.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from recondreamer.generative.config import AutoencoderConfig
from recondreamer.device import module_device


class PlainResBlock(nn.Module):
    def __init__(self, channels: int):
        super().__init__()
        self.conv1 = nn.Conv2d(channels, channels, 3, padding=1)
        self.conv2 = nn.Conv2d(channels, channels, 3, padding=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # (N,C,H,W) -> (N,C,H,W)
        return x + self.conv2(F.silu(self.conv1(F.silu(x))))


class Encoder(nn.Module):
    def __init__(self, config: AutoencoderConfig):
        super().__init__()
        hidden = config.hidden_channels
        self.conv_in = nn.Conv2d(3, hidden[0], 3, padding=1)
        self.blocks = nn.ModuleList(PlainResBlock(c) for c in hidden)
        self.downs = nn.ModuleList(nn.Conv2d(hidden[i], hidden[i + 1], 3, stride=2, padding=1) for i in range(len(hidden) - 1))
        self.conv_out = nn.Conv2d(hidden[-1], config.latent_channels, 3, padding=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # (N,3,H,W) in [-1,1] -> (N,c,H/f,W/f)
        h = self.conv_in(x)
        for level, block in enumerate(self.blocks):
            h = block(h)
            if level < len(self.downs):
                h = self.downs[level](h)
        return self.conv_out(F.silu(h))


class Decoder(nn.Module):
    def __init__(self, config: AutoencoderConfig):
        super().__init__()
        hidden = tuple(reversed(config.hidden_channels))
        self.conv_in = nn.Conv2d(config.latent_channels, hidden[0], 3, padding=1)
        self.blocks = nn.ModuleList(PlainResBlock(c) for c in hidden)
        self.ups = nn.ModuleList(nn.Conv2d(hidden[i], hidden[i + 1], 3, padding=1) for i in range(len(hidden) - 1))
        self.conv_out = nn.Conv2d(hidden[-1], 3, 3, padding=1)

    def forward(self, z: torch.Tensor) -> torch.Tensor:  # (N,c,h,w) -> (N,3,h*f,w*f) in about [-1,1]
        h = self.conv_in(z)
        for level, block in enumerate(self.blocks):
            h = block(h)
            if level < len(self.ups):
                h = self.ups[level](F.interpolate(h, scale_factor=2.0, mode="nearest"))
        return self.conv_out(F.silu(h))


class Autoencoder(nn.Module):
    def __init__(self, config: AutoencoderConfig):
        super().__init__()
        self.config = config
        self.encoder = Encoder(config)
        self.decoder = Decoder(config)
        self.register_buffer("latent_mean", torch.zeros(config.latent_channels))
        self.register_buffer("latent_std", torch.ones(config.latent_channels))

    def encode(self, images: torch.Tensor) -> torch.Tensor:  # (N,3,H,W) in [-1,1] -> (N,c,h,w) standardised
        self._check_size(images)
        z = self.encoder(images)
        return (z - self.latent_mean[:, None, None]) / self.latent_std[:, None, None]

    def decode(self, latents: torch.Tensor) -> torch.Tensor:  # (N,c,h,w) standardised -> (N,3,H,W)
        z = latents * self.latent_std[:, None, None] + self.latent_mean[:, None, None]
        return self.decoder(z)

    def forward(self, images: torch.Tensor) -> torch.Tensor:  # (N,3,H,W) -> (N,3,H,W)
        return self.decoder(self.encoder(images))

    @torch.no_grad()
    def set_latent_statistics(self, images: torch.Tensor) -> None:
        """Measure per-channel latent mean/std on a sample of frames (N,3,H,W) in [-1,1]."""
        z = self.encoder(images)
        self.latent_mean.copy_(z.mean(dim=(0, 2, 3)))
        self.latent_std.copy_(z.std(dim=(0, 2, 3)).clamp(min=1e-4))

    def _check_size(self, images: torch.Tensor) -> None:
        f = self.config.downsample_factor
        if images.dim() != 4 or images.shape[1] != 3:
            raise ValueError(f"expected images of shape (N,3,H,W), got {tuple(images.shape)}")
        if images.shape[2] % f or images.shape[3] % f:
            raise ValueError(f"frame size {images.shape[3]}x{images.shape[2]} is not divisible by the autoencoder's factor {f}")


def frames_to_tensor(frames: np.ndarray) -> torch.Tensor:  # (N,H,W,3) uint8 -> (N,3,H,W) float in [-1,1]
    return torch.from_numpy(np.ascontiguousarray(frames)).permute(0, 3, 1, 2).float() / 127.5 - 1.0


def tensor_to_frames(images: torch.Tensor) -> np.ndarray:  # (N,3,H,W) in [-1,1] -> (N,H,W,3) uint8
    scaled = ((images.clamp(-1.0, 1.0) + 1.0) * 127.5).round().to(torch.uint8)
    return scaled.permute(0, 2, 3, 1).cpu().numpy()


@torch.no_grad()
def encode_frames(autoencoder: Autoencoder, frames: np.ndarray, batch_size: int = 16) -> torch.Tensor:
    """(N,H,W,3) uint8 -> (N,c,h,w) standardised latents, in batches to bound memory.

    Encodes on the autoencoder's device and returns the latents on the CPU, where data sets live.
    """
    device = module_device(autoencoder)
    chunks = [
        autoencoder.encode(frames_to_tensor(frames[i : i + batch_size]).to(device)).cpu() for i in range(0, len(frames), batch_size)
    ]
    return torch.cat(chunks, dim=0)


@torch.no_grad()
def decode_latents(autoencoder: Autoencoder, latents: torch.Tensor, batch_size: int = 16) -> np.ndarray:
    """(N,c,h,w) standardised latents (any device) -> (N,H,W,3) uint8, decoded on the autoencoder's device."""
    device = module_device(autoencoder)
    chunks = [tensor_to_frames(autoencoder.decode(latents[i : i + batch_size].to(device))) for i in range(0, len(latents), batch_size)]
    return np.concatenate(chunks, axis=0)
