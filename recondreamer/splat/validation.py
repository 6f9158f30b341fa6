"""Input checks for :func:`recondreamer.splat.rasterize`, run before any projection or kernel.

Every failure raises :class:`RasterizeInputError`, a ``ValueError`` (and a
``RecondreamerError``, so the command line prints it as one line) whose message names the
argument and says what is wrong.
"""

from __future__ import annotations

import math

import torch

from recondreamer.errors import RecondreamerError

BACKENDS = ("auto", "torch", "cpu", "gsplat")
SH_COEFFICIENT_COUNTS = (1, 4, 9, 16)  # SH degree 0..3


class RasterizeInputError(RecondreamerError, ValueError):
    """A rasterizer argument has the wrong shape, dtype, device, value or type."""


def _check_tensor(name: str, value, shape: tuple[int | None, ...]) -> torch.Tensor:
    """Check the type and shape (``None`` = any size) of one tensor argument."""
    if not isinstance(value, torch.Tensor):
        raise RasterizeInputError(f"{name} must be a torch.Tensor, got {type(value).__name__}")
    if value.dim() != len(shape) or any(want is not None and got != want for got, want in zip(value.shape, shape)):
        expected = "(" + ",".join("N" if s is None else str(s) for s in shape) + ")"
        raise RasterizeInputError(f"{name} must have shape {expected}, got {tuple(value.shape)}")
    return value


def validate_inputs(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    viewmat: torch.Tensor,
    K: torch.Tensor,
    width: int,
    height: int,
    background: torch.Tensor | None,
    backend: str,
) -> None:
    """Raise :class:`RasterizeInputError` naming the first bad argument; return None if all is well."""
    if not isinstance(backend, str) or backend not in BACKENDS:
        raise RasterizeInputError(f"backend must be one of {BACKENDS}, got {backend!r}")
    for name, value in (("width", width), ("height", height)):
        if isinstance(value, bool) or not isinstance(value, int):
            raise RasterizeInputError(f"{name} must be an int, got {type(value).__name__}")
        if value <= 0:
            raise RasterizeInputError(f"{name} must be positive, got {value}")

    _check_tensor("means", means, (None, 3))
    n = means.shape[0]
    _check_tensor("quats", quats, (n, 4))
    _check_tensor("scales", scales, (n, 3))
    _check_tensor("opacities", opacities, (n,))
    if not isinstance(colors, torch.Tensor):
        raise RasterizeInputError(f"colors must be a torch.Tensor, got {type(colors).__name__}")
    if colors.dim() == 2:
        _check_tensor("colors", colors, (n, 3))
    elif colors.dim() == 3:
        _check_tensor("colors", colors, (n, None, 3))
        if colors.shape[1] not in SH_COEFFICIENT_COUNTS:
            raise RasterizeInputError(
                f"colors with shape (N,C,3) are SH coefficients and need C in "
                f"{SH_COEFFICIENT_COUNTS} (degree 0..3), got C={colors.shape[1]}"
            )
    else:
        raise RasterizeInputError(
            f"colors must have shape (N,3) RGB or (N,C,3) SH coefficients, got {tuple(colors.shape)}"
        )
    _check_tensor("viewmat", viewmat, (4, 4))
    _check_tensor("K", K, (3, 3))
    if background is not None:
        _check_tensor("background", background, (3,))

    named = [
        ("means", means),
        ("quats", quats),
        ("scales", scales),
        ("opacities", opacities),
        ("colors", colors),
        ("viewmat", viewmat),
        ("K", K),
    ] + ([("background", background)] if background is not None else [])
    if means.device.type not in ("cpu", "cuda"):
        raise RasterizeInputError(f"means must be on a CPU or CUDA device, got {means.device}")
    for name, value in named:
        if value.dtype not in (torch.float32, torch.float64):
            raise RasterizeInputError(f"{name} must be float32 or float64, got {value.dtype}")
        if value.dtype != means.dtype:
            raise RasterizeInputError(f"{name} has dtype {value.dtype} but means has {means.dtype}; use one dtype")
        if value.device != means.device:
            raise RasterizeInputError(f"{name} is on {value.device} but means is on {means.device}; use one device")
    # One min/max reduction per tensor (NaN propagates through both, inf shows in one) and one
    # transfer for all of them: element-wise isfinite/compare/any chains cost milliseconds at 50k.
    nonempty = [(name, value.detach()) for name, value in named if value.numel() > 0]
    # A product with ones: the row sum over 4 columns as a reduction kernel costs 3x more at 50k.
    squared_quat_norms = quats.detach().square() @ quats.new_ones(4) if n > 0 else None  # (N,)
    reductions = [torch.stack(torch.aminmax(value)) for _, value in nonempty]
    if squared_quat_norms is not None:
        reductions.append(squared_quat_norms.amin()[None])
    values = torch.cat(reductions).tolist() if reductions else []
    extremes = {name: (values[2 * i], values[2 * i + 1]) for i, (name, _) in enumerate(nonempty)}
    for name, (low, high) in extremes.items():
        if not (math.isfinite(low) and math.isfinite(high)):
            raise RasterizeInputError(f"{name} contains NaN or infinite values")

    if n > 0:
        if extremes["opacities"][0] < 0 or extremes["opacities"][1] > 1:
            raise RasterizeInputError("opacities must lie in [0, 1]")
        if extremes["scales"][0] < 0:
            raise RasterizeInputError("scales must be non-negative linear standard deviations")
        if values[-1] == 0:
            raise RasterizeInputError("quats has rows of zero norm (no rotation defined)")
    last_row = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=viewmat.dtype, device=viewmat.device)
    if not torch.allclose(viewmat[3].detach(), last_row):
        raise RasterizeInputError("viewmat must be a rigid world-to-camera matrix with last row (0,0,0,1)")
    k = K.detach()
    if not (k[0, 0] > 0 and k[1, 1] > 0):
        raise RasterizeInputError("K must have positive focal lengths K[0,0] and K[1,1]")
    if not (k[0, 1] == 0 and k[1, 0] == 0 and k[2, 0] == 0 and k[2, 1] == 0 and k[2, 2] == 1):
        raise RasterizeInputError("K must be a pinhole matrix [[fx,0,cx],[0,fy,cy],[0,0,1]]")
