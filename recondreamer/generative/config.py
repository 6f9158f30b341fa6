"""Dataclass configs of the generative stack; each one is stored inside the checkpoints it builds.

Defaults are sized for the embedded synthetic benchmark on a 2-core CPU: 240x160 frames,
60x40 latents, 8-frame windows, a UNet of about one million parameters and 10 DDIM steps.
"""

from __future__ import annotations

from dataclasses import dataclass

from recondreamer.configs import from_dict
from recondreamer.errors import ConfigValueError

ARCHS = ("sd", "svd", "dd2", "dd2_mask")
WORLD_MODEL_ARCHS = ("sd", "svd", "dd2")


def check_at_least(config, low: float, names: tuple[str, ...]) -> None:
    """Every field in ``names`` (each item of a tuple field) at least ``low``."""
    for name in names:
        value = getattr(config, name)
        if min(value if isinstance(value, tuple) else (value,)) < low:
            raise ConfigValueError(name, f"must be >= {low}, got {value}")


def check_fraction(config, name: str, closed_high: bool, open_low: bool = False) -> None:
    """``name`` within [0, 1) (``closed_high`` False), [0, 1], or with ``open_low`` (0, 1]."""
    value = getattr(config, name)
    low_ok = value > 0.0 if open_low else value >= 0.0
    high_ok = value <= 1.0 if closed_high else value < 1.0
    if not (low_ok and high_ok):
        interval = ("(" if open_low else "[") + "0, 1" + ("]" if closed_high else ")")
        raise ConfigValueError(name, f"must be in {interval}, got {value}")


@dataclass(frozen=True)
class AutoencoderConfig:
    """The latent autoencoder E/D: ``downsample_factor``x smaller latents with ``latent_channels``."""

    latent_channels: int = 4  # channels of the latent space the diffusion models work in
    # One entry per resolution, full resolution first; narrow at full resolution where convs cost most.
    hidden_channels: tuple[int, ...] = (16, 48, 64)
    steps: int = 1500  # training steps
    batch_size: int = 8  # crops per step
    crop_size: int = 48  # random square crops of corpus frames (the network is fully convolutional)
    learning_rate: float = 2e-3  # AdamW learning rate
    ssim_weight: float = 0.1  # small SSIM term beside L1 (no perceptual network is available)

    @property
    def downsample_factor(self) -> int:
        return 2 ** (len(self.hidden_channels) - 1)

    def check(self) -> None:
        check_at_least(self, 1, ("latent_channels", "steps", "batch_size", "crop_size"))


@dataclass(frozen=True)
class UNetConfig:
    """A lean latent diffusion UNet; ``arch`` decides which conditions and temporal layers exist."""

    arch: str = "dd2"  # one of ARCHS
    latent_channels: int = 4  # channels of the latent space the diffusion models work in
    channels: tuple[int, ...] = (32, 64, 64)  # one entry per resolution level, finest first
    # Residual blocks per level on the way down and on the way up; the blocks past the first start
    # as the identity, so a UNet can be grown from a trained shallower one (unet.identity_res_block).
    blocks_per_level: int = 1
    attention_levels: tuple[bool, ...] = (False, False, True)  # spatial self-attention per level
    temporal_levels: tuple[bool, ...] = (True, True, True)  # temporal attention per level (video archs)
    num_heads: int = 4
    time_embed_dim: int = 128
    structure_channels: int = 0  # C of the structure maps (dd2 archs); 0 = no structure branch
    structure_hidden: int = 16
    downsample_factor: int = 4  # pixel-to-latent factor (structure maps come at pixel resolution)
    degraded_condition: bool = False  # restorer: degraded-video latent as an extra (zero-initialised) input
    # Restorer beyond the paper: per frame, the latent of the view the reconstruction was trained on
    # at the same timestamp (the recorded frame, for a novel-trajectory render) as a further
    # zero-initialised input; frames without one get zeros (unet.LatentUNet).
    view_condition: bool = False

    @property
    def temporal(self) -> bool:
        return self.arch != "sd"

    @property
    def uses_structure(self) -> bool:
        return self.arch in ("dd2", "dd2_mask")


# UNet fields added after checkpoints had been published, with the value that rebuilds those
# checkpoints as they were trained; a stored config without such a field gets this value.
UNET_FIELDS_ADDED = {"view_condition": False}


