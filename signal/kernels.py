"""Numba kernels behind pulse detection: the whole search-and-measure pass of one shot.

:func:`analyze` does everything that touches the samples: pre-trigger segment, baseline and noise,
smoothing, peak search, drift, and the template fit of every pulse. Its parts live beside it:
:mod:`.smoothing` (prefix-sum filters), :mod:`.robust` (medians and MAD), :mod:`.pulse_fit` (the
pulse model and its fit); the names are re-exported here. It returns plain arrays
(:data:`HEAD` and :data:`PULSE` name their columns), so a 10,000-sample shot costs a few O(n)
passes and no Python work per sample or per pulse; :mod:`solitonde.signal.pulses` only turns the
arrays into objects.

The kernels are written in loops over scalars and preallocated arrays, without numpy's sorting,
linear algebra, ``np.diff``, array arithmetic (``s - line``) or whole-array assignments
(``a[i] = row``): for each of those numba compiles a tree of helper functions of its own (a
quicksort, LAPACK wrappers, broadcasting checks with their error messages), and together they
were about a quarter of the time a fresh install spent compiling :func:`analyze`, for no
run-time gain on records of this size.

Each function is compiled once. numba types a constant passed to a compiled function as that
literal (``Literal[int](0)``) and compiles the callee for it apart from ``int64``, also for a
loop variable that starts as a constant: such arguments are ``np.int64(...)``. The small helpers
are compiled with ``inline="always"``: typed inside each caller for whatever it passes (the
read-only record or a writable work array, a literal or not), they cost no compilation of their
own. None of them carries ``fastmath`` flags, which an inlined body would take from its caller.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .extrema import vargmax, vargmin, vmax, vmin, vminmax
from .gap_drift import D_GAP, D_MISFIT, D_MISFIT_N, drift_at, gap_drift
from .peak_refine import LADDER, common_rung, pre_impact_baseline, refine_peak
from .pulse_fit import (  # noqa: F401
    R_MAX,
    R_MIN,
    fit_pulse,
    parabola_top,
    solve_lu,
    solve_spd,
    template,
)
from .robust import MAD_POINTS, detrended_mad, kth_smallest, median  # noqa: F401
from .smoothing import (  # noqa: F401
    prefix_and_triangle,
    prefix_sum,
    smoother_gain,
    triangle,
    triangle_prefix,
)

MAX_FIT_POINTS = 64
"""A longer fit window is block-averaged down to this (the pulse is smooth on that scale)."""

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

BASELINE_SPAN = 3.0
"""The pre-impact baseline is measured on the pre-trigger samples at least this many FWHM before
the incident's peak."""

TRUNC_SPAN = 2.5
"""A pulse counts as truncated when the record ends (or starts) within this many FWHM of its peak
while the pulse is still above ``fit_fraction`` of its height."""

# Columns of the head array returned by analyze and locate (H_PRE0, H_PRE1: the pre-impact baseline
# H_PRE0 + H_PRE1 * i at sample i, in the sign-corrected trace).
# H_TRAIN: pulses between the incident and a gated reflection (the incident's train); H_NOREF: 1
# when the travel gate holds no pulse (the later pulses are then all secondary).
# H_SIGMA_S, H_FLOOR, H_YMAX: the smoothed trace's noise, the noise floor and the largest sample of
# the sign-corrected trace, which locate hands to measure. H_GAP: the gap samples the drift was
# measured on besides the pre-trigger (gap_drift; 0: the pre-trigger's baseline); H_MISFIT,
# H_MISFIT_N: that fit's largest mean residual over one of its stretches and the stretch's samples.
(H_SIGN, H_BASE, H_SIGMA, H_THR, H_NPRE, H_SMOOTH, H_NPEAKS, H_EARLY, H_SATURATED,
 H_UPPER, H_PRE0, H_PRE1, H_TRAIN, H_NOREF, H_SIGMA_S, H_FLOOR, H_YMAX, H_GAP, H_MISFIT,
 H_MISFIT_N) = range(20)
HEAD = 20

GATE_LO, GATE_HI = 0.75, 3.2
"""With a travel gate, a reflection arrives between these multiples of the round trip at the
incident's solitary-wave speed after the incident: never faster than the incident itself came
down (less a margin for the wave's width and the sensor's place in it); at most that slow when the
reflection is a fiftieth of the incident (its speed then 0.52 of the incident's, F^(1/6)) and the
plate held the last sphere for another round trip."""
# Columns of the per-pulse array returned by analyze (times and widths in samples). P_TIME and
# P_AMP are the fitted template's peak time and its height above the pre-impact baseline P_BASE
# (at that time): a fixed estimator, whose mean under noise is its noise-free value. P_PEAK_TIME
# and P_PEAK_AMP are the peak refined on the data's top (the trace's own peak when clean; see
# peak_refine), P_RISE the template's height above the level the sensor holds just before the
# pulse (P_LEVEL_N; drift-immune), P_METHOD 0 template, 1 parabola (template fit failed), 2 the
# peak refined on the data's top. P_RUNG is the refinement rung the refined value comes from
# (peak_refine.LADDER; its length: the template), P_VALUES.. the value on every rung (NaN where
# unusable), in the trace's units.
(P_TIME, P_AMP, P_BASE, P_WIDTH, P_ONSET, P_END, P_INDEX, P_METHOD, P_TRUNC, P_MERGED,
 P_LEVEL, P_RISE, P_LEVEL_N, P_RUNG, P_PEAK_TIME, P_PEAK_AMP, P_VALUES) = range(17)
