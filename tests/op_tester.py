"""Shared base for op-level tests: one tolerance table by dtype, a dtype-aware ``assert_close``
and a float64 ``gradcheck``.

Each op gets one test class deriving from :class:`BaseTester`, with methods named by the kind of
check: ``test_smoke``, ``test_exception``, ``test_cardinality``, ``test_correctness`` (against a
reference or closed form), ``test_gradcheck``, ``test_dtype``.

Comparisons are elementwise, ``|actual - expected| <= atol + rtol * |expected|``, with the
tolerance of ``actual``'s dtype. The values assume results of order one: a value that is
naturally tiny (the gradient of a mean over thousands of pixels) is compared after scaling it up.
"""

from __future__ import annotations

import numpy as np
import torch

# (rtol, atol) by dtype, for values computed along the same lines as their reference.
TOLERANCES = {
    # Unit roundoff 1.1e-16: implementations that differ only in the order of their sums or in
    # algebraically equal formulas agree to ~1e-14. rtol 1e-10 still covers the digits lost to
    # variance-like cancellation (E[x^2] - E[x]^2 in SSIM: 1e-11 off for identical images);
    # atol 1e-12 is the floor for exact zeros computed as the residue of cancelling O(1) terms.
    torch.float64: (1e-10, 1e-12),
    # Unit roundoff 6e-8: a few dozen rounded operations on O(1) values, about 8 ulps.
    torch.float32: (1e-6, 1e-6),
}

# low_tolerance=True: values out of long float32 sums taken in another order (a fused kernel
# against autograd, windowed SSIM sums) or out of divisions that amplify rounding (a clean latent
# recovered from a noised one). Their error follows the size of the summed terms rather than of
# the result, hence the larger absolute floor (1e-4 for O(1) terms) next to ~100 ulps relative.
# float64 rounding stays far below the plain entry even there, so float64 keeps it.
LOW_TOLERANCES = {
    torch.float64: TOLERANCES[torch.float64],
    torch.float32: (1e-5, 1e-4),
}

# Central differences in float64: truncation error ~eps^2 and rounding error ~1e-16/eps are both
# far below atol at eps 1e-6; atol 1e-5 and rtol 1e-3 (torch's defaults) then flag a wrong
# backward without flagging the finite-difference error of smooth but steep functions.
GRADCHECK_OPTIONS = {"eps": 1e-6, "atol": 1e-5, "rtol": 1e-3}


def _as_tensor(value) -> torch.Tensor:
    """Tensors as they are; numpy arrays and Python or numpy scalars keep their dtype (float64)."""
    return value if isinstance(value, torch.Tensor) else torch.from_numpy(np.array(value))


class BaseTester:
    """Base class of the op test classes: shared comparisons, no tests of its own."""

    @staticmethod
    def tolerance(dtype: torch.dtype, low_tolerance: bool = False) -> tuple[float, float]:
        """(rtol, atol) for results of ``dtype``."""
        table = LOW_TOLERANCES if low_tolerance else TOLERANCES
        if dtype not in table:
            raise TypeError(f"no tolerance for {dtype}: compare it exactly or add it to op_tester's table")
        return table[dtype]

    def assert_close(self, actual, expected, *, low_tolerance: bool = False, msg: str | None = None) -> None:
        """Elementwise closeness with the tolerance of ``actual``'s dtype; shapes, dtypes and
        devices must match (cast a float64 reference to float32 to check a float32 result)."""
        actual, expected = _as_tensor(actual), _as_tensor(expected)
        rtol, atol = self.tolerance(actual.dtype, low_tolerance)
        torch.testing.assert_close(
            actual, expected, rtol=rtol, atol=atol, msg=None if msg is None else lambda text: f"{msg}\n{text}"
        )

    def gradcheck(self, fn, inputs, **kwargs) -> None:
        """``torch.autograd.gradcheck`` of ``fn`` at ``inputs`` (a tensor or a sequence), raising on
        failure. Floating-point tensors are checked as float64 leaves that require grad; other
        inputs pass through. ``kwargs`` override :data:`GRADCHECK_OPTIONS`."""
        inputs = (inputs,) if isinstance(inputs, torch.Tensor) else tuple(inputs)
        inputs = tuple(
            value.detach().to(torch.float64).requires_grad_()
            if isinstance(value, torch.Tensor) and value.is_floating_point()
            else value
            for value in inputs
        )
        torch.autograd.gradcheck(fn, inputs, raise_exception=True, **{**GRADCHECK_OPTIONS, **kwargs})
