"""The C++ tile compositor (``csrc/rasterize_cpu.cpp``): build-on-first-use and autograd glue.

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

SOURCE_DIR = Path(__file__).with_name("csrc")
SOURCES = (SOURCE_DIR / "rasterize_cpu.cpp",)
HEADERS = (SOURCE_DIR / "tile_compositor.h",)
# -ffp-contract=off: no FMA contraction, so the reference's arithmetic is followed op by op.
# -fno-trapping-math lets the compiler evaluate masked-off lanes without caring about FP traps.
BASE_FLAGS = ("-O3", "-ffp-contract=off", "-fno-math-errno", "-fno-trapping-math")

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
    """Flags for this machine: AVX2 only where torch reports the CPU supports it, never
    ``-march=native``; the flags are part of the cache key, so a cache shared by machines with
    different CPUs holds one build per flag set."""
    if platform.machine().lower() in ("x86_64", "amd64") and torch.backends.cpu.get_cpu_capability() in (
        "AVX2",
        "AVX512",
    ):
        return BASE_FLAGS + ("-mavx2",)
    return BASE_FLAGS


def extension_name(flags: tuple[str, ...]) -> str:
    """Name (and cache folder) of the build: changes whenever a source, a flag or torch changes."""
    digest = hashlib.sha256(" ".join(flags).encode() + torch.__version__.encode())
    for path in SOURCES + HEADERS:
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


class _CompositeTiles(torch.autograd.Function):
    """Autograd wrapper: packed splats (M,10) -> rgb (H,W,3), depth (H,W), alpha (H,W)."""

    @staticmethod
    def forward(ctx, packed: torch.Tensor, width: int, height: int):
        extension = load_extension()
        rgb, depth, alpha, transmittance, last, offsets, ids = extension.composite_forward(packed, width, height)
        ctx.save_for_backward(packed, transmittance, last, offsets, ids)
        ctx.size = (width, height)
        return rgb, depth, alpha

    @staticmethod
    def backward(ctx, grad_rgb: torch.Tensor, grad_depth: torch.Tensor, grad_alpha: torch.Tensor):
        packed, transmittance, last, offsets, ids = ctx.saved_tensors
        width, height = ctx.size
        grad_packed = load_extension().composite_backward(
            packed, width, height, transmittance, last, offsets, ids, grad_rgb, grad_depth, grad_alpha
        )
        return grad_packed, None, None


def composite_cpu(
    means2d: torch.Tensor,  # (M,2)
    conics: torch.Tensor,  # (M,3)
    colors: torch.Tensor,  # (M,3)
    opacities: torch.Tensor,  # (M,)
    depths: torch.Tensor,  # (M,)
    width: int,
    height: int,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Same contract as :func:`recondreamer.splat.reference.composite_reference`, in C++."""
    packed = torch.cat([means2d, conics, colors, opacities[:, None], depths[:, None]], dim=1)  # (M,10)
    return _CompositeTiles.apply(packed.contiguous(), width, height)
