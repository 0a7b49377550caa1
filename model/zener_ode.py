"""The two integrators of Zener's contact problem: scipy's DOP853 and a compiled DOP853.

They integrate the regularised system of :mod:`solitonde.model.zener` (its docstring derives it),

    dr/ds = (y - lambda r^3) / 2,   dy/ds = -r^4,   dtau/ds = r,   r(0) = 0, y(0) = 1, tau(0) = 0,

to the first return of r to 0, where e = -y and tau_c = tau. Everyday use never comes here:
``zener`` reads e and tau_c from a Chebyshev table that :func:`chebyshev_table` builds with the
compiled integrator and that ships as ``zener_table.json``, so the theory and the CLI start without
numba or scipy. This module is imported when a lambda lies beyond the table, when the scipy
reference is asked for (tests, benchmarks), and when the table is rebuilt.
"""

from __future__ import annotations

from itertools import pairwise
from math import pi

import numpy as np
from numba import njit
from scipy.integrate import DOP853, solve_ivp

from .errors import SimulationError

# --- the reference integrator (scipy) ------------------------------------------------------------


def _regular_rhs(_s: float, u: np.ndarray, lam: float) -> list[float]:
    r, y, _tau = u
    return [0.5 * (y - lam * r**3), -(r**4), r]


def _contact_end(_s: float, u: np.ndarray, _lam: float) -> float:
    return u[0]


_contact_end.terminal = True  # type: ignore[attr-defined]
_contact_end.direction = -1  # type: ignore[attr-defined]


def integrate_reference(lam: float, rtol: float) -> tuple[float, float]:
    """(e, tau_c) for one lambda by scipy's DOP853 with a terminal event at r = 0.

    Relative error about 1e-11 at rtol 1e-12. Explicit steps are slow once lambda is large (10 s
    at lambda = 1e3), which is why callers keep it to lambda <= 100.
    """
    # The contact lasts s ~ 5 for lambda = 0 and grows fast with lambda; the bound only caps work.
    sol = solve_ivp(
        _regular_rhs, (0.0, 1e12), [0.0, 1.0, 0.0], method="DOP853", args=(lam,),
        rtol=rtol, atol=1e-30, events=_contact_end,
    )
    if sol.status != 1 or len(sol.t_events[0]) == 0:
        raise SimulationError(f"Zener contact for lambda={lam} did not end: {sol.message}")
    _r, y, tau = sol.y_events[0][0]
    return float(-y), float(tau)


# --- the compiled integrator (builds the table, handles lambdas beyond it) ----------------------

_A = np.ascontiguousarray(DOP853.A[: DOP853.n_stages, : DOP853.n_stages], dtype=np.float64)
_B = np.ascontiguousarray(DOP853.B, dtype=np.float64)
_C = np.ascontiguousarray(DOP853.C[: DOP853.n_stages], dtype=np.float64)
_E3 = np.ascontiguousarray(DOP853.E3, dtype=np.float64)
_E5 = np.ascontiguousarray(DOP853.E5, dtype=np.float64)


@njit(cache=True)
def _rk_step(u, h, lam, k, a, b, c):
    """One DOP853 step of size h from u; fills k[0..12] (k[12] = f(u_new)), returns u_new."""
    n_stages = b.shape[0]
    for i in range(n_stages):
        r = u[0]
        y = u[1]
        t = u[2]
        for j in range(i):
            r += h * a[i, j] * k[j, 0]
            y += h * a[i, j] * k[j, 1]
            t += h * a[i, j] * k[j, 2]
        k[i, 0] = 0.5 * (y - lam * r * r * r)
        k[i, 1] = -(r * r) * (r * r)
        k[i, 2] = r
    out = np.empty(3)
    for m in range(3):
        acc = 0.0
        for i in range(n_stages):
            acc += b[i] * k[i, m]
        out[m] = u[m] + h * acc
    r = out[0]
    k[n_stages, 0] = 0.5 * (out[1] - lam * r * r * r)
    k[n_stages, 1] = -(r * r) * (r * r)
    k[n_stages, 2] = r
    return out


