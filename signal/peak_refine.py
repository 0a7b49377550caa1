"""A pulse's peak as the trace itself has it: the pre-impact baseline, and the template's peak
refined on the data's top.

The paper's TOF is the time between the incident and the reflected peaks, its ARR the ratio of
their heights above the sensor's reading before the impact. A fitted template of fixed shape
reads both with little noise, but wherever a pulse's shape differs from it (a reflection that
rises slower than it falls, a flat top, gravity on or off) its peak is not the pulse's: up to
several microseconds and percent. :func:`refine_peak` therefore fits quartics to the data's top
over a ladder of windows, from a few samples (no shape bias, most noise) to a quarter of the
pulse's height, and keeps the widest estimate, the template's included, that agrees with every
narrower one within :data:`AGREE_SIGMAS` of that one's standard error (Lepski's rule). Clean
traces get the narrowest (the trace's own peak); at low SNR the narrow windows are too noisy to
overrule anything, and the template's near-optimal estimate stands.

Compiled with numba; used by :mod:`.kernels`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .extrema import vargmax
from .pulse_fit import solve_spd

LADDER = (0.005, 0.02, 0.08, 0.25)
"""The refinement windows: the part of the pulse within these fractions of its height from the
top (measured on the template's shape), narrowest first; the template's own fit is the last."""
MIN_HALF = 3
"""Fewest samples either side of the centre in a window (7 points carry a cubic)."""
AGREE_SIGMAS = 3.0
"""A wider estimate stands while it lies within this many standard errors of each narrower one."""
SLOPE_SIGMAS = 4.0
"""The pre-trigger's slope is extrapolated as baseline drift only beyond this many standard
errors; otherwise the baseline is the pre-trigger's mean (all a noise-free trace has)."""
MIN_PRE = 16
NOISE_BLOCK = 16
"""Samples per block in the pre-trigger's coloured-noise check."""
RESOLVED = 0.1
"""A window's peak is used only when its time's standard error is at most this fraction of the
window's half-width."""


@njit(cache=True)
def pre_impact_baseline(y: np.ndarray, n_pre: int) -> np.ndarray:
    """``(c0, c1, ok, noise)``: the sensor's reading before the impact, ``c0 + c1 * i`` at sample
    ``i``, and the noise a fit of many samples sees.

    The least-squares line through the pre-trigger segment ``y[:n_pre]``, its slope kept only
    when it is :data:`SLOPE_SIGMAS` standard errors from zero (a drift the segment shows);
    otherwise the segment's mean. ``noise`` is the residuals' standard deviation, scaled up for
    coloured noise (a low-pass, an anti-alias filter) by the spread of their means over
    :data:`NOISE_BLOCK` samples against white noise's. ``ok`` is 0 when there is no pre-trigger
    segment to measure.
    """
    out = np.zeros(4)
    if n_pre < MIN_PRE:
        return out
    m = float(n_pre)
    mean_i = 0.5 * (m - 1.0)
    # Each sum is added in sample order; sums that share a loop are independent chains of
    # additions, which run side by side.
    sy = 0.0
    sxx = 0.0
    for i in range(n_pre):
        sy += y[i]
        d = i - mean_i
        sxx += d * d
    mean_y = sy / m
    sxy = 0.0
    for i in range(n_pre):
        sxy += (i - mean_i) * (y[i] - mean_y)
    slope = sxy / sxx
    rss = 0.0
    acc = 0.0  # the squared means of the residuals over whole blocks
    blocks = n_pre // NOISE_BLOCK
    for k in range(blocks):
        bm = 0.0
        for i in range(k * NOISE_BLOCK, (k + 1) * NOISE_BLOCK):
            e = y[i] - mean_y - slope * (i - mean_i)
            rss += e * e
            bm += e
        bm /= NOISE_BLOCK
        acc += bm * bm
    for i in range(blocks * NOISE_BLOCK, n_pre):
        e = y[i] - mean_y - slope * (i - mean_i)
        rss += e * e
    se = np.sqrt(rss / (m - 2.0) / sxx)
    out[2] = 1.0
    white = rss / (m - 2.0)
    coloured = white
    if blocks >= 4:
        coloured = max(white, NOISE_BLOCK * acc / blocks)
    out[3] = np.sqrt(coloured)
    if abs(slope) > SLOPE_SIGMAS * se:
        out[0] = mean_y - slope * mean_i
        out[1] = slope
    else:
        out[0] = mean_y
    return out


@njit(cache=True)
def poly_peak(y: np.ndarray, c: int, h: int, lo: int, hi: int, sigma: float,
              curvature: float) -> np.ndarray:
    """Least-squares quartic through ``y[c - h .. c + h]`` (within [lo, hi]) and its maximum
    inside the window: ``(time in samples, value, se of time, se of value, ok, curvature at the
    maximum per sample squared)``.

    A quartic, not a parabola or a cubic: a top is flat to fourth order wherever a pulse is
    symmetric, and a cubic through an off-centre window reads that term as a shift. The maximum
    is Newton's root of ``p'`` from the parabola's. The standard errors are the delta method's for
    white noise ``sigma``: at the maximum ``p'(u) = 0``, so the time moves by ``-dp'/p''`` and the
    value by ``dp`` alone; ``p''`` is ``curvature`` when that is negative (the pulse's, from the
    template): a narrow window's own curvature is mostly noise, and a noisy sharp maximum would
    claim a precision it does not have.
    """
    out = np.zeros(6)
    _poly_peak_into(y, c, h, lo, hi, sigma, curvature, out, np.empty((SCRATCH, 5)))
    return out


SCRATCH = 16
"""Rows of five in the scratch array of :func:`_poly_peak_into` (its normal equations, their
right-hand side, and :func:`_quartic_peak`'s work): one array per refined pulse instead of
eleven per window (about 80 allocations a shot, 2 % of the extractor's time)."""


CURVATURE_POINTS = 32
"""The template's curvature (:func:`_template_curvature`) is taken on ``2 CURVATURE_POINTS + 1``
points spread evenly over the widest window, or on its samples where it has fewer: within 2.5 %
of the value on every sample (half-widths of 4 to 2,000 samples, r 1.8 to 3.2), which scales a
standard error; a point costs a ``pow`` and an ``exp``, and on every sample of a 100-sample
half-width they took 3 % of the extractor's time."""


@njit(cache=True)
def _template_curvature(height: float, w: float, r: float, hw: int, frac: float,
                        out: np.ndarray, scratch: np.ndarray) -> float:
    """:func:`poly_peak`'s curvature (``out[5]``, per sample squared) of the template
    ``height exp(-|u / w|^r)`` over the window ``u = -hw - frac .. hw - frac`` (0: none), on
    :data:`CURVATURE_POINTS` either side of the centre; ``out`` (six) and ``scratch``
    (``SCRATCH`` x 5) are overwritten."""
    k = min(hw, CURVATURE_POINTS)
    step = hw / k
    shape = np.empty(2 * k + 1)
    for i in range(shape.size):
        shape[i] = height * np.exp(-(abs((i - k) * step - frac) / w) ** r)
    _poly_peak_into(shape, k, k, 0, shape.size - 1, 1.0, 0.0, out, scratch)
    return out[5] / (step * step)


@njit(cache=True, inline="always")
def _poly_peak_into(y: np.ndarray, c: int, h: int, lo: int, hi: int, sigma: float,
                    curvature: float, out: np.ndarray, scratch: np.ndarray) -> None:
    """:func:`poly_peak` into ``out`` (set to zeros first), with ``scratch`` (``SCRATCH`` x 5,
    overwritten) for the work: the sums over the window, then :func:`_quartic_peak`. Inlined
    into its two callers, which pass the record (read only) and the template (writable); the
    rest is compiled once for both."""
    for q in range(out.size):
        out[q] = 0.0
    a = max(c - h, lo)
    b = min(c + h, hi)
    if b - a < 6 or a >= c or b <= c:
        return
    # The sums of u^(k+q) and u^k y, one scalar each, so they stay in registers: the same
    # products added in the same order as a loop over a 5x5 array (u^0 = 1 multiplies exactly,
    # and m[k, q] and m[q, k] add the same products, since a product commutes exactly).
    m01 = m02 = m03 = m04 = m11 = m12 = m13 = m14 = 0.0
    m22 = m23 = m24 = m33 = m34 = m44 = 0.0
    r0 = r1 = r2 = r3 = r4 = 0.0
    inv_h = 1.0 / h
    for i in range(a, b + 1):
        p1 = (i - c) * inv_h
        p2 = p1 * p1
        p3 = p2 * p1
        p4 = p3 * p1
        yi = y[i]
        r0 += yi
        r1 += p1 * yi
        r2 += p2 * yi
        r3 += p3 * yi
        r4 += p4 * yi
        m01 += p1
        m02 += p2
        m03 += p3
        m04 += p4
        m11 += p1 * p1
        m12 += p1 * p2
        m13 += p1 * p3
        m14 += p1 * p4
        m22 += p2 * p2
        m23 += p2 * p3
        m24 += p2 * p4
        m33 += p3 * p3
        m34 += p3 * p4
        m44 += p4 * p4
    m = scratch[:5]
    m[0, 0] = float(b - a + 1)
    m[0, 1] = m[1, 0] = m01
    m[0, 2] = m[2, 0] = m02
    m[0, 3] = m[3, 0] = m03
    m[0, 4] = m[4, 0] = m04
    m[1, 1] = m11
    m[1, 2] = m[2, 1] = m12
    m[1, 3] = m[3, 1] = m13
    m[1, 4] = m[4, 1] = m14
    m[2, 2] = m22
    m[2, 3] = m[3, 2] = m23
    m[2, 4] = m[4, 2] = m24
    m[3, 3] = m33
    m[3, 4] = m[4, 3] = m34
    m[4, 4] = m44
    rhs = scratch[5]
    rhs[0], rhs[1], rhs[2], rhs[3], rhs[4] = r0, r1, r2, r3, r4
    _quartic_peak(m, rhs, c, h, a, b, sigma, curvature, out, scratch[6:])


@njit(cache=True)
def _quartic_peak(m: np.ndarray, rhs: np.ndarray, c: int, h: int, a: int, b: int, sigma: float,
                  curvature: float, out: np.ndarray, scratch: np.ndarray) -> None:
    """The rest of :func:`poly_peak` from the normal equations ``m coef = rhs`` of the window
    ``[a, b]`` (``u = (i - c) / h``): the quartic's maximum and its standard errors into
    ``out`` (zeros, left so where there is none); ``scratch`` (10 x 5) is overwritten."""
    inv_h = 1.0 / h
    work = scratch[:5]
    for i in range(5):
        for q in range(5):
            work[i, q] = m[i, q]
    coef = scratch[5]
    if not solve_spd(work, rhs, coef):
        return
    c1, c2, c3, c4 = coef[1], coef[2], coef[3], coef[4]
    if not c2 < 0:
        return
    ua, ub = (a - c) * inv_h, (b - c) * inv_h
    u = min(max(-c1 / (2.0 * c2), ua), ub)
    for _ in range(20):
        d1 = c1 + u * (2.0 * c2 + u * (3.0 * c3 + 4.0 * c4 * u))
        d2 = 2.0 * c2 + u * (6.0 * c3 + 12.0 * c4 * u)
        if not d2 < 0:
            return
        step = d1 / d2
        u = min(max(u - step, ua), ub)
        if abs(step) < 1e-12:
            break
    if u <= ua or u >= ub:
        return  # the maximum lies outside the window
    curv = 2.0 * c2 + u * (6.0 * c3 + 12.0 * c4 * u)
    if not curv < 0:
        return
    out[5] = curv * inv_h * inv_h
    if curvature < 0:
        curv = curvature * h * h
    gt = scratch[6]
    ga = scratch[7]
    gt[0] = 0.0
    ga[0] = 1.0
    for k in range(1, 5):
        ga[k] = ga[k - 1] * u
        gt[k] = -k * ga[k - 1] / curv
    var = scratch[8]
    sol = scratch[9]
    for k in range(2):
        g = gt if k == 0 else ga
        for i in range(5):
            for q in range(5):
                work[i, q] = m[i, q]
        if not solve_spd(work, g, sol):
            return
        acc = 0.0
        for q in range(5):
            acc += g[q] * sol[q]
        var[k] = acc
    out[0] = c + u * h
    out[1] = coef[0] + u * (c1 + u * (c2 + u * (c3 + u * c4)))
    out[2] = sigma * np.sqrt(var[0]) * h
    out[3] = sigma * np.sqrt(var[1])
    out[4] = 1.0


@njit(cache=True)
def refine_peak(y: np.ndarray, t_fit: float, top_fit: float, height: float, w: float, r: float,
                lo: int, hi: int, sigma: float, values: np.ndarray
                ) -> tuple[float, float, bool, int]:
    """The peak (time in samples, value) of the pulse whose template peaks at ``t_fit`` with
    ``top_fit`` (``height`` above its own base, scale ``w`` samples, exponent ``r``), the pulse
    lying within samples [lo, hi].

    Quartics over the :data:`LADDER` windows are fitted from the widest in, each centred on the
    peak the next wider one found; then, from the narrowest out, the widest estimate (the
    template last) that lies within :data:`AGREE_SIGMAS` standard errors of every narrower one is
    kept, for the time and the value apart. Returns them, whether either is a refinement (not
    the template's own) and the rung the value comes from (``len(LADDER)``: the template);
    ``values`` (``len(LADDER) + 1``) receives every rung's value (NaN where a window was not
    usable), so that pulses can be read on a common rung (:func:`common_rung`).
    """
    nl = len(LADDER)
    est = np.zeros((nl, 6))
    alt = np.empty(6)
    scratch = np.empty((SCRATCH, 5))
    halves = np.zeros(nl, dtype=np.int64)
    for k in range(nl):
        halves[k] = max(MIN_HALF, round(w * (-np.log(1.0 - LADDER[k])) ** (1.0 / r)))
    # The errors use the template's curvature over the widest window, not each fit's own: noise
    # that sharpens a fitted top would otherwise claim a precision the window does not have.
    curvature = _template_curvature(height, w, r, halves[nl - 1], t_fit - np.floor(t_fit), alt,
                                    scratch)
    values[:] = np.nan
    values[nl] = top_fit
    if not curvature < 0:
        return t_fit, top_fit, False, nl
    centre = t_fit
    for k in range(nl - 1, -1, -1):
        if k < nl - 1 and halves[k] >= halves[k + 1]:
            continue  # the same window as the wider one: nothing new
        c = round(centre)
        if c <= lo or c >= hi:
            continue
        _poly_peak_into(y, c, halves[k], lo, hi, sigma, curvature, est[k], scratch)
        # Usable only where the noise leaves the peak well inside the window: beyond that the
        # cubic's maximum is a root of a noisy derivative, far from Gaussian, and would overrule
        # the wider windows by chance.
        if (est[k, 4] > 0 and abs(est[k, 0] - centre) <= halves[k]
                and est[k, 2] <= RESOLVED * halves[k]):
            centre = est[k, 0]
        else:
            est[k, 4] = 0.0
    # A reflection split in two humps: the ladder follows the template into one of them, the
    # other may be higher. A narrowest window on the pulse's highest sample that reads a clearly
    # higher top replaces the narrow rungs.
    top_i = lo + vargmax(y[lo : hi + 1])
    first = 0
    while first < nl and est[first, 4] == 0:
        first += 1
    if first == nl or abs(top_i - est[first, 0]) > halves[first]:
        _poly_peak_into(y, top_i, halves[0], lo, hi, sigma, curvature, alt, scratch)
        if alt[4] > 0 and alt[2] <= RESOLVED * halves[0] and (
                first == nl or alt[1] > est[first, 1] + AGREE_SIGMAS * max(alt[3],
                                                                           est[first, 3])):
            est[:, 4] = 0.0
            _set_row(est, 0, alt)
    t_pk, k_t = _lepski(est, 0, 2, t_fit)
    v_pk, k_v = _lepski(est, 1, 3, top_fit)
    for k in range(nl):
        values[k] = est[k, 1] if est[k, 4] > 0 else np.nan
    values[nl] = top_fit
    return t_pk, v_pk, k_t < nl or k_v < nl, k_v


@njit(cache=True, inline="always")
def _set_row(a: np.ndarray, k: int, row: np.ndarray) -> None:
    """``a[k] = row`` as a loop (numba compiles a broadcasting check, with its error message,
    for the assignment of one array to another)."""
    for q in range(row.size):
        a[k, q] = row[q]


@njit(cache=True, inline="always")
def _lepski(est: np.ndarray, col: int, se_col: int, fit: float) -> tuple[float, int]:
    """The widest usable estimate ``est[k, col]`` (``fit`` the widest of all, index ``len(est)``)
    within :data:`AGREE_SIGMAS` standard errors ``est[j, se_col]`` of every narrower usable one,
    and its index. Time and value are chosen apart: a template can place a peak right and still
    miss its height (a rounder top than its own)."""
    nl = est.shape[0]
    chosen_v, chosen = fit, nl
    for k in range(nl + 1):
        if k < nl and est[k, 4] == 0:
            continue
        v_k = est[k, col] if k < nl else fit
        for j in range(min(k, nl)):
            if est[j, 4] > 0 and abs(v_k - est[j, col]) > AGREE_SIGMAS * est[j, se_col]:
                return chosen_v, chosen
        chosen_v, chosen = v_k, k
    return chosen_v, chosen


@njit(cache=True, inline="always")
def common_rung(values: np.ndarray, rungs: np.ndarray) -> int:
    """The rung to read both pulses of a ratio on: the narrower of the two chosen, moved out to
    the first rung usable for both. Each rung's shape bias is nearly the same fraction of either
    pulse, so a ratio read on one rung keeps little of it, where a ratio of values from different
    rungs keeps the difference (the template's top lies 0.4-1 % below a pulse's)."""
    k = int(min(rungs[0], rungs[1]))
    while k < values.shape[1] - 1 and not (np.isfinite(values[0, k]) and np.isfinite(values[1, k])):
        k += 1
    return k
