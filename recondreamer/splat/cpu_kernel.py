"""The C++ CPU kernels (``csrc/``): build-on-first-use and autograd glue.

Two autograd Functions: the fused projection + SH colour of the Gaussians
(``csrc/projection.h``) and the tile compositor (``csrc/tile_compositor.h``).

The extension is compiled with ``torch.utils.cpp_extension.load`` the first time it is needed
and cached on disk, keyed by a hash of the source and the flags, so that every later process
(and every later test session) loads the built library in well under a second and an edited
source gets a fresh build. Cache root: ``$RECONDREAMER_EXTENSIONS_DIR``, else
``$TORCH_EXTENSIONS_DIR``, else ``~/.cache/recondreamer/torch_extensions``.
"""

from __future__ import annotations

import hashlib
import os
import platform
import shutil
import threading
from pathlib import Path
from types import ModuleType

import torch

from recondreamer.errors import RecondreamerError
from recondreamer.splat.projection import ProjectedGaussians

SOURCE_DIR = Path(__file__).with_name("csrc")
SOURCES = (SOURCE_DIR / "rasterize_cpu.cpp",)
HEADERS = (SOURCE_DIR / "projection.h", SOURCE_DIR / "tile_compositor.h")
# -ffp-contract=off: no FMA contraction, so the projection follows the reference's arithmetic op by
# op; the compositor's hot loops fuse multiply-adds explicitly (tile_compositor.h, mul_add).
# -fno-trapping-math lets the compiler evaluate masked-off lanes without caring about FP traps.
BASE_FLAGS = ("-O3", "-ffp-contract=off", "-fno-math-errno", "-fno-trapping-math")
# at::parallel_for is a header template: without -fopenmp it silently runs serially, even
# though torch itself is built with OpenMP. The extension links to the libgomp.so.1 that torch
# has already loaded, so both share one thread pool and torch.set_num_threads applies.
OPENMP_FLAGS = ("-fopenmp",)
AVX2_FLAGS = ("-mavx2", "-mfma")
AVX512_FLAGS = ("-mavx512f", "-mavx512vl", "-mavx512dq")

_lock = threading.Lock()
_extension: ModuleType | None = None


class KernelBuildError(RecondreamerError, RuntimeError):
    """The C++ rasterizer could not be compiled or loaded (no compiler, build failure)."""


def cache_root() -> Path:
    """Directory under which built extensions are kept between processes."""
    for variable in ("RECONDREAMER_EXTENSIONS_DIR", "TORCH_EXTENSIONS_DIR"):
        if os.environ.get(variable):
            return Path(os.environ[variable])
    return Path.home() / ".cache" / "recondreamer" / "torch_extensions"


def compiler_flags() -> tuple[str, ...]:
    """Flags for this machine: AVX2 (and AVX-512) only where torch reports the CPU supports it,
    never ``-march=native``; the flags are part of the cache key, so a cache shared by machines with
    different CPUs holds one build per flag set."""
    flags = BASE_FLAGS + (OPENMP_FLAGS if torch_uses_openmp() else ())
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return flags
    capability = torch.backends.cpu.get_cpu_capability()
    # torch reports AVX2 only where the CPU also has FMA3, which the compositor's explicit
    # multiply-adds use (-ffp-contract=off still keeps the compiler from fusing anything else).
    if capability == "AVX512":
        # Still 8-float vectors; AVX-512VL adds 16 more vector registers, which the backward
        # pass's gradient accumulators need (measured: backward 47 -> 42 ms CPU at 50k splats,
        # one thread).
        return flags + AVX2_FLAGS + AVX512_FLAGS
    if capability == "AVX2":
        return flags + AVX2_FLAGS
    return flags


def torch_uses_openmp() -> bool:
    """True when torch's intra-op thread pool is OpenMP (the usual Linux build)."""
    return "parallel backend: OpenMP" in torch.__config__.parallel_info()


def extension_name(flags: tuple[str, ...]) -> str:
    """Name (and cache folder) of the build: changes whenever a source, a flag or torch changes.

    The sources' absolute paths are part of the key too: the build file names them by path, so two
    checkouts sharing one cache would otherwise rebuild each other's library on every switch."""
    digest = hashlib.sha256(" ".join(flags).encode() + torch.__version__.encode())
    for path in SOURCES + HEADERS:
        digest.update(str(path.resolve()).encode())
        digest.update(path.read_bytes())
    return f"recondreamer_splat_cpu_{digest.hexdigest()[:16]}"


def load_extension() -> ModuleType:
    """Return the compiled extension, building it into the cache on first use."""
    global _extension
    with _lock:
        if _extension is not None:
            return _extension
        from torch.utils import cpp_extension

        compiler = os.environ.get("CXX", "c++")
        if shutil.which(compiler) is None:
            raise KernelBuildError(
                f"the CPU rasterizer needs a C++ compiler, but {compiler!r} is not on PATH: install "
                "g++ (e.g. `apt-get install g++`) or set CXX, or use rasterize(..., backend='torch')"
            )
        if not cpp_extension.is_ninja_available():
            raise KernelBuildError("the CPU rasterizer needs ninja to build: `pip install ninja`")
        flags = compiler_flags()
        name = extension_name(flags)
        build_dir = cache_root() / name
        try:
            build_dir.mkdir(parents=True, exist_ok=True)
            _extension = cpp_extension.load(
                name=name,
                sources=[str(path) for path in SOURCES],
                extra_cflags=list(flags),
                extra_ldflags=[flag for flag in flags if flag in OPENMP_FLAGS],
                extra_include_paths=[str(SOURCE_DIR)],
                build_directory=str(build_dir),
                verbose=False,
            )
        except Exception as error:  # unwritable cache, compiler and linker failures: several types
            raise KernelBuildError(
                f"building the CPU rasterizer in {build_dir} failed (set RECONDREAMER_EXTENSIONS_DIR to "
                f"choose another cache folder): {error}"
            ) from error
        return _extension


