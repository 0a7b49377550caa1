"""Numba kernels behind pulse detection: smoothing, peak search, pulse-shape fit.

Every function here is O(n) or works on a window of at most :data:`MAX_FIT_POINTS` points, so a
10,000-sample shot costs a few passes over its samples and no Python work per sample.
"""

from __future__ import annotations

import numpy as np
from numba import njit

MAX_FIT_POINTS = 96
"""A longer fit window is block-averaged down to this (the pulse is smooth on that scale)."""

R_MIN, R_MAX = 1.2, 8.0
"""Bounds on the shape exponent r of the template A exp(-|u|^r)."""


@njit(cache=True)
def boxcar(x: np.ndarray, h: int) -> np.ndarray:
    """Centred moving average over 2h+1 samples (zero phase); the window shrinks at the ends."""
    n = x.size
    out = np.empty(n)
    if n <= 2 * h + 1:
        for i in range(n):
            lo = max(0, i - h)
            hi = min(n, i + h + 1)
            out[i] = np.mean(x[lo:hi])
        return out
    acc = 0.0
    for i in range(h + 1):
        acc += x[i]
    for i in range(h + 1):  # left edge: window [0, i + h]
        out[i] = acc / (i + h + 1)
        acc += x[i + h + 1]
    width = 2 * h + 1
    for i in range(h + 1, n - h):  # acc holds x[i - h - 1 .. i + h]
        acc -= x[i - h - 1]
        out[i] = acc / width
        if i + h + 1 < n:
            acc += x[i + h + 1]
    for i in range(n - h, n):  # right edge: window [i - h, n)
        acc -= x[i - h - 1]
        out[i] = acc / (n - i + h)
    return out


@njit(cache=True)
def triangle(x: np.ndarray, h: int) -> np.ndarray:
    """Two boxcars in a row: a zero-phase triangular smoother of half-width about 2h."""
    if h < 1:
        return x.copy()
    return boxcar(boxcar(x, h), h)


@njit(cache=True)
def median_mad(x: np.ndarray) -> tuple[float, float]:
    """Median and median absolute deviation of ``x``."""
    med = np.median(x)
    return med, np.median(np.abs(x - med))


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
    r = np.empty(n)
    for i in range(n):
        r[i] = x[i] - mean - slope * (i - tm)
    med = np.median(r)
    return np.median(np.abs(r - med))


@njit(cache=True)
def find_peaks_hysteresis(v: np.ndarray, thr: float, delta: float) -> np.ndarray:
    """Indices of peaks of ``v`` that rise above ``thr`` and stand out by ``delta`` on both sides.

    A peak is confirmed once ``v`` falls ``delta`` below it; the search for the next peak starts
    once ``v`` rises ``delta`` above the valley in between (Billauer's peakdet with a floor).
    A peak still rising at the end of the record is reported too (the caller flags truncation).
    """
    n = v.size
    out = np.empty(n, dtype=np.int64)
    k = 0
    seeking_max = True
    cur = v[0]
    icur = 0
    for i in range(1, n):
        x = v[i]
        if seeking_max:
            if x > cur:
                cur = x
                icur = i
            elif x < cur - delta:
                if cur > thr:
                    out[k] = icur
                    k += 1
                    seeking_max = False
                cur = x
                icur = i
        else:
            if x < cur:
                cur = x
                icur = i
            elif x > cur + delta:
                seeking_max = True
                cur = x
                icur = i
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


