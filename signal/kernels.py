"""Numba kernels behind pulse detection: the whole search-and-measure pass of one shot.

:func:`analyze` does everything that touches the samples: pre-trigger segment, baseline and noise,
smoothing, peak search, drift, and the template fit of every pulse. It returns plain arrays
(:data:`HEAD` and :data:`PULSE` name their columns), so a 10,000-sample shot costs a few O(n)
passes and no Python work per sample or per pulse; :mod:`solitonde.signal.pulses` only turns the
arrays into objects.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit
from numba.core import cgutils, types
from numba.extending import intrinsic

MAX_FIT_POINTS = 64
"""A longer fit window is block-averaged down to this (the pulse is smooth on that scale)."""

R_MIN, R_MAX = 1.2, 8.0
"""Bounds on the shape exponent r of the template A exp(-|u|^r)."""

MIN_PRETRIGGER = 16
MAD_TO_SIGMA = 1.4826
NOISE_FLOOR = 1e-9
"""Noise is never taken below this fraction of the largest excursion (noise-free model traces)."""

FOOT = 1.5
"""A pulse's foot lies this many of its FWHM before (and after) its peak: the solitary wave has
fallen below 0.5 % of its peak there. The level the sensor holds before the foot is the pulse's
baseline."""

LEVEL_SPAN = 12.0
"""The baseline window before a pulse's foot is at most this many FWHM long (the noise of the
level falls as the root of its length; the slow trend carries it to the peak)."""

TRUNC_SPAN = 2.5
"""A pulse counts as truncated when the record ends (or starts) within this many FWHM of its peak
while the pulse is still above ``fit_fraction`` of its height."""

# Columns of the head array returned by analyze.
(H_SIGN, H_BASE, H_SIGMA, H_THR, H_NPRE, H_SMOOTH, H_NPEAKS, H_EARLY, H_SATURATED,
 H_UPPER) = range(10)
HEAD = 10
# Columns of the per-pulse array returned by analyze (times and widths in samples).
(P_TIME, P_AMP, P_BASE, P_WIDTH, P_ONSET, P_END, P_INDEX, P_METHOD, P_TRUNC, P_MERGED,
 P_LEVEL) = range(11)
PULSE = 11


def _fp_extremum(name: str) -> object:
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


_fmax = _fp_extremum("maxnum")
_fmin = _fp_extremum("minnum")


@njit(cache=True)
def vmax(a: np.ndarray) -> float:
    """Largest value of a non-empty finite array (vectorised; equals ``a.max()``)."""
    m = a[0]
    for i in range(a.size):
        m = _fmax(m, a[i])
    return m


@njit(cache=True)
def vmin(a: np.ndarray) -> float:
    """Smallest value of a non-empty finite array (vectorised; equals ``a.min()``)."""
    m = a[0]
    for i in range(a.size):
        m = _fmin(m, a[i])
    return m


@njit(cache=True)
def vargmax(a: np.ndarray) -> int:
    """Index of the first largest value, as ``np.argmax`` (vectorised maximum, then a scan)."""
    m = vmax(a)
    i = 0
    while a[i] != m:
        i += 1
    return i


MAX_ABS_SAMPLE = 1e12
"""Largest sample magnitude a shot may hold (N or V; raw ADC counts fit too): far beyond any
sensor, and far below where the kernel's running sums over a record would overflow to inf and
turn indices into NaN (1e305 did)."""

ABS_BITS = np.uint64(0x7FFFFFFFFFFFFFFF)
LIMIT_BITS = np.float64(MAX_ABS_SAMPLE).view(np.uint64)


@njit(cache=True)
def first_invalid(x: np.ndarray) -> int:
    """Flat index of the first sample of a C-contiguous float64 array that is NaN, inf or larger
    in magnitude than :data:`MAX_ABS_SAMPLE`, or -1.

    Non-negative IEEE doubles order as their bit patterns, and NaN and inf lie above every finite
    number: one unsigned comparison of the bits without the sign tests all three. Counting is
    integer work the compiler vectorises, so a clean array costs one fast pass.
    """
    bits = x.reshape(x.size).view(np.uint64)
    count = 0
    for i in range(bits.size):
        count += (bits[i] & ABS_BITS) > LIMIT_BITS
    if count == 0:
        return -1
    i = 0
    while (bits[i] & ABS_BITS) <= LIMIT_BITS:
        i += 1
    return i


@njit(cache=True)
def prefix_sum(x: np.ndarray) -> np.ndarray:
    """``c[0] = 0``, ``c[i + 1] = c[i] + x[i]``: the running sum every moving average here uses."""
    c = np.empty(x.size + 1)
    c[0] = 0.0
    acc = 0.0  # the sum stays in a register: no store-to-load round trip on the chain
    for i in range(x.size):
        acc += x[i]
        c[i + 1] = acc
    return c


@njit(cache=True)
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


@njit(cache=True)
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
def boxcar(x: np.ndarray, h: int) -> np.ndarray:
    """Centred moving average over 2h+1 samples (zero phase); the window shrinks at the ends."""
    out = np.empty(x.size)
    if h < 1:
        out[:] = x
        return out
    _box_into(x, h, np.empty(x.size + 1), out)
    return out


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
    mid = np.empty(n)
    _box_from_prefix(c, h, mid)
    if sign < 0:
        for i in range(n):
            mid[i] = -mid[i]
    _box_into(mid, h, np.empty(n + 1), out)
    return out


@njit(cache=True)
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


SELECT_ROUNDS = 64
"""Partition rounds after which :func:`select` sorts what is left (a median-of-three killer
input; noise never gets there: about 2 log2(n) rounds are typical)."""


@njit(cache=True)
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
    a[lo:hi].sort()
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


@njit(cache=True)
def median(x: np.ndarray) -> float:
    """:func:`median_inplace` of a copy: ``np.median(x)`` for finite ``x``, faster on noise."""
    return median_inplace(x.copy())


MAD_POINTS = 512
"""The MAD is taken over at most this many evenly spread samples (5 % precision on the noise,
which sets thresholds and the reported SNR; every pulse's own baseline uses all samples)."""


@njit(cache=True)
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


SKIP_BLOCK = 16
"""Samples the peak search tests at once before walking them one by one."""


@njit(cache=True)
def find_peaks_hysteresis(v: np.ndarray, thr: float, delta: float) -> np.ndarray:
    """Indices of peaks of ``v`` that rise above ``thr`` and stand out by ``delta`` on both sides.

    A peak is confirmed once ``v`` falls ``delta`` below it; the search for the next peak starts
    once ``v`` rises ``delta`` above the valley in between (Billauer's peakdet with a floor).
    A peak still rising at the end of the record is reported too (the caller flags truncation).
    """
    n = v.size
    out = np.empty(n // 2 + 1, dtype=np.int64)
    k = 0
    seeking_max = True
    cur = v[0]
    icur = 0
    i = 1
    while i < n:
        # A block in which no sample leaves the hysteresis band about the running extreme (which
        # the block itself may move, as on a pulse's slow rise) changes only that extreme and
        # its index: skip it on its (vectorised) max and min, else walk it sample by sample. Most
        # of a smoothed record is such blocks.
        stop = min(i + SKIP_BLOCK, n)
        if stop - i == SKIP_BLOCK:
            block = v[i:stop]
            hi = vmax(block)
            lo = vmin(block)
            if seeking_max and lo >= max(cur, hi) - delta:
                if hi > cur:
                    cur = hi
                    icur = i
                    while v[icur] != hi:
                        icur += 1
                i = stop
                continue
            if not seeking_max and hi <= min(cur, lo) + delta:
                if lo < cur:
                    cur = lo
                    icur = i
                    while v[icur] != lo:
                        icur += 1
                i = stop
                continue
        for j in range(i, stop):
            x = v[j]
            if seeking_max:
                if x > cur:
                    cur = x
                    icur = j
                elif x < cur - delta:
                    if cur > thr:
                        out[k] = icur
                        k += 1
                        seeking_max = False
                    cur = x
                    icur = j
            else:
                if x < cur:
                    cur = x
                    icur = j
                elif x > cur + delta:
                    seeking_max = True
                    cur = x
                    icur = j
        i = stop
    if seeking_max and cur > thr:
        out[k] = icur
        k += 1
    return out[:k]


@njit(cache=True)
def pulse_extent(v: np.ndarray, peak: int, level: float, lo: int, hi: int) -> tuple[int, int]:
    """First and last sample around ``peak`` where ``v`` stays above ``level``, within [lo, hi)."""
    a = peak
    while a > lo and v[a - 1] > level:
        a -= 1
    b = peak
    while b < hi - 1 and v[b + 1] > level:
        b += 1
    return a, b


@njit(cache=True)
def valley(v: np.ndarray, a: int, b: int) -> int:
    """Index of the smallest value of ``v`` in [a, b]."""
    best = a
    for i in range(a + 1, b + 1):
        if v[i] < v[best]:
            best = i
    return best


@njit(cache=True, fastmath={"reassoc", "contract"})
def _power_sums(x: np.ndarray, lo: int, hi: int, acc: np.ndarray) -> None:
    """Adds sum(u^k) for k = 1..4 and sum(u^k x) for k = 0..2 over samples lo..hi-1 to ``acc``
    (u = i / n). Reassociation lets the sums vectorise; they change only in rounding."""
    s1 = s2 = s3 = s4 = r0 = r1 = r2 = 0.0
    inv = 1.0 / x.size
    for i in range(lo, hi):
        u = i * inv
        p2 = u * u
        xi = x[i]
        s1 += u
        s2 += p2
        s3 += u * p2
        s4 += p2 * p2
        r0 += xi
        r1 += u * xi
        r2 += p2 * xi
    acc[0] += s1
    acc[1] += s2
    acc[2] += s3
    acc[3] += s4
    acc[4] += r0
    acc[5] += r1
    acc[6] += r2


@njit(cache=True)
def quadratic_fit(x: np.ndarray, runs: np.ndarray, degree: int) -> tuple[np.ndarray, int]:
    """Least-squares polynomial of ``degree`` (0-2) in u = i / n through the samples of ``runs``.

    ``runs[k] = (a, b)``: the samples a..b-1 take part (:func:`quiet_runs`); n is ``x.size``.
    Returns the coefficients (c0, c1, c2) (unused ones zero) and the number of samples used.
    Fewer than three samples, or a singular system, give a constant.
    """
    acc = np.zeros(7)
    count = 0
    for k in range(runs.shape[0]):
        _power_sums(x, runs[k, 0], runs[k, 1], acc)
        count += runs[k, 1] - runs[k, 0]
    s1, s2, s3, s4, r0, r1, r2 = acc[0], acc[1], acc[2], acc[3], acc[4], acc[5], acc[6]
    coef = np.zeros(3)
    if count == 0:
        return coef, 0
    m = np.empty((3, 3))
    m[0, 0] = float(count)
    m[0, 1] = m[1, 0] = s1
    m[0, 2] = m[1, 1] = m[2, 0] = s2
    m[1, 2] = m[2, 1] = s3
    m[2, 2] = s4
    rhs = np.array([r0, r1, r2])
    k = degree + 1
    if count < 3:
        k = 1
    sub = m[:k, :k].copy()
    if k > 1 and abs(np.linalg.det(sub)) < 1e-14 * m[0, 0] ** k:
        k = 1
        sub = m[:1, :1].copy()
    coef[:k] = np.linalg.solve(sub, rhs[:k].copy())
    return coef, count


@njit(cache=True)
def quiet_runs(centres: np.ndarray, reach: np.ndarray, n: int) -> np.ndarray:
    """Runs ``(a, b)`` (samples a..b-1) of 0..n-1 further than ``reach[j]`` from every
    ``centres[j]``: the complement of the union of the windows, in order."""
    m = centres.size
    starts = np.empty(m, dtype=np.int64)
    for j in range(m):
        starts[j] = centres[j] - reach[j]
    runs = np.empty((m + 1, 2), dtype=np.int64)
    k = 0
    free = 0  # first sample not yet covered by a window or a run
    for j in np.argsort(starts):
        a = max(0, starts[j])
        if a > free:
            runs[k, 0] = free
            runs[k, 1] = min(a, n)
            k += 1
        free = max(free, min(n, centres[j] + reach[j] + 1))
    if free < n:
        runs[k, 0] = free
        runs[k, 1] = n
        k += 1
    return runs[:k]


@njit(cache=True)
def run_count(runs: np.ndarray, lo: int, hi: int) -> int:
    """How many samples of ``runs`` lie in lo..hi-1."""
    count = 0
    for k in range(runs.shape[0]):
        count += max(0, min(runs[k, 1], hi) - max(runs[k, 0], lo))
    return count


@njit(cache=True)
def block_average(t: np.ndarray, y: np.ndarray, m: int) -> tuple[np.ndarray, np.ndarray]:
    """Average consecutive samples in blocks so that at most ``m`` points remain."""
    n = y.size
    q = (n + m - 1) // m
    if q <= 1:
        return t.copy(), y.copy()
    nb = n // q
    tb = np.empty(nb)
    yb = np.empty(nb)
    for j in range(nb):
        st = 0.0
        sy = 0.0
        for i in range(j * q, j * q + q):
            st += t[i]
            sy += y[i]
        tb[j] = st / q
        yb[j] = sy / q
    return tb, yb


@njit(cache=True)
def template(t: np.ndarray, p: np.ndarray, skew: float, f: np.ndarray, jac: np.ndarray) -> None:
    """Skewed super-Gaussian and its Jacobian in (A, tc, w, r).

    ``A exp(-|u|^r)`` with ``u = (t - tc) / (w (1 + skew sign(t - tc)))``: the peak is at ``tc``
    whatever the skew, and the half-widths on the two sides differ by the factor
    ``(1 + skew) / (1 - skew)``.
    """
    amp, tc, w, r = p[0], p[1], p[2], p[3]
    nfree = jac.shape[1]
    for i in range(t.size):
        d = t[i] - tc
        side = 1.0 + skew if d > 0 else 1.0 - skew
        ws = w * side
        a = abs(d) / ws
        if a > 0:
            la = np.log(a)
            g = np.exp(r * la)
            e = np.exp(-g)
            f[i] = amp * e
            jac[i, 0] = e
            jac[i, 1] = amp * e * r * g / a / ws * (1.0 if d > 0 else -1.0)
            jac[i, 2] = amp * e * r * g / w
            if nfree > 3:
                jac[i, 3] = -amp * e * g * la
        else:
            f[i] = amp
            jac[i, 0] = 1.0
            for k in range(1, nfree):
                jac[i, k] = 0.0


@njit(cache=True)
def solve_spd(a: np.ndarray, b: np.ndarray, x: np.ndarray) -> bool:
    """Solves ``a x = b`` for a small symmetric positive definite ``a`` by Cholesky, overwriting
    ``a`` with its factor; False (``x`` undefined) when ``a`` is not positive definite. The LM
    step's 3x3 or 4x4 system: a LAPACK call costs ten times the arithmetic here."""
    m = a.shape[0]
    for i in range(m):
        for j in range(i + 1):
            acc = a[i, j]
            for k in range(j):
                acc -= a[i, k] * a[j, k]
            if i == j:
                if not acc > 0.0:
                    return False
                a[i, i] = np.sqrt(acc)
            else:
                a[i, j] = acc / a[j, j]
    for i in range(m):
        acc = b[i]
        for k in range(i):
            acc -= a[i, k] * x[k]
        x[i] = acc / a[i, i]
    for i in range(m - 1, -1, -1):
        acc = x[i]
        for k in range(i + 1, m):
            acc -= a[k, i] * x[k]
        x[i] = acc / a[i, i]
    return True


@njit(cache=True)
def fit_pulse(
    t: np.ndarray, y: np.ndarray, p0: np.ndarray, skew: float, nfree: int, max_iter: int
) -> tuple[np.ndarray, bool]:
    """Levenberg-Marquardt fit of the skewed super-Gaussian to (t, y): (params, converged).

    Parameters are amplitude, peak time, width and shape exponent r; with ``nfree = 3`` the
    exponent stays at ``p0[3]``. ``t`` should be centred and in sample units and ``y`` scaled to
    the peak, so the normal equations are well conditioned. The whole pulse informs the peak time
    (both flanks), which makes it far less noisy than a parabola through the top.
    """
    n = t.size
    p = p0.copy()
    f = np.empty(n)
    jac = np.empty((n, nfree))
    template(t, p, skew, f, jac)
    cost = 0.0
    for i in range(n):
        cost += (y[i] - f[i]) ** 2
    lam = 1e-3
    trial = p.copy()
    ft = np.empty(n)
    jt = np.empty((n, nfree))
    jtj = np.empty((nfree, nfree))
    g = np.empty(nfree)
    a = np.empty((nfree, nfree))
    step = np.empty(nfree)
    tmin, tmax = t[0], t[n - 1]
    for _ in range(max_iter):
        for k in range(nfree):
            acc = 0.0
            for i in range(n):
                acc += jac[i, k] * (y[i] - f[i])
            g[k] = acc
            for q in range(k, nfree):
                acc = 0.0
                for i in range(n):
                    acc += jac[i, k] * jac[i, q]
                jtj[k, q] = acc
                jtj[q, k] = acc
        improved = False
        for _inner in range(8):
            a[:, :] = jtj
            for k in range(nfree):
                a[k, k] += lam * (jtj[k, k] + 1e-12)
            if not solve_spd(a, g, step):
                lam *= 10.0
                continue
            for k in range(nfree):
                trial[k] = p[k] + step[k]
            trial[1] = min(max(trial[1], tmin), tmax)
            trial[2] = max(trial[2], 0.25)
            trial[3] = min(max(trial[3], R_MIN), R_MAX)
            template(t, trial, skew, ft, jt)
            c = 0.0
            for i in range(n):
                c += (y[i] - ft[i]) ** 2
            if c <= cost:
                rel = abs(step[1]) + abs(step[0]) / max(abs(p[0]), 1e-12)
                p[:] = trial
                f[:] = ft
                jac[:, :] = jt
                small = cost - c <= 1e-10 * cost + 1e-300
                cost = c
                lam = max(lam * 0.3, 1e-9)
                improved = True
                if rel < 1e-7 or small:
                    return p, True
                break
            lam *= 10.0
        if not improved:
            return p, True  # no descent direction left: at a (local) minimum
    return p, False


@njit(cache=True)
def parabola_top(tb: np.ndarray, yb: np.ndarray) -> tuple[float, float, bool]:
    """Least-squares parabola through the top 30 % of (tb, yb): (peak time, peak value, ok)."""
    top = yb.max()
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    s3 = 0.0
    s4 = 0.0
    r0 = 0.0
    r1 = 0.0
    r2 = 0.0
    lo = np.inf
    hi = -np.inf
    count = 0
    for i in range(tb.size):
        if yb[i] > 0.7 * top:
            u = tb[i]
            s0 += 1
            s1 += u
            s2 += u * u
            s3 += u * u * u
            s4 += u * u * u * u
            r0 += yb[i]
            r1 += u * yb[i]
            r2 += u * u * yb[i]
            lo = min(lo, u)
            hi = max(hi, u)
            count += 1
    if count >= 3:
        m = np.array([[s0, s1, s2], [s1, s2, s3], [s2, s3, s4]])
        if abs(np.linalg.det(m)) > 1e-12 * max(s4, 1.0) ** 3:
            c0, c1, c2 = np.linalg.solve(m, np.array([r0, r1, r2]))
            if c2 < 0:
                tc = -c1 / (2 * c2)
                if lo <= tc <= hi:
                    return tc, c0 - c1 * c1 / (4 * c2), True
    return 0.0, 1.0, False


@njit(cache=True)
def _onset_pretrigger(s1: np.ndarray, ref: float) -> int:
    """Samples before the first rise (a first guess; refined once the pulses are known).

    The rise is the first crossing of a quarter of the largest excursion above ``ref``; its onset
    is where the lightly smoothed trace, walking back, falls to 2 % of it; half the rise is kept
    as a margin. Returns 0 when the record starts inside that rise (no pre-trigger exists).
    """
    n = s1.size
    big = max(0.0, vmax(s1) - ref)  # rounding is monotonic: max(s1[i] - ref) = max(s1) - ref
    if big <= 0:
        return max(MIN_PRETRIGGER, n // 10)
    cross = 0
    while s1[cross] - ref <= 0.25 * big:
        cross += 1
    onset = cross
    while onset > 0 and s1[onset - 1] - ref > 0.02 * big:
        onset -= 1
    if onset == 0:
        return 0
    guess = onset - max(8, (cross - onset) // 2)
    return min(max(guess, MIN_PRETRIGGER), max(n // 2, MIN_PRETRIGGER))


@njit(cache=True)
def _level_noise(y: np.ndarray, n_pre: int, ref: float, floor: float) -> tuple[float, float]:
    """Baseline and per-sample noise from the pre-trigger segment ``y[:n_pre]``.

    Median, and the MAD about the segment's least-squares line (slow drift is not noise). With no
    pre-trigger (``n_pre`` 0: the record starts inside a pulse) the record's median and the MAD of
    its first differences (the pulses are smooth on the sample scale) stand in.
    """
    if n_pre > 0:
        return median(y[:n_pre]), max(MAD_TO_SIGMA * detrended_mad(y[:n_pre]), floor)
    d = np.diff(y)
    med = median_inplace(d)
    for i in range(d.size):
        d[i] = abs(d[i] - med)
    return ref, max(MAD_TO_SIGMA * median_inplace(d) / np.sqrt(2.0), floor)


@njit(cache=True)
def _smoothed_noise(s: np.ndarray, n_pre: int, h: int, sigma: float, floor: float) -> float:
    """Noise of the smoothed trace: the smoother's gain (exact for white noise), or the MAD of
    the smoothed pre-trigger if larger (coloured noise). The latter only over at least eight
    smoother lengths: with fewer independent values it is itself too noisy to trust."""
    out = max(smoother_gain(h) * sigma, floor)
    if n_pre >= 8 * (4 * h + 1):
        out = max(out, MAD_TO_SIGMA * detrended_mad(s[:n_pre]))
    return out


@njit(cache=True)
def _fwhm(v: np.ndarray, peak: int, lo: int, hi: int) -> int:
    a, b = pulse_extent(v, peak, 0.5 * v[peak], lo, hi)
    return b - a + 1


@njit(cache=True)
def _peaks(v: np.ndarray, sigma_s: float, thr_sigma: float, min_ratio: float
           ) -> tuple[np.ndarray, float]:
    largest = vmax(v)
    thr = max(thr_sigma * sigma_s, min_ratio * largest)
    return find_peaks_hysteresis(v, thr, thr), thr


@njit(cache=True)
def _bounds(v: np.ndarray, peaks: np.ndarray) -> np.ndarray:
    """Valleys between consecutive peaks, with the record ends: pulse j lives in [b[j], b[j+1]]."""
    m = peaks.size
    b = np.empty(m + 1, dtype=np.int64)
    b[0] = 0
    for j in range(m - 1):
        b[j + 1] = valley(v, peaks[j], peaks[j + 1])
    b[m] = v.size - 1
    return b


@njit(cache=True)
def _widths(v: np.ndarray, peaks: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    m = peaks.size
    w = np.empty(m)
    for j in range(m):
        w[j] = _fwhm(v, peaks[j], bounds[j], bounds[j + 1] + 1)
    return w


@njit(cache=True)
def analyze(
    x: np.ndarray,
    sign_in: float,
    n_pre_in: int,
    h_in: int,
    thr_sigma: float,
    min_ratio: float,
    fit_fraction: float,
    shape_r: float,
    skew: float,
    free_r: bool,
    max_iter: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Detect and measure every pulse of one shot.

    Parameters
    ----------
    x:
        Samples, N.
    sign_in:
        +1 (pulses are positive), -1 (negative) or 0 (whichever excursion is larger).
    n_pre_in:
        Pre-trigger length in samples, or -1 to find it before the first rise.
    h_in:
        Half-width of the detection smoother, or -1 to follow the largest pulse's width.
    thr_sigma, min_ratio:
        A pulse rises ``thr_sigma`` smoothed-noise deviations and ``min_ratio`` of the largest
        pulse above the baseline, and stands out by as much from its neighbours.
    fit_fraction:
        The template is fitted to the part of each pulse above this fraction of its height.
    shape_r, skew, free_r:
        Template exponent (fitted too when ``free_r``) and skew; the first pulse gets ``+skew``,
        the later ones (travelling back up the chain) ``-skew``.
    max_iter:
        Levenberg-Marquardt iterations per pulse.

    Returns
    -------
    head, pulses:
        ``head[H_*]`` and one row ``pulses[j, P_*]`` per pulse, times in samples from the record
        start, amplitudes above each pulse's own baseline in the sign-corrected trace.
    """
    n = x.size
    head = np.zeros(HEAD)
    # Polarity, from the lightly smoothed trace against the record's median.
    step = max(1, n // 1024)
    ref = median(x[::step])
    csum, s1 = prefix_and_triangle(x, 2)
    sign = sign_in
    if sign == 0.0:
        sign = 1.0 if vmax(s1) - ref >= ref - vmin(s1) else -1.0
    y = x if sign > 0 else -x  # read only: a positive trace is used in place
    if sign < 0:
        s1 *= -1.0
    ref *= sign
    head[H_SIGN] = sign
    ymax = vmax(y)

    n_pre = n_pre_in if n_pre_in > 0 else _onset_pretrigger(s1, ref)
    if n_pre == 0:
        head[H_EARLY] = 1.0
    span = max(0.0, ymax - ref, ref - vmin(y))  # = max |y[i] - ref| (monotonic rounding)
    floor = NOISE_FLOOR * max(span, 1e-300)

    base, sigma = _level_noise(y, n_pre, ref, floor)
    line = np.full(n, base)

    # Smoother width: a sixth of the largest pulse's FWHM (a cheap stand-in for a matched filter).
    h = h_in if h_in >= 0 else 2
    s = s1 if h == 2 else triangle_prefix(x, csum, h, sign)
    v = s - line
    if h_in < 0:
        for _ in range(3):
            hn = max(1, _fwhm(v, vargmax(v), 0, n) // 6)
            if 2 * hn <= 3 * h and 3 * hn >= 2 * h:
                break
            h = hn
            s = triangle_prefix(x, csum, h, sign)
            for i in range(n):
                v[i] = s[i] - line[i]
    sigma_s = _smoothed_noise(s, n_pre, h, sigma, floor)
    peaks, thr = _peaks(v, sigma_s, thr_sigma, min_ratio)

    # Pre-trigger: everything before the first pulse's foot, once that pulse is known.
    if n_pre_in <= 0 and peaks.size > 0:
        p0 = peaks[0]
        new_pre = int(p0 - FOOT * _fwhm(v, p0, 0, n))
        if new_pre < MIN_PRETRIGGER:
            head[H_EARLY] = 1.0
            if n_pre > 0:  # keep what lies before the rise, if that is long enough
                new_pre = min(n_pre, max(p0 - 2 * h, 0))
            new_pre = new_pre if new_pre >= MIN_PRETRIGGER else 0
        # Re-estimate when the first guess reached into the rise, or when twice the samples
        # (noise matters for thresholds only: each pulse's own baseline is measured later).
        redo = (new_pre == 0) != (n_pre == 0) or new_pre < 0.9 * n_pre or new_pre > 2 * n_pre
        if redo:
            n_pre = new_pre
            base, sigma = _level_noise(y, n_pre, ref, floor)
            line[:] = base
            v = s - line
            sigma_s = _smoothed_noise(s, n_pre, h, sigma, floor)
            peaks, thr = _peaks(v, sigma_s, thr_sigma, min_ratio)

    # Slow trend (drift and the chain's slow level changes): a quadratic through the quiet samples,
    # those further than 2 FWHM from every pulse; twice, since the pulses depend on the line.
    for it in range(2):
        if peaks.size == 0:
            break
        bounds = _bounds(v, peaks)
        widths = _widths(v, peaks, bounds)
        # A drifting record can hold a wide hump that only looks like a pulse; solitary pulses in
        # one record differ in width by tens of percent, so no pulse hides more than 3 largest.
        cap = 3.0 * widths[np.argmax(v[peaks])]
        reach = np.empty(peaks.size, dtype=np.int64)
        for j in range(peaks.size):
            reach[j] = int(2.0 * min(widths[j], cap)) + 2 * h + 2
        quiet = quiet_runs(peaks, reach, n)
        count_pre = run_count(quiet, 0, n_pre)
        count_post = run_count(quiet, n_pre, n)
        late = run_count(quiet, 2 * n // 3, n) > 0
        middle = run_count(quiet, n // 3, 2 * n // 3) > 0
        if count_pre + count_post < 2 * MIN_PRETRIGGER or count_post < MIN_PRETRIGGER:
            break
        coef, _ = quadratic_fit(y, quiet, 2 if late and middle else 1)
        c0, c1, c2 = coef[0], coef[1], coef[2]
        inv = 1.0 / n
        for i in range(n):
            u = i * inv
            line[i] = c0 + u * (c1 + u * c2)
            v[i] = s[i] - line[i]
        before = peaks
        peaks, thr = _peaks(v, sigma_s, thr_sigma, min_ratio)
        if it == 0 and peaks.size == before.size and np.all(np.abs(peaks - before) <= h):
            break  # the same pulses: the quiet samples, hence the line, would not change

    head[H_BASE] = base
    head[H_SIGMA] = sigma
    head[H_THR] = thr
    head[H_NPRE] = n_pre
    head[H_SMOOTH] = h
    m = peaks.size
    head[H_NPEAKS] = m
    out = np.zeros((m, PULSE))
    if m == 0:
        return head, out

    bounds = _bounds(v, peaks)
    widths = _widths(v, peaks, bounds)
    nfree = 4 if free_r else 3
    prev_end = 0
    for j in range(m):
        ip = peaks[j]
        lo, hi = bounds[j], bounds[j + 1]
        wj = widths[j]
        row = out[j]
        # Baseline: the level (about the slow trend) the sensor holds before the pulse's foot.
        stop = int(ip - FOOT * wj)
        start = max(prev_end, int(stop - LEVEL_SPAN * wj))
        level = 0.0
        if stop - start >= MIN_PRETRIGGER:
            acc = 0.0
            for i in range(start, stop):
                acc += y[i] - line[i]
            level = acc / (stop - start)
            row[P_LEVEL] = 1.0
        prev_end = min(n, int(ip + FOOT * wj) + 1)
        base_j = line[ip] + level
        top = s[ip] - base_j
        if top <= 0:
            top = v[ip]
            level = 0.0
            base_j = line[ip]
        fa, fb = pulse_extent(v, ip, level + fit_fraction * top, lo, hi + 1)
        reach = int(TRUNC_SPAN * wj) + 1
        trunc = (fa <= 0 and ip - reach < 0) or (fb >= n - 1 and ip + reach > n - 1)
        fa = max(fa, ip - reach)
        fb = min(fb, ip + reach)
        if fb - fa < 8:
            fa, fb = max(0, ip - 4), min(n - 1, ip + 4)
        k = fb - fa + 1
        tt = np.empty(k)
        yy = np.empty(k)
        for i in range(k):
            tt[i] = fa + i - ip
            yy[i] = (y[fa + i] - line[fa + i] - level) / top
        tb, yb = block_average(tt, yy, MAX_FIT_POINTS)
        ha, hb = pulse_extent(v, ip, v[ip] - 0.5 * top, lo, hi + 1)
        p0 = np.array([1.0, 0.0, 0.5 * max(hb - ha, 2) / np.log(2.0) ** (1.0 / shape_r), shape_r])
        sk = skew if j == 0 else -skew
        p, ok = fit_pulse(tb, yb, p0, sk, nfree, max_iter)
        method = 0.0
        if ok and 0.2 < p[0] < 5.0 and tb[0] < p[1] < tb[-1]:
            width = 2.0 * p[2] * np.log(2.0) ** (1.0 / p[3])
            t_pk = p[1]
            amp = p[0]
        else:
            method = 1.0
            t_pk, amp, good = parabola_top(tb, yb)
            if not good:
                t_pk, amp = 0.0, 1.0
            width = float(hb - ha + 1)
        a, b = pulse_extent(v, ip, 0.5 * thr, lo, hi + 1)
        row[P_TIME] = ip + t_pk
        row[P_AMP] = amp * top
        row[P_BASE] = base_j
        row[P_WIDTH] = width
        row[P_ONSET] = a
        row[P_END] = b
        row[P_INDEX] = ip
        row[P_METHOD] = method
        row[P_TRUNC] = 1.0 if trunc else 0.0
        row[P_MERGED] = 1.0 if (j + 1 < m and v[bounds[j + 1]] > 0.5 * thr) else 0.0

    # No reflection: the largest excursion after the incident's foot bounds the ARR from above.
    first = min(n, int(peaks[0] + FOOT * widths[0]) + 1)
    after = max(0.0, vmax(v[first:])) if first < n else 0.0
    head[H_UPPER] = max(thr, after) / max(out[0, P_AMP], 1e-300)

    # Clipping: the record's top value repeats over more than a twentieth of the incident's width.
    top = ymax - 1e-9 * max(abs(ymax), 1e-300)
    count = 0
    for i in range(n):
        count += y[i] >= top
    head[H_SATURATED] = 1.0 if count >= max(3.0, 0.05 * out[0, P_WIDTH]) else 0.0
    return head, out


@njit(cache=True, nogil=True)
def analyze_batch(
    x: np.ndarray,
    sign_in: float,
    n_pre_in: int,
    h_in: int,
    thr_sigma: float,
    min_ratio: float,
    fit_fraction: float,
    shape_r: float,
    skew: float,
    free_r: bool,
    max_iter: int,
    keep: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`analyze` of every row of ``x`` (one shot per row), without the GIL (callers split
    the rows over threads).

    Returns ``heads[i, H_*]``, the first ``keep`` pulse rows of each shot ``pulses[i, j, P_*]``
    (zero past its count) and the count of pulses of each shot.
    """
    m = x.shape[0]
    heads = np.zeros((m, HEAD))
    pulses = np.zeros((m, keep, PULSE))
    counts = np.zeros(m, dtype=np.int64)
    for i in range(m):
        head, rows = analyze(x[i], sign_in, n_pre_in, h_in, thr_sigma, min_ratio, fit_fraction,
                             shape_r, skew, free_r, max_iter)
        heads[i] = head
        counts[i] = rows.shape[0]
        for j in range(min(rows.shape[0], keep)):
            pulses[i, j] = rows[j]
    return heads, pulses, counts