class _ProjectGaussians(torch.autograd.Function):
    """Autograd wrapper: Gaussians -> means2d (N,2), conics (N,3), depths (N,), rgb (N,3) from SH.

    viewmat and K are constants here (the caller falls back to the torch projection when they
    need gradients); radii, in_front and visible are returned as non-differentiable outputs."""

    @staticmethod
    def forward(ctx, means, quats, scales, sh, viewmat, K, width: int, height: int):
        extension = load_extension()
        means2d, conics, depths, rgb, radii, in_front, visible = extension.project_forward(
            means, quats, scales, sh, viewmat, K, width, height
        )
        ctx.save_for_backward(means, quats, scales, sh, viewmat, K)
        ctx.size = (width, height)
        ctx.mark_non_differentiable(radii, in_front, visible)
        return means2d, conics, depths, rgb, radii, in_front, visible

    @staticmethod
    def backward(ctx, grad_means2d, grad_conics, grad_depths, grad_rgb, *_non_differentiable):
        means, quats, scales, sh, viewmat, K = ctx.saved_tensors
        width, height = ctx.size
        grad_means, grad_quats, grad_scales, grad_sh = load_extension().project_backward(
            means, quats, scales, sh, viewmat, K, width, height, grad_means2d, grad_conics, grad_depths, grad_rgb
        )
        return grad_means, grad_quats, grad_scales, grad_sh if sh.numel() else None, None, None, None, None


def project_cpu(
    means: torch.Tensor,  # (N,3)
    quats: torch.Tensor,  # (N,4)
    scales: torch.Tensor,  # (N,3)
    colors: torch.Tensor,  # (N,3) RGB or (N,C,3) SH
    viewmat: torch.Tensor,  # (4,4), no gradient
    K: torch.Tensor,  # (3,3), no gradient
    width: int,
    height: int,
) -> tuple[ProjectedGaussians, torch.Tensor]:
    """Same contract as ``project_gaussians`` followed by ``evaluate_colors``, in one C++ pass:
    returns the splats and the per-Gaussian RGB (N,3)."""
    sh = colors.contiguous() if colors.dim() == 3 else colors.new_empty(0)
    means2d, conics, depths, rgb, radii, in_front, visible = _ProjectGaussians.apply(
        means.contiguous(),
        quats.contiguous(),
        scales.contiguous(),
        sh,
        viewmat.detach().contiguous(),
        K.detach().contiguous(),
        width,
        height,
    )
    rgb_per_gaussian = rgb if colors.dim() == 3 else colors
    return ProjectedGaussians(means2d, conics, depths, in_front, radii, visible), rgb_per_gaussian


class _CompositeTiles(torch.autograd.Function):
    """Autograd wrapper: splats -> rgb (H,W,3), depth (H,W), alpha (H,W); the C++ side packs the
    fields into one (M,10) array and hands the gradients back field by field."""

    @staticmethod
    def forward(ctx, means2d, conics, colors, opacities, depths, keep, width: int, height: int):
        extension = load_extension()
        rgb, depth, alpha, *tile_state = extension.composite_forward(
            means2d, conics, colors, opacities, depths, keep, width, height
        )
        ctx.save_for_backward(*tile_state)  # packed, transmittance, last, offsets, ids, boxes, reached
        ctx.size = (width, height)
        return rgb, depth, alpha

    @staticmethod
    def backward(ctx, grad_rgb: torch.Tensor, grad_depth: torch.Tensor, grad_alpha: torch.Tensor):
        packed, *tile_state = ctx.saved_tensors
        width, height = ctx.size
        grads = load_extension().composite_backward(
            packed, width, height, *tile_state, grad_rgb, grad_depth, grad_alpha
        )  # means2d, conics, colors, opacities, depths
        return (*grads, None, None, None)  # no gradient for keep, width, height


def composite_cpu(
    means2d: torch.Tensor,  # (M,2)
    conics: torch.Tensor,  # (M,3)
    colors: torch.Tensor,  # (M,3)
    opacities: torch.Tensor,  # (M,)
    depths: torch.Tensor,  # (M,)
    width: int,
    height: int,
    keep: torch.Tensor | None = None,  # (M,) bool: splats to composite; None = all
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Same contract as :func:`recondreamer.splat.reference.composite_reference` (on the splats
    with ``keep`` true), in C++."""
    if keep is None:
        keep = torch.ones(means2d.shape[0], dtype=torch.bool, device=means2d.device)
    return _CompositeTiles.apply(means2d, conics, colors, opacities, depths, keep, width, height)
