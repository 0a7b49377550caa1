"""The pulse model and its fit: a skewed super-Gaussian ``A exp(-|u|^r)`` with its Jacobian, small
Cholesky and LU solvers, the Levenberg-Marquardt fit of amplitude, peak time, width and shape, and
a parabola through the top as the fallback.

Compiled with numba; used by :mod:`.kernels`. Written in loops over scalars, without numpy's
linear algebra or whole-array assignments (``a[:, :] = b``): numba compiles those from dozens of
helper functions of its own (LAPACK wrappers, shape checks and their error messages), which
made up a fifth of the extractor's first compilation and nothing of its run time.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .extrema import vmax

R_MIN, R_MAX = 1.2, 8.0
"""Bounds on the shape exponent r of the template A exp(-|u|^r)."""


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
def solve_lu(a: np.ndarray, b: np.ndarray, x: np.ndarray) -> float:
    """Solves ``a x = b`` for a small square ``a`` by Gaussian elimination with partial pivoting
    (what LAPACK's ``gesv`` does), overwriting ``a`` and ``b``; returns ``det(a)``, 0 (``x``
    undefined) when a pivot is exactly zero. The least-squares polynomials' 2x2 and 3x3 normal
    equations, whose callers test the determinant before they use ``x``."""
    m = a.shape[0]
    det = 1.0
    for k in range(m):
        p = k
        for i in range(k + 1, m):
            if abs(a[i, k]) > abs(a[p, k]):
                p = i
        if a[p, k] == 0.0:
            return 0.0
        if p != k:
            det = -det
            for j in range(m):
                a[k, j], a[p, j] = a[p, j], a[k, j]
            b[k], b[p] = b[p], b[k]
        det *= a[k, k]
        for i in range(k + 1, m):
            f = a[i, k] / a[k, k]
            for j in range(k + 1, m):
                a[i, j] -= f * a[k, j]
            b[i] -= f * b[k]
    for i in range(m - 1, -1, -1):
        acc = b[i]
        for j in range(i + 1, m):
            acc -= a[i, j] * x[j]
        x[i] = acc / a[i, i]
    return det


@njit(cache=True, inline="always")
def _normal_equations(wt: np.ndarray, jac: np.ndarray, y: np.ndarray, f: np.ndarray,
                      g: np.ndarray, jtj: np.ndarray) -> None:
    """``g = J^T W (y - f)`` and ``jtj = J^T W J``, each entry summed over the points in order.

    One pass with every entry's sum in its own register: the sums are independent chains of
    additions, which one loop per entry would run one after the other, each waiting on its
    own additions. The products and their order per entry are a loop per entry's, so the
    numbers are the same to the bit. Three or four parameters (``jac``'s columns)."""
    nfree = jac.shape[1]
    g0 = g1 = g2 = g3 = 0.0
    m00 = m01 = m02 = m03 = m11 = m12 = m13 = m22 = m23 = m33 = 0.0
    if nfree == 3:
        for i in range(wt.size):
            w = wt[i]
            r = y[i] - f[i]
            j0, j1, j2 = jac[i, 0], jac[i, 1], jac[i, 2]
            g0 += w * j0 * r
            g1 += w * j1 * r
            g2 += w * j2 * r
            m00 += w * j0 * j0
            m01 += w * j0 * j1
            m02 += w * j0 * j2
            m11 += w * j1 * j1
            m12 += w * j1 * j2
            m22 += w * j2 * j2
    else:
        for i in range(wt.size):
            w = wt[i]
            r = y[i] - f[i]
            j0, j1, j2, j3 = jac[i, 0], jac[i, 1], jac[i, 2], jac[i, 3]
            g0 += w * j0 * r
            g1 += w * j1 * r
            g2 += w * j2 * r
            g3 += w * j3 * r
            m00 += w * j0 * j0
            m01 += w * j0 * j1
            m02 += w * j0 * j2
            m03 += w * j0 * j3
            m11 += w * j1 * j1
            m12 += w * j1 * j2
            m13 += w * j1 * j3
            m22 += w * j2 * j2
            m23 += w * j2 * j3
            m33 += w * j3 * j3
    g[0], g[1], g[2] = g0, g1, g2
    jtj[0, 0], jtj[1, 1], jtj[2, 2] = m00, m11, m22
    jtj[0, 1] = jtj[1, 0] = m01
    jtj[0, 2] = jtj[2, 0] = m02
    jtj[1, 2] = jtj[2, 1] = m12
    if nfree > 3:
        g[3] = g3
        jtj[3, 3] = m33
        jtj[0, 3] = jtj[3, 0] = m03
        jtj[1, 3] = jtj[3, 1] = m13
        jtj[2, 3] = jtj[3, 2] = m23


@njit(cache=True)
def fit_pulse(
    t: np.ndarray, y: np.ndarray, wt: np.ndarray, p0: np.ndarray, skew: float, nfree: int,
    max_iter: int
) -> tuple[np.ndarray, bool]:
    """Levenberg-Marquardt fit of the skewed super-Gaussian to (t, y), each point weighing ``wt``
(a block's share of the fit window): (params, converged).

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
        cost += wt[i] * (y[i] - f[i]) ** 2
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
        _normal_equations(wt, jac, y, f, g, jtj)
        improved = False
        for _inner in range(8):
            for k in range(nfree):
                for q in range(nfree):
                    a[k, q] = jtj[k, q]
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
                c += wt[i] * (y[i] - ft[i]) ** 2
            if c <= cost:
                rel = abs(step[1]) + abs(step[0]) / max(abs(p[0]), 1e-12)
                for k in range(p.size):
                    p[k] = trial[k]
                f, ft = ft, f  # the trial's values and Jacobian become the current ones
                jac, jt = jt, jac
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
    top = vmax(yb)
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
        m = np.empty((3, 3))
        m[0, 0] = s0
        m[0, 1] = m[1, 0] = s1
        m[0, 2] = m[1, 1] = m[2, 0] = s2
        m[1, 2] = m[2, 1] = s3
        m[2, 2] = s4
        rhs = np.empty(3)
        rhs[0], rhs[1], rhs[2] = r0, r1, r2
        c = np.empty(3)
        if abs(solve_lu(m, rhs, c)) > 1e-12 * max(s4, 1.0) ** 3:
            c0, c1, c2 = c[0], c[1], c[2]
            if c2 < 0:
                tc = -c1 / (2 * c2)
                if lo <= tc <= hi:
                    return tc, c0 - c1 * c1 / (4 * c2), True
    return 0.0, 1.0, False
