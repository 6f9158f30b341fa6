"""Lean latent diffusion UNet for image (``sd``) and video (``svd``, ``dd2``, ``dd2_mask``) models.

Inputs are clips of latents ``(B, T, c, h, w)``. Spatial layers treat the ``B*T`` frames
independently; video archs add temporal self-attention that mixes the ``T`` frames at every
spatial location. Conditions:

- reference frame latent ``(B, c, h, w)``: concatenated to every frame's noisy latent (all archs);
- structure maps ``(B, T, S, H, W)`` at pixel resolution (dd2 archs): a small strided conv
  encoder brings them to latent resolution; its last conv is zero-initialised;
- degraded-video latent ``(B, T, c, h, w)`` (restorers): its own input conv, zero-initialised, so a
  restorer made from a world model computes exactly the world model's output at step 0;
- reference-view latent ``(B, T, c, h, w)`` (restorers with ``view_condition``, beyond the paper):
  per frame, the view the reconstruction was trained on at the same timestamp (for a
  novel-trajectory render, the recorded frame); its own zero-initialised input conv. Frames
  without such a view get zeros, which the zero-initialised conv maps to its bias alone.

``blocks_per_level`` > 1 adds residual blocks after the first of each level, down and up; they
start as the identity, so a deeper UNet grown from a trained one computes what it did at first.

Stock diffusers UNets cost seconds per step on the project's 2-core CPU even when tiny; this one
keeps 3 levels, one residual block per level by default (``blocks_per_level``) and attention only
where the map is small.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from recondreamer.generative.config import UNetConfig


def timestep_embedding(timesteps: torch.Tensor, dim: int) -> torch.Tensor:  # (N,) -> (N, dim)
    """Sinusoidal embedding of (diffusion or frame) indices."""
    half = dim // 2
    freqs = torch.exp(-math.log(10000.0) * torch.arange(half, dtype=torch.float32, device=timesteps.device) / half)
    args = timesteps.float()[:, None] * freqs[None]
    return torch.cat([torch.cos(args), torch.sin(args)], dim=1)


def zero_module(module: nn.Module) -> nn.Module:
    for parameter in module.parameters():
        nn.init.zeros_(parameter)
    return module


def group_norm(channels: int) -> nn.GroupNorm:
    return nn.GroupNorm(num_groups=min(8, channels), num_channels=channels)


class ResBlock(nn.Module):
    """Two 3x3 convs with a time-embedding shift in between, plus a 1x1 skip when channels change."""

    def __init__(self, in_channels: int, out_channels: int, time_embed_dim: int):
        super().__init__()
        self.norm1 = group_norm(in_channels)
        self.conv1 = nn.Conv2d(in_channels, out_channels, 3, padding=1)
        self.time_proj = nn.Linear(time_embed_dim, out_channels)
        self.norm2 = group_norm(out_channels)
        self.conv2 = nn.Conv2d(out_channels, out_channels, 3, padding=1)
        self.skip = nn.Conv2d(in_channels, out_channels, 1) if in_channels != out_channels else nn.Identity()

    def forward(self, x: torch.Tensor, temb: torch.Tensor) -> torch.Tensor:  # (N,Ci,h,w), (N,E) -> (N,Co,h,w)
        h = self.conv1(F.silu(self.norm1(x)))
        h = h + self.time_proj(F.silu(temb))[:, :, None, None]
        h = self.conv2(F.silu(self.norm2(h)))
        return h + self.skip(x)


def identity_res_block(channels: int, time_embed_dim: int) -> ResBlock:
    """A residual block that starts as the identity: its last conv is zero-initialised (as guided
    diffusion initialises every block), so ``h = 0`` and the block returns its input. Added to a
    trained UNet it leaves the UNet's output unchanged, and training then makes use of it."""
    block = ResBlock(channels, channels, time_embed_dim)
    zero_module(block.conv2)
    return block