@njit(cache=True)
def _integrate_one(lam, rtol, a, b, c, e3, e5):
    """Adaptive DOP853 (scipy's step control) to the first r = 0 crossing; returns (e, tau_c, ok).

    The end of contact is refined by the Illinois method on h -> r(step(u, h)): every trial is a
    full DOP853 step from the last accepted state, so the located end keeps the method's order.
    """
    k = np.empty((b.shape[0] + 1, 3))
    u = np.zeros(3)
    u[1] = 1.0
    h = 1e-3
    started = False
    for _ in range(10_000_000):
        new = _rk_step(u, h, lam, k, a, b, c)
        err5 = 0.0
        err3 = 0.0
        for m in range(3):
            s5 = 0.0
            s3 = 0.0
            for i in range(k.shape[0]):
                s5 += e5[i] * k[i, m]
                s3 += e3[i] * k[i, m]
            scale = 1e-30 + max(abs(u[m]), abs(new[m])) * rtol
            err5 += (s5 / scale) ** 2
            err3 += (s3 / scale) ** 2
        if err5 == 0.0 and err3 == 0.0:
            norm = 0.0
        else:
            norm = abs(h) * err5 / np.sqrt((err5 + 0.01 * err3) * 3.0)
        if norm >= 1.0:
            h *= max(0.2, 0.9 * norm**-0.125)
            continue
        if started and new[0] <= 0.0:
            lo, hi = 0.0, h
            f_lo, f_hi = u[0], new[0]
            side = 0
            for _it in range(200):
                mid = hi - f_hi * (hi - lo) / (f_hi - f_lo)
                trial = _rk_step(u, mid, lam, k, a, b, c)
                f_mid = trial[0]
                if f_mid == 0.0 or abs(hi - lo) <= 1e-15 * hi:
                    lo = hi = mid
                    new = trial
                    break
                if f_mid > 0.0:
                    lo, f_lo = mid, f_mid
                    if side == -1:
                        f_hi *= 0.5
                    side = -1
                else:
                    hi, f_hi = mid, f_mid
                    if side == 1:
                        f_lo *= 0.5
                    side = 1
                new = trial
            return -new[1], new[2], True
        started = True
        u = new
        h *= 10.0 if norm == 0.0 else min(10.0, 0.9 * norm**-0.125)
    return np.nan, np.nan, False


@njit(cache=True)
def _integrate_many(lams, rtol, a, b, c, e3, e5):
    n = lams.shape[0]
    e = np.empty(n)
    tau = np.empty(n)
    ok = True
    for i in range(n):
        e[i], tau[i], good = _integrate_one(lams[i], rtol, a, b, c, e3, e5)
        ok = ok and good
    return e, tau, ok


def integrate_compiled(lams: np.ndarray, rtol: float) -> tuple[np.ndarray, np.ndarray]:
    """(e, tau_c) for each lambda by the compiled DOP853 (milliseconds each once compiled)."""
    e, tau, ok = _integrate_many(np.ascontiguousarray(lams, dtype=np.float64), rtol,
                                 _A, _B, _C, _E3, _E5)
    if not ok:
        raise SimulationError("Zener contact did not end within the step budget")
    return e, tau


# --- the table the fast path reads ---------------------------------------------------------------


def _chebyshev_nodes(a: float, b: float, degree: int) -> np.ndarray:
    """Chebyshev points of the first kind mapped to [a, b]."""
    t = np.cos(pi * (np.arange(degree + 1) + 0.5) / (degree + 1))
    return a + 0.5 * (b - a) * (t + 1.0)


def chebyshev_table(
    lambda_max: float, panels: int, degree: int, anchor_lambda: float, rtol: float
) -> dict[str, object]:
    """Piecewise Chebyshev series of ln e and ln tau_c in x = ln(1 + lambda) on [0, lambda_max].

    Both functions are real-analytic in lambda (the ODE is polynomial in lambda and the end of
    contact is a transversal root), so on each of the equal ``panels`` in x their Chebyshev
    coefficients decay geometrically and the interpolation error is about the size of the first
    neglected coefficient. ``tail``, the largest of the last three coefficients of any panel and
    series, must stay below 1e-10 (it comes out near 1e-14, the noise of the rtol 1e-12 node
    values), which bounds the relative error of e and tau_c far below 1e-6. A single global series
    converges much more slowly (coefficient 60 is still 1e-7), hence the panels. Also integrates
    (e, tau_c) at ``anchor_lambda``, where the large-lambda law takes over.

    Returns the content of ``zener_table.json``: the settings, ``log_e`` and ``log_tau`` as
    panels x (degree + 1) nested lists, ``tail`` and ``anchor``.
    """
    x_max = float(np.log1p(lambda_max))
    edges = np.linspace(0.0, x_max, panels + 1)
    spans = list(pairwise(edges))
    x = np.concatenate([_chebyshev_nodes(a, b, degree) for a, b in spans])
    e, tau = integrate_compiled(np.expm1(x), rtol)
    n = degree + 1
    cheb = np.polynomial.chebyshev
    log_e = np.empty((panels, n))
    log_tau = np.empty((panels, n))
    for p, (a, b) in enumerate(spans):
        t = (2.0 * x[p * n:(p + 1) * n] - a - b) / (b - a)
        log_e[p] = cheb.chebfit(t, np.log(e[p * n:(p + 1) * n]), degree)
        log_tau[p] = cheb.chebfit(t, np.log(tau[p * n:(p + 1) * n]), degree)
    tail = float(max(np.abs(log_e[:, -3:]).max(), np.abs(log_tau[:, -3:]).max()))
    if tail > 1e-10:
        raise SimulationError(f"Zener table did not converge (tail coefficient {tail:.1e})")
    e_anchor, tau_anchor = integrate_compiled(np.array([anchor_lambda]), rtol)
    return {
        "lambda_max": lambda_max, "panels": panels, "degree": degree, "rtol": rtol,
        "log_e": log_e.tolist(), "log_tau": log_tau.tolist(), "tail": tail,
        "anchor": {"lambda": anchor_lambda, "e": float(e_anchor[0]),
                   "tau_c": float(tau_anchor[0])},
    }
