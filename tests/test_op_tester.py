"""The shared op-test helpers can fail: assert_close at its tolerance edge, gradcheck on a wrong backward."""

from __future__ import annotations

import pytest
import torch
from op_tester import BaseTester


class Cube(torch.autograd.Function):
    """x^3 with a chosen backward: 3x^2 (right) or 2x (wrong)."""

    @staticmethod
    def forward(ctx, x, right):
        assert x.dtype == torch.float64  # gradcheck's inputs arrive as float64
        ctx.save_for_backward(x)
        ctx.right = right
        return x**3

    @staticmethod
    def backward(ctx, grad):
        (x,) = ctx.saved_tensors
        return grad * (3 * x**2 if ctx.right else 2 * x), None


class TestBaseTester(BaseTester):
    @pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
    @pytest.mark.parametrize("low_tolerance", [False, True])
    @pytest.mark.parametrize("value", [0.0, 1.0, -3.0])
    def test_assert_close_edge(self, dtype, low_tolerance, value):
        rtol, atol = self.tolerance(dtype, low_tolerance)
        bound = atol + rtol * abs(value)
        expected = torch.full((5,), value, dtype=torch.float64)
        offset = torch.zeros(5, dtype=torch.float64)
        offset[3] = bound  # one element off, the others exact
        self.assert_close((expected + 0.9 * offset).to(dtype), expected.to(dtype), low_tolerance=low_tolerance)
        self.assert_close((expected - 0.9 * offset).to(dtype), expected.to(dtype), low_tolerance=low_tolerance)
        with pytest.raises(AssertionError):
            self.assert_close((expected + 1.1 * offset).to(dtype), expected.to(dtype), low_tolerance=low_tolerance)
        with pytest.raises(AssertionError):
            self.assert_close((expected - 1.1 * offset).to(dtype), expected.to(dtype), low_tolerance=low_tolerance)

    def test_assert_close_takes_python_and_numpy_values_as_float64(self):
        rtol, atol = self.tolerance(torch.float64)
        self.assert_close(2.0 + 0.9 * (atol + 2 * rtol), 2.0)
        with pytest.raises(AssertionError):
            self.assert_close(2.0 + 1.1 * (atol + 2 * rtol), 2.0)
        with pytest.raises(AssertionError):
            self.assert_close(torch.tensor(2.0), 2.0)  # float32 against float64: dtypes must match

    def test_assert_close_adds_the_message_and_rejects_unknown_dtypes(self):
        with pytest.raises(AssertionError, match="grad_means"):
            self.assert_close(torch.ones(3), torch.zeros(3), msg="grad_means")
        with pytest.raises(TypeError, match="no tolerance"):
            self.assert_close(torch.ones(3, dtype=torch.float16), torch.ones(3, dtype=torch.float16))

    def test_gradcheck(self):
        x = torch.linspace(-1.0, 1.5, 7)  # float32: checked in float64
        self.gradcheck(lambda t: Cube.apply(t, True), x)
        with pytest.raises(RuntimeError, match="Jacobian mismatch"):
            self.gradcheck(lambda t: Cube.apply(t, False), (x,))
