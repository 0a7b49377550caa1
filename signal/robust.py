"""Order statistics for noise and levels: quickselect, the median, and the MAD about a fitted
line (so slow drift does not count as noise).

A branch-free three-way quickselect instead of numba's ``np.median``, whose partition
mispredicts a branch per noisy sample; results equal. Compiled with numba; used by
:mod:`.kernels`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .extrema import _fmax

SELECT_ROUNDS = 64
"""Partition rounds after which :func:`select` sorts what is left (a median-of-three killer
input; noise never gets there: about 2 log2(n) rounds are typical)."""


@njit(cache=True, inline="always")
def heapsort(a: np.ndarray, lo: int, hi: int) -> None:
    """Sorts ``a[lo:hi]`` in place in O(n log n) whatever the input: the fallback of
    :func:`select`. Numba's ``ndarray.sort`` would do too, but compiling its quicksort took
    about a second, more than the rest of this module; this path is almost never taken.

    One loop: first the heap is built (``start`` walks down to 0), then its top is swapped to
    the end of the shrinking heap; either way the element at ``root`` is sifted down."""
    n = hi - lo
    start = n // 2
    end = n
    while end > 1:
        if start > 0:
            start -= 1
        else:
            end -= 1
            a[lo], a[lo + end] = a[lo + end], a[lo]
        root = start
        while 2 * root + 1 < end:
            child = 2 * root + 1
            if child + 1 < end and a[lo + child + 1] > a[lo + child]:
                child += 1
            if not a[lo + child] > a[lo + root]:
                break
            a[lo + root], a[lo + child] = a[lo + child], a[lo + root]
            root = child


@njit(cache=True, inline="always")
def _partition(a: np.ndarray, lo: int, hi: int, pivot: float, inclusive: bool) -> int:
    """Moves the values of ``a[lo:hi]`` below ``pivot`` (or not above it, when ``inclusive``) to
    the front of that range and returns where they end. Branch-free: on noise every comparison
    is a coin toss, which would cost a mispredicted branch per element."""
    i = lo
    for j in range(lo, hi):
        v = a[j]
        t = a[i]
        small = v <= pivot if inclusive else v < pivot
        a[j] = t if small else v
        a[i] = v if small else t
        i += small
    return i


@njit(cache=True)
def select(a: np.ndarray, k: int) -> float:
    """The ``k``-th smallest value of ``a`` (0-based), leaving ``a`` partially reordered so that
    ``a[:k]`` holds the ``k`` smallest values.

    Quickselect with a median-of-three pivot, three-way (values equal to the pivot are set aside
    in one step, so a quantised or noise-free flat trace costs a pass, not a pass per value).
    numba's ``np.median`` spends most of its time on mispredicted branches here.
    """
    lo, hi = 0, a.size  # the k-th value lies in a[lo:hi]
    for _ in range(SELECT_ROUNDS):
        if hi - lo <= 1:
            return a[k]
        x, y, z = a[lo], a[(lo + hi) >> 1], a[hi - 1]
        pivot = max(min(x, y), min(max(x, y), z))  # the median of the three
        i = _partition(a, lo, hi, pivot, False)
        if k < i:
            hi = i
            continue
        j = _partition(a, i, hi, pivot, True)  # a[i:j] == pivot
        if k < j:
            return pivot
        lo = j
    heapsort(a, lo, hi)
    return a[k]


@njit(cache=True)
def median_inplace(a: np.ndarray) -> float:
    """Median of a non-empty finite array, equal to ``np.median`` (the mean of the two middle
    values for an even size); reorders ``a``."""
    n = a.size
    k = n // 2
    upper = select(a, k)
    if n % 2:
        return upper
    lower = a[0]  # after select, a[:k] holds the k smallest values
    for i in range(1, k):
        lower = _fmax(lower, a[i])
    return 0.5 * (lower + upper)


@njit(cache=True, inline="always")
def median(x: np.ndarray) -> float:
    """:func:`median_inplace` of a copy: ``np.median(x)`` for finite ``x``, faster on noise."""
    return median_inplace(x.copy())


MAD_POINTS = 512
"""The MAD is taken over at most this many evenly spread samples (5 % precision on the noise,
which sets thresholds and the reported SNR; every pulse's own baseline uses all samples)."""


@njit(cache=True, inline="always")
def detrended_mad(x: np.ndarray) -> float:
    """MAD of ``x`` about its least-squares line, so slow drift does not count as noise."""
    n = x.size
    tm = 0.5 * (n - 1)
    sx = 0.0
    sxx = 0.0
    sy = 0.0
    for i in range(n):
        sy += x[i]
        sx += (i - tm) * x[i]
        sxx += (i - tm) * (i - tm)
    slope = sx / sxx if sxx > 0 else 0.0
    mean = sy / n
    stride = (n + MAD_POINTS - 1) // MAD_POINTS
    m = (n + stride - 1) // stride
    r = np.empty(m)
    for k in range(m):
        i = k * stride
        r[k] = x[i] - mean - slope * (i - tm)
    med = median_inplace(r)
    for k in range(m):
        r[k] = abs(r[k] - med)
    return median_inplace(r)