@njit(cache=True)
def quadratic_fit(x: np.ndarray, mask: np.ndarray, degree: int) -> tuple[np.ndarray, int]:
    """Least-squares polynomial of ``degree`` (0-2) in u = i / n through the masked-in samples.

    Returns the coefficients (c0, c1, c2) (unused ones zero) and the number of samples used.
    The baseline under the pulses: the quiet samples all along the record pin it down and a slow
    drift (a ramp with some curvature) is followed. Fewer than three samples give a constant.
    """
    n = x.size
    m = np.zeros((3, 3))
    rhs = np.zeros(3)
    count = 0
    for i in range(n):
        if mask[i]:
            u = i / n
            p1, p2 = u, u * u
            m[0, 0] += 1.0
            m[0, 1] += p1
            m[0, 2] += p2
            m[1, 2] += p1 * p2
            m[2, 2] += p2 * p2
            rhs[0] += x[i]
            rhs[1] += p1 * x[i]
            rhs[2] += p2 * x[i]
            count += 1
    coef = np.zeros(3)
    if count == 0:
        return coef, 0
    m[1, 0] = m[0, 1]
    m[1, 1] = m[0, 2]
    m[2, 0] = m[0, 2]
    m[2, 1] = m[1, 2]
    det = np.linalg.det(m)
    if count < 3 or abs(det) < 1e-12 * m[0, 0] ** 3 * 1e-6:
        coef[0] = rhs[0] / m[0, 0]
        return coef, count
    k = degree + 1
    coef[:k] = np.linalg.solve(m[:k, :k], rhs[:k])
    return coef, count


@njit(cache=True)
def poly_eval(coef: np.ndarray, n: int) -> np.ndarray:
    """c0 + c1 u + c2 u^2 at u = i / n for i in 0..n-1."""
    out = np.empty(n)
    for i in range(n):
        u = i / n
        out[i] = coef[0] + u * (coef[1] + u * coef[2])
    return out


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
def _template(t: np.ndarray, p: np.ndarray, f: np.ndarray, jac: np.ndarray) -> None:
    """Super-Gaussian A exp(-|u|^r), u = (t - tc)/w, and its Jacobian in (A, tc, w, r)."""
    amp, tc, w, r = p[0], p[1], p[2], p[3]
    nfree = jac.shape[1]
    for i in range(t.size):
        d = t[i] - tc
        a = abs(d) / w
        if a > 0:
            la = np.log(a)
            g = np.exp(r * la)
            e = np.exp(-g)
            f[i] = amp * e
            jac[i, 0] = e
            jac[i, 1] = amp * e * r * g / a / w * (1.0 if d > 0 else -1.0)
            jac[i, 2] = amp * e * r * g / w
            if nfree > 3:
                jac[i, 3] = -amp * e * g * la
        else:
            f[i] = amp
            jac[i, 0] = 1.0
            for k in range(1, nfree):
                jac[i, k] = 0.0


@njit(cache=True)
def fit_pulse(
    t: np.ndarray, y: np.ndarray, p0: np.ndarray, nfree: int, max_iter: int
) -> tuple[np.ndarray, bool]:
    """Levenberg-Marquardt fit of a symmetric super-Gaussian to (t, y): (params, converged).

    Parameters are amplitude, peak time, width and shape exponent r; with ``nfree = 3`` the
    exponent stays at ``p0[3]``. ``t`` should be centred and in sample units and ``y`` scaled to
    the peak, so the normal equations are well conditioned. A symmetric shape uses both flanks to
    place the peak, which is what makes it far less noisy than a parabola through the top.
    """
    n = t.size
    p = p0.copy()
    f = np.empty(n)
    jac = np.empty((n, nfree))
    _template(t, p, f, jac)
    cost = 0.0
    for i in range(n):
        cost += (y[i] - f[i]) ** 2
    lam = 1e-3
    trial = p.copy()
    ft = np.empty(n)
    jt = np.empty((n, nfree))
    tmin, tmax = t[0], t[n - 1]
    for _ in range(max_iter):
        jtj = jac.T @ jac
        g = jac.T @ (y - f)
        improved = False
        for _inner in range(8):
            a = jtj.copy()
            for k in range(nfree):
                a[k, k] += lam * (jtj[k, k] + 1e-12)
            step = np.linalg.solve(a, g)
            for k in range(nfree):
                trial[k] = p[k] + step[k]
            trial[1] = min(max(trial[1], tmin), tmax)
            trial[2] = max(trial[2], 0.25)
            trial[3] = min(max(trial[3], R_MIN), R_MAX)
            _template(t, trial, ft, jt)
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
