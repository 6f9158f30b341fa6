"""Building models from checkpoints: autoencoder, world model, restorer (a world model + degraded input)."""

from __future__ import annotations

import contextlib
import dataclasses
import os
from dataclasses import dataclass

import torch

from recondreamer.configs import from_dict, to_dict
from recondreamer.errors import CheckpointError, RecondreamerError
from recondreamer.generative.autoencoder import Autoencoder
from recondreamer.generative.checkpoint import load_checkpoint
from recondreamer.generative.config import (
    AutoencoderConfig,
    DiffusionConfig,
    MaskConfig,
    RefinerConfig,
    RestoreConfig,
    TrainConfig,
    UNetConfig,
    unet_config_from_dict,
)
from recondreamer.device import module_device, use_fast_conv_layout
from recondreamer.generative.diffusion import NoiseSchedule
from recondreamer.generative.refiner import PixelRefiner
from recondreamer.generative.unet import LatentUNet


def autoencoder_from_payload(payload: dict) -> Autoencoder:
    """An autoencoder from a checkpoint dict of kind autoencoder (or the one embedded in a model)."""
    model = Autoencoder(from_dict(AutoencoderConfig, payload["config"]))
    model.load_state_dict(payload["state"])
    return model.eval().requires_grad_(False)


def autoencoder_payload(autoencoder: Autoencoder) -> dict:
    """The autoencoder as embedded in world-model and restorer checkpoints."""
    return {"config": to_dict(autoencoder.config), "state": autoencoder.state_dict()}


@contextlib.contextmanager
def config_errors_name(path: str | os.PathLike):
    """A stored config that this code cannot rebuild (``configs.from_dict``) becomes a CheckpointError naming the file."""
    try:
        yield
    except CheckpointError:
        raise
    except RecondreamerError as error:
        raise CheckpointError(f"{path}: {error}; retrain it with this version of the code") from error


def load_autoencoder(path: str | os.PathLike, device: torch.device | str = "cpu") -> tuple[Autoencoder, dict]:
    payload = load_checkpoint(path, "autoencoder")
    with config_errors_name(path):
        return use_fast_conv_layout(autoencoder_from_payload(payload).to(device)), payload


@dataclass
class GenerativeModel:
    """A world model or a restorer with everything needed to sample from it."""

    kind: str  # "world_model" | "restorer"
    arch: str
    unet: LatentUNet
    autoencoder: Autoencoder
    schedule: NoiseSchedule
    unet_config: UNetConfig
    diffusion_config: DiffusionConfig
    train_config: TrainConfig
    structure_channels: tuple[str, ...]  # names of the structure-map channels (empty if unused)
    frame_size: tuple[int, int]  # (H, W) the model was trained on
    mask_config: MaskConfig | None = None
    restore_config: RestoreConfig = dataclasses.field(default_factory=RestoreConfig)
    refiner: PixelRefiner | None = None  # restorers trained further with train-refiner (refiner.py)

    @property
    def device(self) -> torch.device:
        return module_device(self.unet)

    def to(self, device: torch.device | str) -> GenerativeModel:
        """Move the UNet and the autoencoder to ``device`` (in place; channels-last convs on the
        CPU, ``device.use_fast_conv_layout``); returns the model."""
        use_fast_conv_layout(self.unet.to(device))
        use_fast_conv_layout(self.autoencoder.to(device))
        if self.refiner is not None:
            use_fast_conv_layout(self.refiner.to(device))
        return self


def model_config_dict(model: GenerativeModel) -> dict:
    return {
        "unet": to_dict(model.unet_config),
        "diffusion": to_dict(model.diffusion_config),
        "train": to_dict(model.train_config),
        "structure_channels": list(model.structure_channels),
        "frame_size": list(model.frame_size),
        "masks": None if model.mask_config is None else to_dict(model.mask_config),
        "restore": to_dict(model.restore_config),
    }


