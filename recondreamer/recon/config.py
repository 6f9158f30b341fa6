"""Dataclass configs of a reconstruction run and the three presets (quick, default, paper).

A config is plain data: it round-trips through ``recondreamer.configs`` so that
checkpoints and ``run.json`` describe themselves. Learning rates of positions are relative to
the scene extent (metres), as in 3DGS.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from recondreamer.errors import ConfigValueError, RecondreamerError

MODEL_TYPES = ("street", "pvg", "deformable", "s3")
PRESETS = ("quick", "default", "paper")


@dataclass
class InitConfig:
    """Initial Gaussians: LiDAR points seen by the camera, plus a far shell for the background."""

    max_lidar_points: int = (
        3000  # subsample of all frames' LiDAR points seen by the camera
    )
    num_far_points: int = (
        400  # random points on a shell around the scene (far background)
    )
    far_radius: tuple[float, float] = (
        1.5,
        3.0,
    )  # shell radii as multiples of the LiDAR radius
    max_object_points: int = 120  # street: initial points per tracked vehicle
    initial_opacity: float = 0.3


@dataclass
class ModelConfig:
    """Architecture sizes; each backbone reads only its own fields."""

    sh_degree: int = (
        1  # view-dependent colour; degree raised every ``sh_degree_every`` steps
    )
    sh_degree_every: int = 500
    sky_height: int = (
        32  # equirectangular sky texture (every backbone has the same sky)
    )
    sky_width: int = 128
    object_labels: tuple[str, ...] = (
        "vehicle",
    )  # street: labels modelled in their box frame
    pvg_cycle: float = (
        0.2  # pvg: vibration period l, in normalised time (segment = [0, 1])
    )
    pvg_lifespan: float = 0.5  # pvg: initial lifespan beta (normalised time)
    deform_width: int = 64  # deformable: MLP width
    deform_depth: int = 3  # deformable: hidden layers
    deform_freqs_x: int = 6  # deformable: positional-encoding octaves of position
    deform_freqs_t: int = 4  # deformable: positional-encoding octaves of time
    hexplane_resolutions: tuple[int, ...] = (
        16,
        32,
    )  # s3: spatial plane resolutions (multi-res)
    hexplane_time_resolution: int = (
        0  # s3: time resolution; 0 = half the number of frames
    )
    hexplane_features: int = 16  # s3: channels per plane
    s3_decoder_width: int = 64  # s3: decoder MLP width
    warmup_fraction: float = 0.15  # deformable/s3: static warm-up, as in both papers


@dataclass
class OptimConfig:
    """Adam learning rates per parameter group (positions relative to the scene extent)."""

    means: float = 1.6e-3
    means_final: float = 1.6e-5
    quats: float = 2e-3
    scales: float = 1e-2
    opacities: float = 5e-2
    sh_dc: float = 5e-3
    sh_rest: float = 2.5e-4
    dynamics: float = 5e-3  # pvg: velocity, peak time, lifespan
    field: float = 2e-3  # deformation MLP / HexPlane field and decoders
    field_final: float = 1e-4
    grid: float = 2e-2  # s3: HexPlane feature planes
    grid_final: float = 1e-3
    sky: float = 2e-2


@dataclass
class DensifyConfig:
    """Adaptive density control (3DGS): clone small, split large, prune transparent or huge."""

    start: int = 100
    stop_fraction: float = 0.7  # densify until this fraction of the iterations
    every: int = 100
    grad_threshold: float = 2e-4  # mean screen-space gradient norm (NDC units)
    percent_dense: float = 0.01  # clone/split boundary: fraction of the scene extent
    min_opacity: float = 0.005
    max_screen_radius: float = 0.0  # px; 0 = no screen-size pruning
    max_world_scale: float = 0.2  # fraction of the scene extent
    reset_opacity_every: int = 1000  # 0 = never
    max_gaussians: int = 8000


@dataclass
class LossConfig:
    """Loss weights and the depth-loss mask. The weights are the public defaults of drivestudio and
    Street Gaussians: RGB 0.8, SSIM 0.2, LiDAR depth in their 0.01-0.1 range, sky opacity 0.05."""

    rgb: float = 0.8
    ssim: float = 0.2
    depth: float = 0.05
    sky: float = 0.05
    depth_min_alpha: float = 0.5  # depth loss only where the render is this opaque
    ssim_window: int = 11


@dataclass
class ReconConfig:
    """Everything one reconstruction run needs besides the scene."""

    model: str = "street"
    preset: str = "default"
    iterations: int = 2000  # training iterations (each preset sets its own)
    seed: int = 0  # random seed (initialisation, view order, splits)
    backend: str = "auto"  # rasteriser: auto (gsplat on CUDA, else the C++ CPU kernel), torch, cpu or gsplat
    device: str = "cpu"  # torch device of the model, e.g. cpu or cuda (cuda pairs with the gsplat backend)
    log_every: int = 100
    checkpoint_every: int = 500
    snapshot_steps: tuple[int, ...] = ()
    coarse_fraction: float = (
        0.0  # first fraction of the iterations trained at reduced resolution
    )
    coarse_factor: int = (
        2  # resolution divisor of the coarse phase (coarse-to-fine schedule)
    )
    init: InitConfig = field(default_factory=InitConfig)
    net: ModelConfig = field(default_factory=ModelConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    densify: DensifyConfig = field(default_factory=DensifyConfig)
    loss: LossConfig = field(default_factory=LossConfig)

    def check(self) -> None:
        from recondreamer.splat.validation import BACKENDS  # the rasteriser's list (imports torch: not at module load)

        if self.iterations < 1:
            raise ConfigValueError("iterations", f"must be at least 1, got {self.iterations}")
        if self.backend not in BACKENDS:
            raise ConfigValueError("backend", f"must be one of {', '.join(BACKENDS)}, got {self.backend!r}")


def make_config(model: str, preset: str = "default", **overrides) -> ReconConfig:
    """The preset's config for one backbone; ``overrides`` replace top-level fields."""
    if model not in MODEL_TYPES:
        raise RecondreamerError(
            f"unknown reconstruction model {model!r}; choose one of {', '.join(MODEL_TYPES)}"
        )
    if preset not in PRESETS:
        raise RecondreamerError(
            f"unknown preset {preset!r}; choose one of {', '.join(PRESETS)}"
        )
    if preset == "quick":
        config = ReconConfig(
            model=model,
            preset=preset,
            iterations=300,
            log_every=50,
            checkpoint_every=100,
            snapshot_steps=(100, 200),
            init=InitConfig(
                max_lidar_points=1200, num_far_points=150, max_object_points=150
            ),
            net=ModelConfig(
                sh_degree=0,
                sky_height=16,
                sky_width=64,
                deform_width=32,
                deform_depth=2,
                hexplane_resolutions=(8, 16),
                hexplane_features=8,
                s3_decoder_width=32,
            ),
            densify=DensifyConfig(
                start=50, every=50, reset_opacity_every=0, max_gaussians=2500
            ),
        )
    elif preset == "default":
        # Short CPU schedule: half resolution for the first half, no opacity reset (it costs
        # more PSNR than it saves in a schedule this short).
        config = ReconConfig(
            model=model,
            preset=preset,
            iterations=2000,
            snapshot_steps=(250, 500, 1000),
            coarse_fraction=0.5,
            densify=DensifyConfig(reset_opacity_every=0),
        )
    else:
        config = ReconConfig(
            model=model,
            preset=preset,
            iterations=50000,
            log_every=500,
            checkpoint_every=5000,
            snapshot_steps=(2000, 5000, 10000, 20000),
            init=InitConfig(
                max_lidar_points=600000,
                num_far_points=100000,
                max_object_points=20000,
                initial_opacity=0.1,
            ),
            net=ModelConfig(
                sh_degree=3,
                sh_degree_every=1000,
                sky_height=256,
                sky_width=1024,
                pvg_cycle=0.2,
                deform_width=256,
                deform_depth=8,
                deform_freqs_x=10,
                deform_freqs_t=6,
                hexplane_resolutions=(64, 128),
                hexplane_features=32,
                s3_decoder_width=128,
                warmup_fraction=0.06,
            ),
            optim=OptimConfig(
                means=1.6e-4,
                means_final=1.6e-6,
                quats=1e-3,
                scales=5e-3,
                sh_dc=2.5e-3,
                sh_rest=1.25e-4,
                dynamics=1e-3,
                field=8e-4,
                field_final=1.6e-6,
                grid=1.6e-3,
                grid_final=1.6e-5,
                sky=1e-2,
            ),
            densify=DensifyConfig(
                start=500,
                stop_fraction=0.5,
                every=100,
                grad_threshold=2e-4,
                max_screen_radius=20.0,
                max_world_scale=0.1,
                reset_opacity_every=3000,
                max_gaussians=3_000_000,
            ),
        )
    for key, value in overrides.items():
        if not hasattr(config, key):
            raise RecondreamerError(f"unknown config field {key!r}")
        setattr(config, key, value)
    return config
