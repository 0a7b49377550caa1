"""Vectorised extrema of float arrays: ``llvm.maxnum``/``llvm.minnum`` as numba intrinsics, and the
largest, smallest, first-largest and first-smallest of an array with them (numba's own ``max``
does not vectorise). Used by :mod:`.kernels` and :mod:`.robust`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from llvmlite import ir
from numba import config as _config
from numba import njit
from numba.core import cgutils, types
from numba.extending import intrinsic


def _fp_extremum(name: str) -> Any:
    """``llvm.maxnum``/``llvm.minnum`` with fast-math flags: a max or min reduction written with it
    vectorises (numba's ``max`` does not). Exact for finite input, so the order is free."""

    @intrinsic
    def extremum(typingctx, a, b):  # typing context and operand types, as numba passes them
        def codegen(context, builder, signature, args):
            double = ir.DoubleType()
            fn = cgutils.get_or_insert_function(
                builder.module, ir.FunctionType(double, [double, double]), f"llvm.{name}.f64"
            )
            return builder.call(fn, args, fastmath=("fast",))

        return types.float64(types.float64, types.float64), codegen

    return extremum


def _max(a: float, b: float) -> float:
    return a if a >= b else b


def _min(a: float, b: float) -> float:
    return a if a <= b else b


config: Any = _config  # its settings are set at run time: untyped
if config.DISABLE_JIT:  # interpreted (:mod:`.interpreted`): an intrinsic cannot run in Python
    _fmax, _fmin = _max, _min
else:
    _fmax = _fp_extremum("maxnum")
    _fmin = _fp_extremum("minnum")


@njit(cache=True, inline="always")
def vmax(a: np.ndarray) -> float:
    """Largest value of a non-empty finite array (vectorised; equals ``a.max()``)."""
    m = a[0]
    for i in range(a.size):
        m = _fmax(m, a[i])
    return m


@njit(cache=True, inline="always")
def vmin(a: np.ndarray) -> float:
    """Smallest value of a non-empty finite array (vectorised; equals ``a.min()``)."""
    m = a[0]
    for i in range(a.size):
        m = _fmin(m, a[i])
    return m


@njit(cache=True, inline="always")
def vminmax(a: np.ndarray) -> tuple[float, float]:
    """Smallest and largest value of a non-empty finite array in one vectorised pass (equal to
    ``a.min()`` and ``a.max()``)."""
    lo = a[0]
    hi = a[0]
    for i in range(a.size):
        lo = _fmin(lo, a[i])
        hi = _fmax(hi, a[i])
    return lo, hi


@njit(cache=True, inline="always")
def vargmax(a: np.ndarray) -> int:
    """Index of the first largest value, as ``np.argmax`` (vectorised maximum, then a scan)."""
    m = vmax(a)
    i = 0
    while a[i] != m:
        i += 1
    return i


@njit(cache=True, inline="always")
def vargmin(a: np.ndarray) -> int:
    """Index of the first smallest value, as ``np.argmin`` (vectorised minimum, then a scan)."""
    m = vmin(a)
    i = 0
    while a[i] != m:
        i += 1
    return i
