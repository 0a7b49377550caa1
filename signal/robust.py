"""Order statistics for noise and levels: the k-th smallest value, the median, and the MAD about a
fitted line (so slow drift does not count as noise).

The k-th smallest value by quickselect, partitioning out of place into two scratch buffers
without a branch per sample: numba's ``np.median`` partitions in place with a branch that a
noisy sample mispredicts half the time, and an in-place branch-free partition waits on its own
stores (each step reads a slot the step before may have written); written to the other buffer
from both ends, a step depends on nothing but two counters. A k-th smallest value is a value of
the set whatever finds it, so the results equal ``np.median``'s. Compiled with numba; used by
:mod:`.kernels`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

SELECT_ROUNDS = 64
"""Partition rounds after which :func:`kth_smallest` sorts what is left (a median-of-three killer
input; noise never gets there: about 2 log2(n) rounds are typical)."""
SMALL = 16
"""A range this short is finished by insertion sort."""


@njit(cache=True, inline="always")
def heapsort(a: np.ndarray, lo: int, hi: int) -> None:
    """Sorts ``a[lo:hi]`` in place in O(n log n) whatever the input: the fallback of
    :func:`kth_smallest`. Numba's ``ndarray.sort`` would do too, but compiling its quicksort
    took about a second, more than the rest of this module; this path is almost never taken.

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
def _insertion_sort(a: np.ndarray, lo: int, hi: int) -> None:
    """Sorts the short range ``a[lo:hi]`` in place."""
    for i in range(lo + 1, hi):
        v = a[i]
        j = i - 1
        while j >= lo and a[j] > v:
            a[j + 1] = a[j]
            j -= 1
        a[j + 1] = v


@njit(cache=True, inline="always")
def _split(src: np.ndarray, dst: np.ndarray, lo: int, hi: int, pivot: float,
           inclusive: bool) -> int:
    """The values of ``src[lo:hi]`` below ``pivot`` (or not above it, when ``inclusive``) into
    ``dst[lo:i]``, the others into ``dst[i:hi]``; returns ``i``. Each value is written at both
    ends of what is left and only the end it belongs to moves on (the other write is overwritten
    later): no branch, and no step reads what another wrote."""
    left = lo
    right = hi - 1
    for j in range(lo, hi):
        v = src[j]
        dst[left] = v
        dst[right] = v
        small = v <= pivot if inclusive else v < pivot
        left += small
        right -= 1 - small
    return left


@njit(cache=True)
def kth_smallest(a: np.ndarray, k: int) -> float:
    """The ``k``-th smallest value of the finite ``a`` (0-based); ``a`` is only read.

    Quickselect with a median-of-three pivot, three-way (values equal to the pivot are set aside
    in one step, so a quantised or noise-free flat trace costs a pass, not a pass per value),
    each round partitioning one buffer's range into the other's (:func:`_split`); the first
    round reads ``a`` itself."""
    n = a.size
    one = np.empty(n)
    two = np.empty(n)
    if n <= SMALL:
        for i in range(n):
            one[i] = a[i]
        _insertion_sort(one, 0, n)
        return one[k]
    x, y, z = a[0], a[n >> 1], a[n - 1]
    pivot = max(min(x, y), min(max(x, y), z))  # the median of the three
    i = _split(a, one, 0, n, pivot, False)
    lo, hi = 0, n  # the k-th value lies in one[lo:hi] or two[lo:hi], as in_one says
    in_one = True
    if k < i:
        hi = i
    else:
        j = _split(one, two, i, n, pivot, True)  # two[i:j] == pivot
        if k < j:
            return pivot
        lo, in_one = j, False
    for _ in range(SELECT_ROUNDS):
        if hi - lo <= SMALL:
            break
        src = one if in_one else two
        dst = two if in_one else one
        x, y, z = src[lo], src[(lo + hi) >> 1], src[hi - 1]
        pivot = max(min(x, y), min(max(x, y), z))
        i = _split(src, dst, lo, hi, pivot, False)
        if k < i:
            hi, in_one = i, not in_one
            continue
        j = _split(dst, src, i, hi, pivot, True)  # src[i:j] == pivot
        if k < j:
            return pivot
        lo = j
    work = one if in_one else two
    if hi - lo <= SMALL:
        _insertion_sort(work, lo, hi)
    else:
        heapsort(work, lo, hi)
    return work[k]


@njit(cache=True)
def median(a: np.ndarray) -> float:
    """Median of a non-empty finite array, equal to ``np.median`` (the mean of the two middle
    values for an even size); ``a`` is only read."""
    n = a.size
    k = n // 2
    upper = kth_smallest(a, k)
    if n % 2:
        return upper
    # the (k-1)-th smallest: upper itself if fewer than k values lie below it, else their largest
    below = 0
    lower = -np.inf
    for i in range(n):
        v = a[i]
        small = v < upper
        below += small
        lower = max(lower, v if small else -np.inf)
    if below < k:
        lower = upper
    return 0.5 * (lower + upper)


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
    med = median(r)
    for k in range(m):
        r[k] = abs(r[k] - med)
    return median(r)