def unet_config_from_dict(values: dict) -> UNetConfig:
    """A stored UNet config (``configs.to_dict``), including those written before ``UNET_FIELDS_ADDED``."""
    return from_dict(UNetConfig, {**UNET_FIELDS_ADDED, **values})


@dataclass(frozen=True)
class DiffusionConfig:
    """Noise schedule, prediction target and DDIM sampling defaults (see ``diffusion.py``)."""

    schedule: str = "linear"  # "linear" (Stable Diffusion's scaled-linear betas) or "cosine"
    # "v" (as Stable Video Diffusion), "epsilon" (as Stable Diffusion) or "x0": v keeps the
    # noisiest steps' x0 estimate free of the ~15x eps-error amplification of the linear schedule.
    prediction: str = "v"
    train_timesteps: int = 1000
    beta_start: float = 0.00085
    beta_end: float = 0.012
    sample_steps: int = 10
    eta: float = 0.0
    # What the diffusion generates: "clean" latents (world models) or, for restorers, the
    # "residual" (clean - degraded) / residual_scale, so that a zero output is the identity
    # (see diffusion.py: NoiseSchedule.to_diffusion_space).
    target_space: str = "clean"
    residual_scale: float = 1.0  # std of (clean - degraded) latents over the training pairs


@dataclass(frozen=True)
class MaskConfig:
    """Random masks on degraded frames (dd2_mask): sky/scene boundary band and distant centre.

    A frame is masked with ``probability``; a masked frame gets ``boundary_boxes`` random boxes
    centred on the sky/scene boundary band and ``center_boxes`` random boxes centred in the
    distant central region. Every box is clipped to the union of the two regions, so masked
    pixels never fall outside them. Sizes are fractions of the image height.
    """

    probability: float = 0.5  # probability that a frame is masked
    band_half_width: float = 0.06  # half-width of the sky/scene boundary band
    boundary_boxes: tuple[int, int] = (2, 5)  # inclusive range of the number of boxes
    center_boxes: tuple[int, int] = (1, 2)
    box_size: tuple[float, float] = (0.08, 0.25)  # side length range
    center_width: float = 0.4  # distant central region (around the vanishing point): width ...
    center_height: float = 0.22  # ... and height, as fractions of the image width and height

    def check(self) -> None:
        check_fraction(self, "probability", closed_high=True)


@dataclass(frozen=True)
class TrainConfig:
    """Optimisation of a world model or restorer."""

    steps: int = 1200  # training steps
    batch_size: int = 2  # clips per step
    window: int = 8  # frames per clip
    crop: tuple[int, int] = (24, 32)  # latent crop (h, w) used in training; 0,0 = whole latent
    learning_rate: float = 1e-3  # AdamW learning rate (linear warm-up, then cosine decay)
    weight_decay: float = 0.0  # AdamW weight decay
    warmup_steps: int = 50  # steps of linear learning-rate warm-up
    # Training timesteps have density proportional to t^(power - 1): 1 = uniform (pretraining);
    # > 1 favours the noisy steps where a restorer's few-step sampler spends its effort.
    timestep_power: float = 1.0
    # Restorers: weight of an image-space term beside the diffusion loss, the MSE of the frames the
    # one-step sample decodes to (training.image_space_loss); 0 = the diffusion loss alone.
    pixel_loss_weight: float = 0.0
    # Decay of an exponential moving average of the weights, which the checkpoint then holds;
    # 0 = the last weights. Batches of two clips make single steps noisy, and averaging them is
    # standard in diffusion training (recondreamer.training_loop).
    ema_decay: float = 0.0
    checkpoint_every: int = 200  # steps between resume checkpoints
    log_every: int = 50  # steps between progress lines
    seed: int = 0  # random seed of initialisation, batches and noise

    def check(self) -> None:
        check_at_least(self, 1, ("steps", "batch_size", "window", "checkpoint_every", "log_every"))
        check_at_least(self, 0, ("crop", "pixel_loss_weight", "seed"))
        check_fraction(self, "ema_decay", closed_high=False)
        if self.learning_rate <= 0 or self.timestep_power <= 0:
            raise ConfigValueError("learning_rate" if self.learning_rate <= 0 else "timestep_power", "must be > 0")


