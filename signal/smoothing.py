"""Moving-window smoothing in O(n) by prefix sums: box and triangle filters, and the gain a
triangle filter has on white noise (which sets the detection threshold on the smoothed trace).

Compiled with numba; used by :mod:`.kernels`.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def prefix_sum(x: np.ndarray) -> np.ndarray:
    """``c[0] = 0``, ``c[i + 1] = c[i] + x[i]``: the running sum every moving average here uses."""
    c = np.empty(x.size + 1)
    c[0] = 0.0
    acc = 0.0  # the sum stays in a register: no store-to-load round trip on the chain
    for i in range(x.size):
        acc += x[i]
        c[i + 1] = acc
    return c


@njit(cache=True, inline="always")
def _box_from_prefix(c: np.ndarray, h: int, out: np.ndarray) -> None:
    """Centred moving average over 2h+1 samples from the running sum ``c``; shrinks at the ends."""
    n = out.size
    inv = 1.0 / (2 * h + 1)
    for i in range(min(h, n)):
        hi = min(n, i + h + 1)
        out[i] = c[hi] / hi
    m = n - 2 * h
    if m > 0:  # out[i] = (c[i + h + 1] - c[i - h]) * inv, on views so the loop vectorises
        upper = c[2 * h + 1 : 2 * h + 1 + m]
        lower = c[:m]
        mid = out[h : h + m]
        for k in range(m):
            mid[k] = (upper[k] - lower[k]) * inv
    for i in range(max(n - h, h), n):
        lo = i - h
        out[i] = (c[n] - c[lo]) / (n - lo)


@njit(cache=True, inline="always")
def _box_into(x: np.ndarray, h: int, c: np.ndarray, out: np.ndarray) -> None:
    """Centred moving average over 2h+1 samples by a running (prefix) sum; shrinks at the ends."""
    n = x.size
    c[0] = 0.0
    acc = 0.0
    for i in range(n):
        acc += x[i]
        c[i + 1] = acc
    _box_from_prefix(c, h, out)


@njit(cache=True)
def triangle(x: np.ndarray, h: int) -> np.ndarray:
    """Two boxcars in a row: a zero-phase triangular smoother of half-width about 2h."""
    out = np.empty(x.size)
    if h < 1:
        out[:] = x
        return out
    c = np.empty(x.size + 1)
    mid = np.empty(x.size)
    _box_into(x, h, c, mid)
    _box_into(mid, h, c, out)
    return out


@njit(cache=True)
def prefix_and_triangle(x: np.ndarray, h: int) -> tuple[np.ndarray, np.ndarray]:
    """``(prefix_sum(x), triangle(x, h))``, bit for bit, with the two running sums in one loop.

    A running sum is a chain of dependent additions; two independent chains side by side cost
    about what one does. The first box's value at ``j`` is ready once the first sum reaches
    ``j + h + 1``, so the second sum trails the first by ``h + 1`` samples.
    """
    n = x.size
    if h < 1 or n <= 2 * h:
        c = prefix_sum(x)
        return c, triangle_prefix(x, c, h, 1.0)
    c = np.empty(n + 1)
    c2 = np.empty(n + 1)
    c[0] = 0.0
    c2[0] = 0.0
    inv = 1.0 / (2 * h + 1)
    acc = 0.0
    acc2 = 0.0
    for i in range(h):
        acc += x[i]
        c[i + 1] = acc
    for i in range(h, 2 * h):  # box values that shrink at the start
        acc += x[i]
        c[i + 1] = acc
        acc2 += acc / (i + 1)
        c2[i - h + 1] = acc2
    lower = c[: n - 2 * h]
    for k in range(n - 2 * h):  # sample i = k + 2h; box value at j = k + h
        acc += x[k + 2 * h]
        c[k + 2 * h + 1] = acc
        acc2 += (acc - lower[k]) * inv
        c2[k + h + 1] = acc2
    for j in range(n - h, n):  # and at the end
        lo = j - h
        acc2 += (acc - c[lo]) / (n - lo)
        c2[j + 1] = acc2
    out = np.empty(n)
    _box_from_prefix(c2, h, out)
    return c, out


@njit(cache=True)
def triangle_prefix(x: np.ndarray, c: np.ndarray, h: int, sign: float) -> np.ndarray:
    """``triangle(sign * x, h)`` from ``c = prefix_sum(x)``, bit for bit, with ``sign`` = +-1.

    Negation commutes with rounding, so the running sum of ``-x`` is ``-c`` and every smoothed
    value just changes sign: one running sum of the record serves every width and polarity.
    """
    n = x.size
    out = np.empty(n)
    if h < 1:
        for i in range(n):
            out[i] = sign * x[i]
        return out
    # The first box's values (:func:`_box_from_prefix`'s, in its three parts) go straight into
    # the second box's running sum: the sum waits on its own additions, and each value is
    # worked out while it does.
    c2 = np.empty(n + 1)
    c2[0] = 0.0
    acc = 0.0
    inv = 1.0 / (2 * h + 1)
    for i in range(min(h, n)):
        hi = min(n, i + h + 1)
        acc += sign * (c[hi] / hi)
        c2[i + 1] = acc
    for i in range(h, n - h):
        acc += sign * ((c[i + h + 1] - c[i - h]) * inv)
        c2[i + 1] = acc
    for i in range(max(n - h, h), n):
        lo = i - h
        acc += sign * ((c[n] - c[lo]) / (n - lo))
        c2[i + 1] = acc
    _box_from_prefix(c2, h, out)
    return out


@njit(cache=True, inline="always")
def smoother_gain(h: int) -> float:
    """Standard deviation of white noise after :func:`triangle` with half-width ``h``."""
    if h < 1:
        return 1.0
    width = 2 * h + 1
    acc = 0.0
    for k in range(-2 * h, 2 * h + 1):
        tap = width - abs(k)
        acc += tap * tap
    return np.sqrt(acc) / width**2