def config_sections(config: dict) -> dict:
    """The config dataclasses of a model config dict, section by section ("masks" may be None)."""
    return {
        "unet": unet_config_from_dict(config["unet"]),
        "diffusion": from_dict(DiffusionConfig, config["diffusion"]),
        "train": from_dict(TrainConfig, config["train"]),
        "masks": None if config["masks"] is None else from_dict(MaskConfig, config["masks"]),
        "restore": from_dict(RestoreConfig, config["restore"]),
    }


def model_from_payload(payload: dict, device: torch.device | str = "cpu") -> GenerativeModel:
    config = payload["config"]
    sections = config_sections(config)  # RecondreamerError for a config of another code version
    unet = LatentUNet(sections["unet"])
    unet.load_state_dict(payload["state"])
    return GenerativeModel(
        kind=payload["kind"],
        arch=payload["arch"],
        unet=unet.eval(),
        autoencoder=autoencoder_from_payload(payload["autoencoder"]),
        schedule=NoiseSchedule(sections["diffusion"]),
        unet_config=sections["unet"],
        diffusion_config=sections["diffusion"],
        train_config=sections["train"],
        structure_channels=tuple(config["structure_channels"]),
        frame_size=tuple(config["frame_size"]),
        mask_config=sections["masks"],
        restore_config=sections["restore"],
        refiner=None if payload.get("refiner") is None else refiner_from_payload(payload["refiner"]),
    ).to(device)


def refiner_from_payload(payload: dict) -> PixelRefiner:
    """The pixel refiner stored in a restorer checkpoint's ``refiner`` entry (``training.train_refiner``)."""
    config = from_dict(RefinerConfig, payload["config"])
    refiner = PixelRefiner(config, payload["structure_channels"])
    refiner.load_state_dict(payload["state"])
    return refiner.eval()


def load_generative_model(path: str | os.PathLike, kind: str, device: torch.device | str = "cpu") -> GenerativeModel:
    """Load a ``world_model`` or ``restorer`` checkpoint (CheckpointError on the wrong kind) onto ``device``."""
    with config_errors_name(path):
        return model_from_payload(load_checkpoint(path, kind), device)


def restorer_unet_from_world_model(
    world: GenerativeModel, arch: str, blocks_per_level: int | None = None, view_condition: bool = False
) -> LatentUNet:
    """The world model's UNet with a zero-initialised degraded-video input branch (and, with
    ``view_condition``, a zero-initialised reference-view branch).

    ``dd2_mask`` is fine-tuned from a ``dd2`` world model, every other arch from its own.
    ``blocks_per_level`` (default: the world model's) may add residual blocks per level; they
    start as the identity, so the restorer still starts from the world model's output.
    """
    expected_world_arch = "dd2" if arch == "dd2_mask" else arch
    if world.arch != expected_world_arch:
        raise CheckpointError(f"restorer arch {arch!r} is fine-tuned from a {expected_world_arch!r} world model, got {world.arch!r}")
    blocks = world.unet_config.blocks_per_level if blocks_per_level is None else blocks_per_level
    if blocks < world.unet_config.blocks_per_level:
        raise CheckpointError(
            f"a restorer of {blocks} residual blocks per level cannot start from a world model of {world.unet_config.blocks_per_level}"
        )
    config = dataclasses.replace(world.unet_config, arch=arch, degraded_condition=True, blocks_per_level=blocks, view_condition=view_condition)
    unet = LatentUNet(config)
    load_grown_state(unet, world.unet.state_dict(), allowed_missing=("degraded_in.", "view_in."), source="world model")
    return unet


GROWN_BLOCK_PREFIXES = ("down_extra.", "up_extra.")


def load_grown_state(unet: LatentUNet, state: dict, allowed_missing: tuple[str, ...], source: str) -> None:
    """Load ``state`` into ``unet``, which may have more residual blocks per level than the UNet the
    state came from (those stay as built: the identity); any other missing or unexpected weight
    is a CheckpointError naming ``source``."""
    missing, unexpected = unet.load_state_dict(state, strict=False)
    allowed = allowed_missing + GROWN_BLOCK_PREFIXES
    if unexpected or any(not key.startswith(allowed) for key in missing):
        raise CheckpointError(f"{source} weights do not fit the restorer: missing {missing}, unexpected {unexpected}")


def count_parameters(module: torch.nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())