@dataclass(frozen=True)
class RefinerConfig:
    """The pixel refiner (``refiner.py``) and its training (``training.train_refiner``).

    It trains on random square pixel crops of single frames: the restorer's output, the degraded
    render and the structure maps of one frame, against its ground truth.
    """

    width: int = 24  # channels at full resolution (2x at half, 3x at quarter resolution)
    bottleneck_blocks: int = 3  # residual blocks at quarter resolution
    use_structure: bool = True  # also see the structure maps (dd2 archs' conditions)
    temporal_neighbours: int = 0  # also see the restored and degraded frames this many frames before and after (0: per frame)
    output_norm: bool = True  # per-pixel channel norm before the last activation (refiner.PixelChannelNorm)
    # Largest change the correction may make to a pixel, in grey levels of 255 (0: unbounded). The
    # refiner learns small edge corrections (1-2 levels on average) from 64-pixel crops; on a flat
    # surface filling much of a frame, unlike its crops, an unbounded one brightened a truck's side
    # to up to 159 levels from the truth and cost 5 dB. Clipping that refiner's correction at 12 levels
    # scored best of bounds 2-64 and none on 4 scenes neither it nor its restorer trained on
    # (experiments/refiner_bound.py, docs/generative.md).
    max_correction: float = 12.0
    steps: int = 3000  # training steps
    batch_size: int = 8  # crops per step
    crop: int = 64  # crop side in pixels
    # 1e-3 trained two 3000-step refiners but sent a 6000-step one to a loss spike (step 1200) after
    # which it returned its input unchanged; 5e-4 trained that job well (docs/generative.md).
    learning_rate: float = 5e-4  # AdamW learning rate
    warmup_steps: int = 100  # steps of linear learning-rate warm-up
    ema_decay: float = 0.0  # decay of a moving average of the weights saved instead of the last ones (0: off)
    checkpoint_every: int = 200  # steps between resume checkpoints
    log_every: int = 50  # steps between progress lines
    seed: int = 0  # random seed of initialisation and crops

    def check(self) -> None:
        check_at_least(self, 1, ("width", "steps", "batch_size", "crop"))
        check_at_least(self, 0, ("temporal_neighbours", "max_correction", "seed"))
        check_fraction(self, "ema_decay", closed_high=False)


@dataclass(frozen=True)
class RestoreConfig:
    """Inference of a restorer over a clip of any length."""

    window: int = 8  # frames restored together
    overlap: int = 2  # frames shared by consecutive windows, linearly cross-faded in latent space
    sample_steps: int = 10  # DDIM steps
    strength: float = 1.0  # 1 = start from pure noise; < 1 starts from the noised degraded latent
    seed: int = 0  # sampling seed
    # Decode the change only: output = input + D(z_restored) - D(E(input)). Pixels the restorer
    # leaves alone keep the input's detail instead of the autoencoder's reconstruction of it, so
    # the autoencoder's own error no longer caps the output's fidelity.
    residual_decoding: bool = False
    # Noise draws sampled per window and averaged in latent space (inference.py): more samples
    # approach the output distribution's mean, the least-squares estimate, at that many UNet passes.
    samples: int = 1

    def check(self) -> None:
        check_at_least(self, 1, ("window", "sample_steps", "samples"))
        check_at_least(self, 0, ("overlap", "seed"))
        if self.overlap >= self.window:
            raise ConfigValueError("overlap", f"must be smaller than the window ({self.window} frames), got {self.overlap}")
        check_fraction(self, "strength", closed_high=True, open_low=True)


# What `train-restorer` uses unless told otherwise (docs/generative.md): one DDIM step with residual
# decoding when restoring (4 steps scored ~1 dB lower on held-out pairs) and four noise draws
# averaged per window (+0.06-0.07 dB on held-out pairs over one draw, and less flicker, for
# 1.5-1.6x the restore time: the autoencoder, run once, costs more than the UNet passes); training
# timesteps with density ~ t^49, 95% of them above t = 940: the restorer learns the one step it
# samples (t = 999). Against power 3 this gained +0.33 vs +0.13 dB on held-out pairs at 1000 steps
# and +0.84 vs +0.62 dB at 3000; later DDIM steps are then barely trained.
RESTORER_RESTORE = RestoreConfig(sample_steps=1, residual_decoding=True, samples=4)
RESTORER_TIMESTEP_POWER = 50.0