PULSE = P_VALUES + len(LADDER) + 1


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


SKIP_BLOCK = 32
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


@njit(cache=True, inline="always")
def pulse_extent(v: np.ndarray, peak: int, level: float, lo: int, hi: int) -> tuple[int, int]:
    """First and last sample around ``peak`` where ``v`` stays above ``level``, within [lo, hi)."""
    a = peak
    while a > lo and v[a - 1] > level:
        a -= 1
    b = peak
    while b < hi - 1 and v[b + 1] > level:
        b += 1
    return a, b


@njit(cache=True, inline="always")
def valley(v: np.ndarray, a: int, b: int) -> int:
    """Index of the (first) smallest value of ``v`` in [a, b]: vectorised, where a running
    minimum's index is a chain of dependent comparisons (thousands of samples between pulses)."""
    return a + vargmin(v[a : b + 1])


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
    coef = np.zeros(3)
    if count == 0:
        return coef, 0
    # power sums: sum(u^0) = count, then acc[0..3]; right-hand sides acc[4..6]
    sums = np.empty(5)
    sums[0] = float(count)
    for i in range(4):
        sums[i + 1] = acc[i]
    k = degree + 1
    if count < 3:
        k = 1
    if k > 1:
        m = np.empty((k, k))
        rhs = np.empty(k)
        for i in range(k):
            rhs[i] = acc[4 + i]
            for j in range(k):
                m[i, j] = sums[i + j]
        if abs(solve_lu(m, rhs, coef)) < 1e-14 * sums[0] ** k:
            coef[:] = 0.0
            k = 1
    if k == 1:
        coef[0] = acc[4] / sums[0]
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
    # the windows by start: a handful of pulses, so an insertion sort (ties in any order give the
    # same runs)
    order = np.empty(m, dtype=np.int64)
    for j in range(m):
        i = j
        while i > 0 and starts[order[i - 1]] > starts[j]:
            order[i] = order[i - 1]
            i -= 1
        order[i] = j
    free = 0  # first sample not yet covered by a window or a run
    for j in order:  # type: ignore[assignment]
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


@njit(cache=True, inline="always")
def run_count(runs: np.ndarray, lo: int, hi: int) -> int:
    """How many samples of ``runs`` lie in lo..hi-1."""
    count = 0
    for k in range(runs.shape[0]):
        count += max(0, min(runs[k, 1], hi) - max(runs[k, 0], lo))
    return count