class SpatialAttention(nn.Module):
    """Self-attention over the h*w positions of each frame (residual, output projection zero-init)."""

    def __init__(self, channels: int, num_heads: int):
        super().__init__()
        self.num_heads = num_heads
        self.norm = group_norm(channels)
        self.qkv = nn.Linear(channels, 3 * channels)
        self.proj_out = zero_module(nn.Linear(channels, channels))

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # (N,C,h,w) -> (N,C,h,w)
        n, c, h, w = x.shape
        tokens = self.norm(x).flatten(2).transpose(1, 2)  # (N, h*w, C)
        q, k, v = self.qkv(tokens).reshape(n, h * w, 3, self.num_heads, c // self.num_heads).permute(2, 0, 3, 1, 4)
        attended = F.scaled_dot_product_attention(q, k, v)  # (N, heads, h*w, C/heads)
        attended = attended.transpose(1, 2).reshape(n, h * w, c)
        return x + self.proj_out(attended).transpose(1, 2).reshape(n, c, h, w)


class TemporalAttention(nn.Module):
    """Self-attention over the T frames at each spatial location, with a frame-index embedding.

    The output projection is zero-initialised so a freshly built video model starts as a per-frame
    model and learns how much to mix frames.
    """

    def __init__(self, channels: int, num_heads: int):
        super().__init__()
        self.num_heads = num_heads
        self.norm = nn.LayerNorm(channels)
        self.frame_proj = nn.Linear(channels, channels)
        self.qkv = nn.Linear(channels, 3 * channels)
        self.proj_out = zero_module(nn.Linear(channels, channels))

    def forward(self, x: torch.Tensor, num_frames: int) -> torch.Tensor:  # (B*T,C,h,w) -> (B*T,C,h,w)
        bt, c, h, w = x.shape
        b = bt // num_frames
        tokens = x.reshape(b, num_frames, c, h * w).permute(0, 3, 1, 2).reshape(b * h * w, num_frames, c)
        frame_index = torch.arange(num_frames, device=x.device)
        hidden = self.norm(tokens) + self.frame_proj(timestep_embedding(frame_index, c))[None]
        q, k, v = self.qkv(hidden).reshape(-1, num_frames, 3, self.num_heads, c // self.num_heads).permute(2, 0, 3, 1, 4)
        attended = F.scaled_dot_product_attention(q, k, v)  # (B*h*w, heads, T, C/heads)
        attended = self.proj_out(attended.transpose(1, 2).reshape(-1, num_frames, c))  # (B*h*w, T, C)
        mixed = attended.reshape(b, h * w, num_frames, c).permute(0, 2, 3, 1).reshape(bt, c, h, w)
        return x + mixed


class StructureEncoder(nn.Module):
    """Structure maps at pixel resolution -> features at latent resolution (last conv zero-init)."""

    def __init__(self, in_channels: int, hidden: int, out_channels: int, downsample_factor: int):
        super().__init__()
        self.conv_in = nn.Conv2d(in_channels, hidden, 3, padding=1)
        num_down = round(math.log2(downsample_factor))
        self.downs = nn.ModuleList(nn.Conv2d(hidden, hidden, 3, stride=2, padding=1) for _ in range(num_down))
        self.conv_out = zero_module(nn.Conv2d(hidden, out_channels, 3, padding=1))

    def forward(self, structure: torch.Tensor) -> torch.Tensor:  # (N,S,H,W) -> (N,Co,H/f,W/f)
        h = F.silu(self.conv_in(structure))
        for down in self.downs:
            h = F.silu(down(h))
        return self.conv_out(h)


class LatentUNet(nn.Module):
    """Diffusion UNet over clips of latents (it outputs the schedule's prediction target: eps, v or
    x0); see the module docstring for the conditions."""

    def __init__(self, config: UNetConfig):
        super().__init__()
        self.config = config
        channels = config.channels
        levels = len(channels)
        embed = config.time_embed_dim
        if not len(config.attention_levels) == len(config.temporal_levels) == levels:
            raise ValueError(f"attention_levels and temporal_levels need one entry per level ({levels})")
        use_temporal = [config.temporal and flag for flag in config.temporal_levels]

        self.time_mlp = nn.Sequential(nn.Linear(channels[0], embed), nn.SiLU(), nn.Linear(embed, embed))
        # Noisy latent and reference latent, concatenated along channels.
        self.conv_in = nn.Conv2d(2 * config.latent_channels, channels[0], 3, padding=1)
        self.degraded_in = (
            zero_module(nn.Conv2d(config.latent_channels, channels[0], 3, padding=1)) if config.degraded_condition else None
        )
        self.view_in = zero_module(nn.Conv2d(config.latent_channels, channels[0], 3, padding=1)) if config.view_condition else None
        if config.view_condition and not config.degraded_condition:
            raise ValueError("view_condition is a restorer input: it needs degraded_condition")
        self.structure_encoder = (
            StructureEncoder(config.structure_channels, config.structure_hidden, channels[0], config.downsample_factor)
            if config.uses_structure
            else None
        )
        if config.uses_structure and config.structure_channels <= 0:
            raise ValueError(f"arch {config.arch!r} needs structure_channels > 0")

        if config.blocks_per_level < 1:
            raise ValueError(f"blocks_per_level must be >= 1, got {config.blocks_per_level}")
        extra_blocks = config.blocks_per_level - 1
        self.down_res = nn.ModuleList()
        self.down_extra = nn.ModuleList()  # per level: the blocks after the first (identity at start)
        self.down_attn = nn.ModuleList()
        self.down_temporal = nn.ModuleList()
        self.downsamplers = nn.ModuleList()
        previous = channels[0]
        for level in range(levels):
            self.down_res.append(ResBlock(previous, channels[level], embed))
            self.down_extra.append(nn.ModuleList(identity_res_block(channels[level], embed) for _ in range(extra_blocks)))
            self.down_attn.append(SpatialAttention(channels[level], config.num_heads) if config.attention_levels[level] else nn.Identity())
            self.down_temporal.append(TemporalAttention(channels[level], config.num_heads) if use_temporal[level] else None)
            if level < levels - 1:
                self.downsamplers.append(nn.Conv2d(channels[level], channels[level], 3, stride=2, padding=1))
            previous = channels[level]

        self.mid_res1 = ResBlock(channels[-1], channels[-1], embed)
        self.mid_attn = SpatialAttention(channels[-1], config.num_heads)
        self.mid_temporal = TemporalAttention(channels[-1], config.num_heads) if config.temporal else None
        self.mid_res2 = ResBlock(channels[-1], channels[-1], embed)

        self.upsamplers = nn.ModuleList()
        self.up_res = nn.ModuleList()
        self.up_extra = nn.ModuleList()
        self.up_attn = nn.ModuleList()
        self.up_temporal = nn.ModuleList()
        for level in reversed(range(levels)):
            self.up_res.append(ResBlock(previous + channels[level], channels[level], embed))
            self.up_extra.append(nn.ModuleList(identity_res_block(channels[level], embed) for _ in range(extra_blocks)))
            self.up_attn.append(SpatialAttention(channels[level], config.num_heads) if config.attention_levels[level] else nn.Identity())
            self.up_temporal.append(TemporalAttention(channels[level], config.num_heads) if use_temporal[level] else None)
            if level > 0:
                self.upsamplers.append(nn.Conv2d(channels[level], channels[level - 1], 3, padding=1))
                previous = channels[level - 1]
            else:
                previous = channels[level]

        self.norm_out = group_norm(channels[0])
        self.conv_out = nn.Conv2d(channels[0], config.latent_channels, 3, padding=1)

    def forward(
        self,
        noisy: torch.Tensor,  # (B,T,c,h,w)
        timesteps: torch.Tensor,  # (B,) integer diffusion steps
        reference: torch.Tensor,  # (B,c,h,w) latent of the reference frame
        structure: torch.Tensor | None = None,  # (B,T,S,H,W) with H = h*factor (dd2 archs)
        degraded: torch.Tensor | None = None,  # (B,T,c,h,w) degraded-video latent (restorers)
        structure_features: torch.Tensor | None = None,  # (B*T,C0,h,w) from encode_structure, instead of structure
        view: torch.Tensor | None = None,  # (B,T,c,h,w) reference-view latent (view_condition restorers)
    ) -> torch.Tensor:  # (B,T,c,h,w) predicted target (eps, v or x0)
        b, t, c, h, w = noisy.shape
        self._check_conditions(noisy, reference, degraded, view)
        if structure_features is None and self.structure_encoder is not None:
            structure_features = self.encode_structure(structure, noisy.shape)
        frames = noisy.reshape(b * t, c, h, w)
        reference_frames = reference[:, None].expand(b, t, c, h, w).reshape(b * t, c, h, w)
        temb = self.time_mlp(timestep_embedding(timesteps, self.config.channels[0]))  # (B,E)
        temb = temb[:, None].expand(b, t, -1).reshape(b * t, -1)  # (B*T,E)

        x = self.conv_in(torch.cat([frames, reference_frames], dim=1))  # (B*T,C0,h,w)
        if self.degraded_in is not None:
            x = x + self.degraded_in(degraded.reshape(b * t, c, h, w))
        if self.view_in is not None:
            x = x + self.view_in(view.reshape(b * t, c, h, w))
        if structure_features is not None:
            x = x + structure_features

        skips = []
        for level in range(len(self.down_res)):
            x = self.down_res[level](x, temb)
            for block in self.down_extra[level]:
                x = block(x, temb)
            x = self.down_attn[level](x)
            if self.down_temporal[level] is not None:
                x = self.down_temporal[level](x, t)
            skips.append(x)
            if level < len(self.downsamplers):
                x = self.downsamplers[level](x)

        x = self.mid_res1(x, temb)
        x = self.mid_attn(x)
        if self.mid_temporal is not None:
            x = self.mid_temporal(x, t)
        x = self.mid_res2(x, temb)

        for index in range(len(self.up_res)):
            x = self.up_res[index](torch.cat([x, skips.pop()], dim=1), temb)
            for block in self.up_extra[index]:
                x = block(x, temb)
            x = self.up_attn[index](x)
            if self.up_temporal[index] is not None:
                x = self.up_temporal[index](x, t)
            if index < len(self.upsamplers):
                x = F.interpolate(x, size=skips[-1].shape[-2:], mode="nearest")
                x = self.upsamplers[index](x)

        x = self.conv_out(F.silu(self.norm_out(x)))
        return x.reshape(b, t, c, h, w)

    def encode_structure(self, structure: torch.Tensor | None, latent_shape: tuple[int, ...]) -> torch.Tensor:
        """Structure maps (B,T,S,H,W) -> (B*T,C0,h,w) features; independent of the diffusion step,
        so samplers compute them once per clip."""
        b, t, _, h, w = latent_shape
        f = self.config.downsample_factor
        expected = (b, t, self.config.structure_channels, h * f, w * f)
        if structure is None:
            raise ValueError(f"arch {self.config.arch!r} needs structure conditions of shape {expected}")
        if tuple(structure.shape) != expected:
            raise ValueError(f"structure conditions have shape {tuple(structure.shape)}, expected {expected}")
        return self.structure_encoder(structure.reshape(b * t, *structure.shape[2:]))

    def _check_conditions(self, noisy, reference, degraded, view) -> None:
        b, _, c, h, w = noisy.shape
        if c != self.config.latent_channels:
            raise ValueError(f"latent has {c} channels, the model expects {self.config.latent_channels}")
        if tuple(reference.shape) != (b, c, h, w):
            raise ValueError(f"reference latent has shape {tuple(reference.shape)}, expected {(b, c, h, w)}")
        if self.degraded_in is not None:
            if degraded is None:
                raise ValueError("a restorer needs the degraded-video latent as a condition")
            if degraded.shape != noisy.shape:
                raise ValueError(f"degraded latent has shape {tuple(degraded.shape)}, expected {tuple(noisy.shape)}")
        if self.view_in is not None:
            if view is None:
                raise ValueError("a view-conditioned restorer needs the reference-view latent (zeros for frames without a view)")
            if view.shape != noisy.shape:
                raise ValueError(f"reference-view latent has shape {tuple(view.shape)}, expected {tuple(noisy.shape)}")
        elif view is not None:
            raise ValueError("this UNet has no reference-view input (view_condition is off)")