@njit(cache=True)
def block_average(t: np.ndarray, y: np.ndarray, w: np.ndarray, m: int
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted means of consecutive samples in blocks so that at most ``m`` points remain, and
    each block's total weight (the last block takes what is left)."""
    n = y.size
    q = max((n + m - 1) // m, 1)
    nb = (n + q - 1) // q
    tb = np.empty(nb)
    yb = np.empty(nb)
    wb = np.empty(nb)
    for j in range(nb):
        st = 0.0
        sy = 0.0
        sw = 0.0
        e = min(n, j * q + q)
        for i in range(j * q, e):
            st += w[i] * t[i]
            sy += w[i] * y[i]
            sw += w[i]
        if sw > 0.0:
            tb[j] = st / sw
            yb[j] = sy / sw
        else:  # a window end that lies on a sample's edge: the block counts for nothing
            tb[j] = 0.5 * (t[j * q] + t[e - 1])
            yb[j] = y[j * q]
        wb[j] = sw
    return tb, yb, wb


@njit(cache=True)
def _onset_pretrigger(s1: np.ndarray, ref: float, top: float) -> int:
    """Samples before the first rise (a first guess; refined once the pulses are known).

    The rise is the first crossing of a quarter of the largest excursion above ``ref``; its onset
    is where the lightly smoothed trace, walking back, falls to 2 % of it; half the rise is kept
    as a margin. Returns 0 when the record starts inside that rise (no pre-trigger exists).
    """
    n = s1.size
    big = max(0.0, top - ref)  # rounding is monotonic: max(s1[i] - ref) = max(s1) - ref
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
    d = np.empty(y.size - 1)
    for i in range(d.size):
        d[i] = y[i + 1] - y[i]
    med = median(d)
    for i in range(d.size):
        d[i] = abs(d[i] - med)
    return ref, max(MAD_TO_SIGMA * median(d) / np.sqrt(2.0), floor)


@njit(cache=True, inline="always")
def _smoothed_noise(s: np.ndarray, n_pre: int, h: int, sigma: float, floor: float) -> float:
    """Noise of the smoothed trace: the smoother's gain (exact for white noise), or the MAD of
    the smoothed pre-trigger if larger (coloured noise). The latter only over at least eight
    smoother lengths: with fewer independent values it is itself too noisy to trust."""
    out = max(smoother_gain(h) * sigma, floor)
    if n_pre >= 8 * (4 * h + 1):
        out = max(out, MAD_TO_SIGMA * detrended_mad(s[:n_pre]))
    return out


@njit(cache=True, inline="always")
def _fwhm(v: np.ndarray, peak: int, lo: int, hi: int) -> int:
    a, b = pulse_extent(v, peak, 0.5 * v[peak], lo, hi)
    return b - a + 1


@njit(cache=True, inline="always")
def _peaks(v: np.ndarray, sigma_s: float, thr_sigma: float, min_ratio: float
           ) -> tuple[np.ndarray, float]:
    largest = vmax(v)
    thr = max(thr_sigma * sigma_s, min_ratio * largest)
    return find_peaks_hysteresis(v, thr, thr), thr


@njit(cache=True, inline="always")
def _bounds(v: np.ndarray, peaks: np.ndarray) -> np.ndarray:
    """Valleys between consecutive peaks, with the record ends: pulse j lives in [b[j], b[j+1]]."""
    m = peaks.size
    b = np.empty(m + 1, dtype=np.int64)
    b[0] = 0
    for j in range(m - 1):
        b[j + 1] = valley(v, peaks[j], peaks[j + 1])
    b[m] = v.size - 1
    return b


@njit(cache=True, inline="always")
def _widths(v: np.ndarray, peaks: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    m = peaks.size
    w = np.empty(m)
    for j in range(m):
        w[j] = _fwhm(v, peaks[j], bounds[j], bounds[j + 1] + 1)
    return w


@njit(cache=True)
def _polarity(x: np.ndarray, sign_in: float
              ) -> tuple[float, float, np.ndarray, np.ndarray, float]:
    """(sign, record median in the sign-corrected trace, prefix sums, lightly smoothed trace
    (sign-corrected), that trace's largest value): the polarity from the smoothed trace against
    the record's median."""
    # The running sums first: the first pass over a shot's samples, which arrive from memory
    # while the sums wait on their own additions; the strided samples are then in cache.
    csum, s1 = prefix_and_triangle(x, np.int64(2))  # type: ignore[arg-type]  # int64, not a literal
    step = max(1, x.size // 1024)
    spread = np.empty((x.size + step - 1) // step)  # every step-th sample
    for i in range(spread.size):
        spread[i] = x[i * step]
    ref = median(spread)
    low, high = vminmax(s1)
    sign = sign_in
    if sign == 0.0:
        sign = 1.0 if high - ref >= ref - low else -1.0
    if sign < 0:
        for i in range(s1.size):
            s1[i] = -s1[i]
    return sign, ref * sign, csum, s1, high if sign > 0 else -low  # negation is exact


@njit(cache=True)
def _smoother(x: np.ndarray, csum: np.ndarray, s1: np.ndarray, line: np.ndarray, sign: float,
              h_in: int) -> tuple[int, np.ndarray, np.ndarray]:
    """(h, smoothed trace s, s - line): ``h_in``, or a sixth of the largest pulse's FWHM (a cheap
    stand-in for a matched filter), iterated until it settles."""
    n = x.size
    h = h_in if h_in >= 0 else 2
    s = s1 if h == 2 else triangle_prefix(x, csum, h, sign)
    v = np.empty(n)
    for i in range(n):
        v[i] = s[i] - line[i]
    if h_in < 0:
        for _ in range(3):
            hn = max(1, _fwhm(v, vargmax(v), 0, n) // 6)
            if 2 * hn <= 3 * h and 3 * hn >= 2 * h:
                break
            h = hn
            s = triangle_prefix(x, csum, h, sign)
            for i in range(n):
                v[i] = s[i] - line[i]
    return h, s, v


@njit(cache=True, inline="always")
def _pretrigger_after_peaks(v: np.ndarray, peaks: np.ndarray, n_pre: int, h: int
                            ) -> tuple[int, bool, bool]:
    """(pre-trigger length, early onset, whether to re-estimate): everything before the first
    pulse's foot, once that pulse is known."""
    p0 = peaks[0]
    early = False
    new_pre = int(p0 - FOOT * _fwhm(v, p0, 0, v.size))
    if new_pre < MIN_PRETRIGGER:
        early = True
        if n_pre > 0:  # keep what lies before the rise, if that is long enough
            new_pre = min(n_pre, max(p0 - 2 * h, 0))
        new_pre = new_pre if new_pre >= MIN_PRETRIGGER else 0
    # Re-estimate when the first guess reached into the rise, or when twice the samples
    # (noise matters for thresholds only: each pulse's own baseline is measured later).
    redo = (new_pre == 0) != (n_pre == 0) or new_pre < 0.9 * n_pre or new_pre > 2 * n_pre
    return new_pre, early, redo


@njit(cache=True)
def _quiet_fit(y: np.ndarray, v: np.ndarray, peaks: np.ndarray, widths: np.ndarray,
               n_pre: int, h: int, end: int) -> tuple[bool, float, float, float]:
    """The slow trend of ``y[:end]``: (whether fitted, c0, c1, c2) of the polynomial in
    u = i / end through its quiet samples, those further than 2 FWHM (and the smoother's reach)
    from every pulse. A quadratic where quiet samples lie both in the middle and the last third
    of ``y[:end]``, else a line (a quadratic would bend freely where nothing holds it); no fit
    where fewer than 2 MIN_PRETRIGGER quiet samples, or fewer than MIN_PRETRIGGER after the
    pre-trigger, are left."""
    # A drifting record can hold a wide hump that only looks like a pulse; solitary pulses in
    # one record differ in width by tens of percent, so no pulse hides more than 3 largest.
    big = 0  # the largest pulse (the first of equals)
    for j in range(1, peaks.size):
        if v[peaks[j]] > v[peaks[big]]:
            big = j
    cap = 3.0 * widths[big]
    reach = np.empty(peaks.size, dtype=np.int64)
    for j in range(peaks.size):
        reach[j] = int(2.0 * min(widths[j], cap)) + 2 * h + 2
    quiet = quiet_runs(peaks, reach, end)
    count_pre = run_count(quiet, 0, n_pre)
    count_post = run_count(quiet, n_pre, end)
    if count_pre + count_post < 2 * MIN_PRETRIGGER or count_post < MIN_PRETRIGGER:
        return False, 0.0, 0.0, 0.0
    late = run_count(quiet, 2 * end // 3, end) > 0
    middle = run_count(quiet, end // 3, 2 * end // 3) > 0
    coef, _ = quadratic_fit(y[:end], quiet, 2 if late and middle else 1)
    return True, coef[0], coef[1], coef[2]


@njit(cache=True)
def _same_pulses(peaks: np.ndarray, before: np.ndarray, h: int) -> bool:
    """Whether ``peaks`` are ``before``'s pulses, each within ``h`` samples."""
    if peaks.size != before.size:
        return False
    for j in range(peaks.size):  # noqa: SIM110 (numba compiles no generator inside all())
        if abs(peaks[j] - before[j]) > h:
            return False
    return True


@njit(cache=True)
def _in_gate(times: np.ndarray, incident_amp: float, gate_1n: float) -> tuple[int, float]:
    """(index of the first pulse after ``times[0]``, the incident's, inside the travel gate, or
    -1; the trip ``gate_1n F_inc^(-1/6)`` in samples). The gate runs from :data:`GATE_LO` to
    :data:`GATE_HI` trips after the incident."""
    trip = gate_1n * max(incident_amp, 1e-300) ** (-1.0 / 6.0)
    for j in range(1, times.size):
        delay = times[j] - times[0]
        if GATE_LO * trip <= delay <= GATE_HI * trip:
            return j, trip
    return -1, trip


@njit(cache=True)
def _trend(y: np.ndarray, s: np.ndarray, v: np.ndarray, line: np.ndarray, peaks: np.ndarray,
           n_pre: int, h: int, sigma_s: float, thr_sigma: float, min_ratio: float,
           thr: float) -> tuple[np.ndarray, float]:
    """Fit the slow trend (drift and the chain's slow level changes) into ``line`` (and ``v``):
    :func:`_quiet_fit` on the whole record, twice, since the pulses depend on the line. Returns
    the pulses and threshold on the new line."""
    n = y.size
    for it in range(2):
        if peaks.size == 0:
            break
        widths = _widths(v, peaks, _bounds(v, peaks))
        fitted, c0, c1, c2 = _quiet_fit(y, v, peaks, widths, n_pre, h, n)
        if not fitted:
            break
        inv = 1.0 / n
        for i in range(n):
            u = i * inv
            line[i] = c0 + u * (c1 + u * c2)
            v[i] = s[i] - line[i]
        before = peaks
        peaks, thr = _peaks(v, sigma_s, thr_sigma, min_ratio)
        if it == 0 and _same_pulses(peaks, before, h):
            break  # the same pulses: the quiet samples, hence the line, would not change
    return peaks, thr


@njit(cache=True)
def _reflection_trend(y: np.ndarray, s: np.ndarray, v: np.ndarray, line: np.ndarray,
                      peaks: np.ndarray, n_pre: int, h: int, thr: float, gate_1n: float
                      ) -> np.ndarray:
    """Refit the slow trend before the reflection on the record as it stands
    :data:`TRUNC_SPAN` FWHM after the reflection's peak, so that the incident and the
    reflection read the same however long the record runs on.

    :func:`_trend` fits one quadratic through the quiet samples of the whole record, and after
    the reflection the chain's own level (gravity) bends it: the same clean trace read ARR up to
    1 % apart (D 19.05 mm) as its record ended 2.6, 4 or 10 FWHM after the reflection. A record
    that holds the reflection whole holds ``TRUNC_SPAN`` FWHM after its peak, so the trend is
    refitted there, :func:`_quiet_fit` on the record cut there as :func:`_trend` fits a whole
    record, and beyond the cut the whole record's trend is kept, shifted to meet it (a constant
    moves no later pulse's rise). The reflection is the first pulse inside the travel gate (as
    :func:`_gate_reflection` picks it, on ``v``); without a gate, a pulse in it, or a record
    that runs on past the cut, nothing changes. The pulses stay the whole record's: where the
    new line would add or drop one (a step of the level between the pulses, bent into a hump
    that a pulse's test passes), the pulses found on the whole record's are kept and measured on
    the new line, so that such a shot still fails the gap's drift fit (``unsteady_baseline``)
    instead of hiding the step as a pulse. Returns the pulses (their peaks on the new line
    otherwise); ``line`` and ``v`` are updated in place."""
    n = y.size
    for _ in range(2):
        m = peaks.size
        if gate_1n <= 0 or m < 2:
            return peaks
        pick, _ = _in_gate(peaks, v[peaks[0]], gate_1n)
        if pick < 0:
            return peaks
        widths = _widths(v, peaks, _bounds(v, peaks))
        cut = int(peaks[pick] + TRUNC_SPAN * widths[pick]) + 1
        if cut >= n:
            return peaks
        fitted, c0, c1, c2 = _quiet_fit(y, v, peaks, widths, n_pre, h, cut)
        if not fitted:
            return peaks
        shift = c0 + c1 + c2 - line[cut]  # the cut's trend at u = 1 against the record's there
        inv = 1.0 / cut
        for i in range(n):
            if i < cut:
                u = i * inv
                line[i] = c0 + u * (c1 + u * c2)
            else:
                line[i] += shift
            v[i] = s[i] - line[i]
        before = peaks
        peaks = find_peaks_hysteresis(v, thr, thr)
        if peaks.size != before.size:
            return before  # the pulses are the whole record's: a refit adds or drops none
        if _same_pulses(peaks, before, h):
            break  # the same pulses: the quiet samples, hence the line, would not change
    return peaks


@njit(cache=True)
def _measure_pulse(y: np.ndarray, s: np.ndarray, v: np.ndarray, line: np.ndarray, ip: int,
                   lo: int, hi: int, wj: float, prev_end: int, thr: float, fit_fraction: float,
                   shape_r: float, sk: float, nfree: int, max_iter: int, sigma: float,
                   pre: np.ndarray, row: np.ndarray) -> int:
    """Fill ``row[P_*]`` for the pulse at sample ``ip`` (between valleys ``lo`` and ``hi``, width
    ``wj``): the level before it, the template fit to its top (a parabola when the fit fails),
    then the peak refined on the data (:func:`refine_peak`) and measured above the pre-impact
    baseline ``pre[0] + pre[1] * i`` (``pre[2]`` 0: no pre-trigger, the slow trend stands in).
    Returns where this pulse's foot ends (the next pulse's baseline starts after it)."""
    n = y.size
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
    end = min(n, int(ip + FOOT * wj) + 1)
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
    # The window's ends where v crosses the level, between samples: each sample weighs the part
    # of its own interval inside, so the fit moves continuously with the sampling phase.
    thr_fit = level + fit_fraction * top
    ta = float(fa) - 0.5
    tz = float(fb) + 0.5
    if fa > lo and fa - 1 >= 0 and v[fa] > thr_fit >= v[fa - 1]:
        ta = fa - 1 + (thr_fit - v[fa - 1]) / (v[fa] - v[fa - 1])
        fa -= 1
    if fb < hi and fb + 1 < n and v[fb] > thr_fit >= v[fb + 1]:
        tz = fb + (v[fb] - thr_fit) / (v[fb] - v[fb + 1])
        fb += 1
    k = fb - fa + 1
    tt = np.empty(k)
    yy = np.empty(k)
    ww = np.empty(k)
    for i in range(k):
        tt[i] = fa + i - ip
        yy[i] = (y[fa + i] - line[fa + i] - level) / top
        ww[i] = min(max(min(fa + i + 0.5, tz) - max(fa + i - 0.5, ta), 0.0), 1.0)
    tb, yb, wb = block_average(tt, yy, ww, MAX_FIT_POINTS)
    ha, hb = pulse_extent(v, ip, v[ip] - 0.5 * top, lo, hi + 1)
    p0 = np.array([1.0, 0.0, 0.5 * max(hb - ha, 2) / np.log(2.0) ** (1.0 / shape_r), shape_r])
    p, ok = fit_pulse(tb, yb, wb, p0, sk, nfree, max_iter)
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
    # The template's peak in the trace's units, then the peak refined on the data's top: the
    # template's shape is fixed, a pulse's is not (skewed or flat-topped reflections).
    t_fit = ip + t_pk
    top_fit = base_j + amp * top
    half = 0.5 * width * 1.0 / np.log(2.0) ** (1.0 / shape_r)
    values = row[P_VALUES:P_VALUES + len(LADDER) + 1]
    t_ref, top_ref, refined, rung = refine_peak(y, t_fit, top_fit, amp * top, half, shape_r, a,
                                                b, sigma, values)
    row[P_RUNG] = rung
    if refined:
        method = 2.0
    i_fit = min(max(round(t_fit), 0), n - 1)
    base_pre = pre[0] + pre[1] * t_fit if pre[2] > 0 else line[i_fit]
    row[P_TIME] = t_fit
    row[P_AMP] = top_fit - base_pre
    row[P_BASE] = base_pre
    i_ref = min(max(round(t_ref), 0), n - 1)
    row[P_PEAK_TIME] = t_ref
    row[P_PEAK_AMP] = top_ref - (pre[0] + pre[1] * t_ref if pre[2] > 0 else line[i_ref])
    row[P_RISE] = amp * top
    row[P_LEVEL_N] = base_j
    row[P_WIDTH] = width
    row[P_ONSET] = a
    row[P_END] = b
    row[P_INDEX] = ip
    row[P_METHOD] = method
    row[P_TRUNC] = 1.0 if trunc else 0.0
    return end


@njit(cache=True)
def _gate_reflection(out: np.ndarray, gate_1n: float, head: np.ndarray) -> np.ndarray:
    """The rows reordered so that the reflection, the first pulse inside the travel gate
    (:data:`GATE_LO`, :data:`GATE_HI` times ``gate_1n F_inc^(-1/6)`` samples after the incident),
    comes second; the pulses before it (the incident's train) follow it, then the later ones, in
    time order. No pulse inside the gate sets ``head[H_NOREF]``."""
    m = out.shape[0]
    pick, trip = _in_gate(out[:, P_TIME], out[0, P_AMP], gate_1n)
    if pick < 0:
        head[H_NOREF] = 1.0
        head[H_TRAIN] = 0.0
        for j in range(1, m):
            if out[j, P_TIME] - out[0, P_TIME] < GATE_LO * trip:
                head[H_TRAIN] += 1.0
        return out
    head[H_TRAIN] = pick - 1
    if pick == 1:
        return out
    order = np.empty(m, dtype=np.int64)
    order[0] = 0
    order[1] = pick
    k = 2
    for j in range(1, m):
        if j != pick:
            order[k] = j
            k += 1
    moved = np.empty_like(out)
    for j in range(m):
        for c in range(out.shape[1]):
            moved[j, c] = out[order[j], c]
    return moved


@njit(cache=True, inline="always")
def _negated(x: np.ndarray) -> np.ndarray:
    """``-x`` as a new array."""
    out = np.empty(x.size)
    for i in range(x.size):
        out[i] = -x[i]
    return out


@njit(cache=True, inline="always")
def _saturated(y: np.ndarray, ymax: float, incident_width: float) -> bool:
    """Clipping: the record's top value repeats over more than a twentieth of the incident's
    width."""
    top = ymax - 1e-9 * max(abs(ymax), 1e-300)
    count = 0
    for i in range(y.size):
        count += y[i] >= top
    return count >= max(3.0, 0.05 * incident_width)


LOCATE_ARGS = 5
"""How many of :func:`analyze`'s arguments after the samples are :func:`locate`'s; the rest are
:func:`measure`'s."""


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
    gate_1n: float,
    relax: np.ndarray,
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
    gate_1n:
        Sensor-to-plate-and-back travel time, in samples, of a solitary wave of unit peak (the
        trace's units); the reflection is then gated (:func:`_gate_reflection`). 0: no gate,
        the pulse after the incident is the reflection.
    relax:
        The chain's own level after the incident, above the pre-impact reading, one value per
        sample from the incident's peak on (a model trace of the chain, :mod:`.gap_drift`); the
        drift is then measured on the gap before the reflection too. Empty: the pre-trigger's
        baseline.

    The work is :func:`locate` then :func:`measure`, two compilations of about equal size,
    which a fresh install compiles side by side and this function then links
    (:mod:`solitonde.signal.precompile`); the per-shot path
    (:func:`solitonde.signal.pulses.detect`) and :func:`analyze_batch` call it.

    Returns
    -------
    head, pulses:
        ``head[H_*]`` and one row ``pulses[j, P_*]`` per pulse, times in samples from the record
        start, amplitudes above each pulse's own baseline in the sign-corrected trace.
    """
    head, y, s, v, line, peaks = locate(x, sign_in, n_pre_in, h_in, thr_sigma, min_ratio)
    return head, measure(head, y, s, v, line, peaks, fit_fraction, shape_r, skew, free_r,
                         max_iter, gate_1n, relax)


@njit(cache=True)
def locate(x: np.ndarray, sign_in: float, n_pre_in: int, h_in: int, thr_sigma: float,
           min_ratio: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                      np.ndarray]:
    """The first half of :func:`analyze` (same arguments): polarity, pre-trigger, baseline and
    noise, smoothing, the pulses and the slow trend.

    Returns ``head`` (its ``H_*`` columns up to ``H_NPEAKS``, and ``H_SIGMA_S``, ``H_FLOOR``,
    ``H_YMAX``), the sign-corrected trace ``y`` (read only; ``x`` itself when positive), the
    smoothed trace ``s``, ``v = s - line``, the slow trend ``line`` and the pulses' peak indices:
    what :func:`measure` takes.
    """
    n = x.size
    head = np.zeros(HEAD)
    sign, ref, csum, s1, s1_top = _polarity(x, sign_in)
    y = x if sign > 0 else _negated(x)  # read only: a positive trace is used in place
    head[H_SIGN] = sign
    ymin, ymax = vminmax(y)

    n_pre = n_pre_in if n_pre_in > 0 else _onset_pretrigger(s1, ref, s1_top)
    if n_pre == 0:
        head[H_EARLY] = 1.0
    span = max(0.0, ymax - ref, ref - ymin)  # = max |y[i] - ref| (monotonic rounding)
    floor = NOISE_FLOOR * max(span, 1e-300)
    base, sigma = _level_noise(y, n_pre, ref, floor)
    line = np.empty(n)
    line[:] = base
    h, s, v = _smoother(x, csum, s1, line, sign, h_in)
    sigma_s = _smoothed_noise(s, n_pre, h, sigma, floor)
    peaks, thr = _peaks(v, sigma_s, thr_sigma, min_ratio)

    if n_pre_in <= 0 and peaks.size > 0:
        new_pre, early, redo = _pretrigger_after_peaks(v, peaks, n_pre, h)
        if early:
            head[H_EARLY] = 1.0
        if redo:
            n_pre = new_pre
            base, sigma = _level_noise(y, n_pre, ref, floor)
            line[:] = base
            for i in range(n):
                v[i] = s[i] - line[i]
            sigma_s = _smoothed_noise(s, n_pre, h, sigma, floor)
            peaks, thr = _peaks(v, sigma_s, thr_sigma, min_ratio)
    peaks, thr = _trend(y, s, v, line, peaks, n_pre, h, sigma_s, thr_sigma, min_ratio, thr)

    head[H_BASE] = base
    head[H_SIGMA] = sigma
    head[H_THR] = thr
    head[H_NPRE] = n_pre
    head[H_SMOOTH] = h
    m = peaks.size
    head[H_NPEAKS] = m
    head[H_SIGMA_S] = sigma_s
    head[H_FLOOR] = floor
    head[H_YMAX] = ymax
    return head, y, s, v, line, peaks


@njit(cache=True)
def measure(head: np.ndarray, y: np.ndarray, s: np.ndarray, v: np.ndarray, line: np.ndarray,
            peaks: np.ndarray, fit_fraction: float, shape_r: float, skew: float, free_r: bool,
            max_iter: int, gate_1n: float, relax: np.ndarray) -> np.ndarray:
    """The second half of :func:`analyze`: every pulse :func:`locate` found, measured (its
    template fit and refined peak, :func:`_measure_pulse`), the reflection gated, the drift
    measured on the gap where the chain's relaxation is given (:mod:`.gap_drift`), the upper
    bound on the ARR and the saturation flag. Fills the rest of ``head``; returns
    ``pulses[j, P_*]``. The other arguments are :func:`analyze`'s."""
    n = y.size
    thr = head[H_THR]
    n_pre = int(head[H_NPRE])
    h = int(head[H_SMOOTH])
    peaks = _reflection_trend(y, s, v, line, peaks, n_pre, h, thr, gate_1n)
    m = peaks.size
    head[H_NPEAKS] = m
    out = np.zeros((m, PULSE))
    if m == 0:
        return out
    sigma = head[H_SIGMA]
    sigma_s = head[H_SIGMA_S]
    floor = head[H_FLOOR]
    ymax = head[H_YMAX]
    bounds = _bounds(v, peaks)
    widths = _widths(v, peaks, bounds)
    # The pre-impact baseline from the pre-trigger up to BASELINE_SPAN FWHM before the incident's
    # peak: the solitary wave's leading tail, still 0.5 % of its peak at the foot, would tilt it.
    n_base = min(n_pre, int(peaks[0] - BASELINE_SPAN * widths[0]))
    pre = pre_impact_baseline(y, n_base)
    head[H_PRE0] = pre[0] if pre[2] > 0 else line[0]
    head[H_PRE1] = pre[1] if pre[2] > 0 else 0.0
    nfree = 4 if free_r else 3
    # The refinement's errors take the noise where the baseline is measured (coloured noise
    # included): the detection's segment reaches into the incident's leading tail, which on a
    # clean trace is all its "noise". Without such a segment, the smoothed noise's excess over
    # white noise's tells the colour.
    if pre[2] > 0:
        sigma_top = max(pre[3], floor)
    else:
        sigma_top = sigma * max(1.0, sigma_s / max(smoother_gain(h) * sigma, 1e-300))
    prev_end = np.int64(0)  # int64, not a literal (module docstring)
    for j in range(m):
        sk = skew if j == 0 else -skew  # the later pulses travel back up the chain
        # (the stubs type the compiled call's int64 as int; numba reads no comments)
        prev_end = _measure_pulse(  # type: ignore[assignment]
            y, s, v, line, peaks[j], bounds[j], bounds[j + 1], widths[j],
            prev_end, thr, fit_fraction, shape_r, sk, nfree, max_iter,  # type: ignore[arg-type]
            sigma_top, pre, out[j])
        out[j, P_MERGED] = 1.0 if (j + 1 < m and v[bounds[j + 1]] > 0.5 * thr) else 0.0

    if gate_1n > 0 and m >= 2:
        out = _gate_reflection(out, gate_1n, head)
    drift = np.zeros(1)
    if m >= 2 and head[H_NOREF] == 0 and relax.size > 0 and pre[2] > 0:
        drift = gap_drift(y, max(n_base, 0), out, int(head[H_TRAIN]), relax, P_TIME, P_WIDTH)
        if drift[D_GAP] > 0:
            head[H_GAP] = drift[D_GAP]
            head[H_MISFIT] = drift[D_MISFIT]
            head[H_MISFIT_N] = drift[D_MISFIT_N]
            for j in range(2):  # the template's height above the drifted baseline
                base_j = drift_at(drift, out[j, P_TIME])
                out[j, P_AMP] += out[j, P_BASE] - base_j
                out[j, P_BASE] = base_j
    if m >= 2 and head[H_NOREF] == 0:  # the refined peaks of the incident and the reflection
        k = common_rung(out[:2, P_VALUES:], out[:2, P_RUNG])
        for j in range(2):
            t_j = out[j, P_PEAK_TIME]
            i_j = min(max(round(t_j), 0), n - 1)
            if head[H_GAP] > 0:
                base_j = drift_at(drift, t_j)
            else:
                base_j = pre[0] + pre[1] * t_j if pre[2] > 0 else line[i_j]
            out[j, P_PEAK_AMP] = out[j, P_VALUES + k] - base_j
    # No reflection: the largest excursion after the incident's foot bounds the ARR from above.
    first = min(n, int(peaks[0] + FOOT * widths[0]) + 1)
    last = n
    if gate_1n > 0:
        trip = gate_1n * max(out[0, P_AMP], 1e-300) ** (-1.0 / 6.0)
        first = max(first, min(n, int(out[0, P_TIME] + GATE_LO * trip)))
        last = max(first, min(n, int(out[0, P_TIME] + GATE_HI * trip) + 1))
    after = max(0.0, vmax(v[first:last])) if first < last else 0.0
    head[H_UPPER] = max(thr, after) / max(out[0, P_AMP], 1e-300)
    head[H_SATURATED] = 1.0 if _saturated(y, ymax, out[0, P_WIDTH]) else 0.0
    return out


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
    gate_1n: float,
    relax: np.ndarray,
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
                             shape_r, skew, free_r, max_iter, gate_1n, relax)
        for c in range(HEAD):
            heads[i, c] = head[c]
        counts[i] = rows.shape[0]
        for j in range(min(rows.shape[0], keep)):
            for c in range(PULSE):
                pulses[i, j, c] = rows[j, c]
    return heads, pulses, counts
