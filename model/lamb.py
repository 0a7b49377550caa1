"""Rayleigh-Lamb dispersion of a free plate: A0, S0 and A1 (the paper's Sec. 4.2.2 and Fig. 9).

With half-thickness h, p^2 = w^2/c_L^2 - k^2 and q^2 = w^2/c_T^2 - k^2 the Rayleigh-Lamb equations

    symmetric:      tan(q h)/tan(p h) = -4 k^2 p q / (k^2 - q^2)^2
    antisymmetric:  tan(q h)/tan(p h) = -(k^2 - q^2)^2 / (4 k^2 p q)

are used here in a pole-free real form. Multiplying out the tangents and dividing by q (symmetric)
or p (antisymmetric) gives

    G_S = (k^2 - q^2)^2 C(p) S(q) + 4 k^2 P(p) C(q)
    G_A = (k^2 - q^2)^2 S(p) C(q) + 4 k^2 C(p) P(q)

with C(x) = cos(x h), S(x) = sin(x h)/x, P(x) = x sin(x h). All three are entire functions of x^2
(they turn into cosh, sinh/x and -x sinh when x^2 < 0), so G_S and G_A are real and smooth for
every real k and w, have no poles, and lose the trivial roots p = 0 or q = 0. A sign change on a
k grid is therefore a root and nothing else.

Tracing: at every frequency the roots in k are bracketed on a fine grid and refined by bisection;
within a family modes do not cross, so A0 is the largest-k antisymmetric root, A1 the next and S0
the largest-k symmetric root. A branch is accepted only if it continues smoothly from the previous
frequencies; otherwise that frequency is re-scanned on a finer grid, and a branch that still jumps
raises :class:`SimulationError` rather than returning a wrong mode. Group velocity follows from
implicit differentiation of G(k, w) = 0 at each root: c_g = dw/dk = -G_k / G_w.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from math import pi, sqrt

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import brentq

from .errors import SimulationError
from .materials import Material

MODES = ("A0", "S0", "A1")


# --- closed-form limits -------------------------------------------------------------------------


def rayleigh_velocity(material: Material) -> float:
    """Rayleigh surface-wave speed c_R (root of (2 - x^2)^2 = 4 sqrt(1 - x^2 k^2) sqrt(1 - x^2)).

    Here x = c_R / c_T and k = c_T / c_L. It is the high-frequency limit of A0 and S0.
    """
    kappa2 = (material.shear_velocity / material.longitudinal_velocity) ** 2

    def f(x: float) -> float:
        x2 = x * x
        return (2.0 - x2) ** 2 - 4.0 * sqrt(1.0 - x2 * kappa2) * sqrt(1.0 - x2)

    return brentq(f, 0.5, 1.0 - 1e-15, xtol=1e-15, rtol=1e-15) * material.shear_velocity


def kirchhoff_phase_velocity(
    frequency: ArrayLike, thickness: float, material: Material
) -> np.ndarray:
    """Flexural (Kirchhoff plate) phase velocity sqrt(w) (D_p / (rho t))^(1/4), m/s.

    The low-frequency limit of A0; the Kirchhoff group velocity is twice this.
    """
    omega = 2.0 * pi * np.asarray(frequency, dtype=float)
    bending = material.plane_stress_modulus * thickness**3 / 12.0
    return np.sqrt(omega) * (bending / (material.density * thickness)) ** 0.25


def a1_cutoff_frequency(thickness: float, material: Material) -> float:
    """A1 cut-off, the first thickness-shear resonance c_T / (2 t), Hz.

    At k = 0 the antisymmetric equation reduces to sin(p h) cos(q h) = 0, whose lowest root is
    q h = pi/2 (c_L / t, from p h = pi, is always higher).
    """
    return material.shear_velocity / (2.0 * thickness)


# --- the dispersion function --------------------------------------------------------------------


def _parts(x2: np.ndarray, scaled: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """C = cos x, S = sin(x)/x, P = x sin x as functions of x^2 (real for either sign).

    With ``scaled`` the evanescent (x^2 < 0) values are multiplied by exp(-|x|), a positive factor
    that keeps the sign and avoids overflow.
    """
    pos = x2 >= 0.0
    a = np.sqrt(np.abs(x2))
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        if scaled:
            em = np.exp(-2.0 * a)
            ch = 0.5 * (1.0 + em)
            sh = -0.5 * np.expm1(-2.0 * a)
        else:
            ch = np.cosh(a)
            sh = np.sinh(a)
        c = np.where(pos, np.cos(a), ch)
        s = np.where(pos, np.sinc(a / pi), np.where(a > 0.0, sh / np.where(a > 0, a, 1.0), 1.0))
        p = np.where(pos, a * np.sin(a), -a * sh)
    return c, s, p


def dispersion_function(family: str, kh: ArrayLike, wh: ArrayLike, kappa: float,
                        scaled: bool = True) -> np.ndarray:
    """G_S or G_A in the dimensionless variables K = k h and W = w h / c_T.

    Parameters
    ----------
    family: "S" (symmetric) or "A" (antisymmetric).
    kh: K = k h.
    wh: W = w h / c_T.
    kappa: c_T / c_L.
    scaled: multiply evanescent factors by exp(-|x| h) (sign-preserving; avoids overflow).
    """
    K = np.asarray(kh, dtype=float)
    W = np.asarray(wh, dtype=float)
    k2 = K * K
    q2 = W * W - k2
    p2 = (kappa * W) ** 2 - k2
    cp, sp, pp = _parts(p2, scaled)
    cq, sq, pq = _parts(q2, scaled)
    lead = (k2 - q2) ** 2
    if family == "S":
        return lead * cp * sq + 4.0 * k2 * pp * cq
    if family == "A":
        return lead * sp * cq + 4.0 * k2 * cp * pq
    raise ValueError(f"family must be 'S' or 'A', got {family!r}")


def _roots(family: str, W: np.ndarray, kappa: float, k_max: np.ndarray, n: int) -> list[np.ndarray]:
    """All roots K in (0, k_max] at each W, each list entry descending (slowest mode first)."""
    grid = np.linspace(1e-7, 1.0, n)
    K = k_max[:, None] * grid[None, :]
    g = dispersion_function(family, K, W[:, None], kappa)
    sign = np.signbit(g)
    row, col = np.nonzero(sign[:, :-1] != sign[:, 1:])
    lo = K[row, col]
    hi = K[row, col + 1]
    g_lo = g[row, col]
    w = W[row]
    for _ in range(64):
        mid = 0.5 * (lo + hi)
        g_mid = dispersion_function(family, mid, w, kappa)
        left = np.signbit(g_mid) == np.signbit(g_lo)
        lo = np.where(left, mid, lo)
        g_lo = np.where(left, g_mid, g_lo)
        hi = np.where(left, hi, mid)
    root = 0.5 * (lo + hi)
    return [np.sort(root[row == j])[::-1] for j in range(W.size)]


def _dispersion_complex(family: str, K: np.ndarray, W: np.ndarray, kappa: float) -> np.ndarray:
    """G_S or G_A for complex K and W (unscaled), for complex-step derivatives.

    cos(x), sin(x)/x and x sin(x) are even in x, so any branch of x = sqrt(x^2) gives the same,
    analytic, value.
    """
    k2 = K * K
    q2 = W * W - k2
    p2 = (kappa * W) ** 2 - k2
    xp = np.sqrt(p2.astype(complex))
    xq = np.sqrt(q2.astype(complex))
    cp, cq = np.cos(xp), np.cos(xq)
    with np.errstate(invalid="ignore", divide="ignore"):
        sp = np.where(xp == 0, 1.0, np.sin(xp) / np.where(xp == 0, 1.0, xp))
        sq = np.where(xq == 0, 1.0, np.sin(xq) / np.where(xq == 0, 1.0, xq))
    pp, pq = xp * np.sin(xp), xq * np.sin(xq)
    lead = (k2 - q2) ** 2
    if family == "S":
        return lead * cp * sq + 4.0 * k2 * pp * cq
    return lead * sp * cq + 4.0 * k2 * cp * pq


def _group_velocity_ratio(family: str, K: np.ndarray, W: np.ndarray, kappa: float) -> np.ndarray:
    """dW/dK along G(K, W) = 0 by implicit differentiation, -G_K / G_W.

    Both partial derivatives are complex-step derivatives (Im G(x + i eps) / eps), which have no
    subtractive cancellation: finite differences lose digits at low frequency, where the terms of
    G cancel to many digits at the A0 root.
    """
    K = np.asarray(K, dtype=float)
    W = np.asarray(W, dtype=float)
    eps = 1e-30
    g_k = _dispersion_complex(family, K + 1j * eps, W + 0j, kappa).imag / eps
    g_w = _dispersion_complex(family, K + 0j, W + 1j * eps, kappa).imag / eps
    with np.errstate(invalid="ignore"):
        return -g_k / g_w


@dataclass(frozen=True)
class LambDispersion:
    """Phase and group velocity of A0, S0 and A1 against frequency for one plate.

    ``phase_velocity[mode]`` and ``group_velocity[mode]`` are arrays over ``frequency_hz`` in
    m/s; NaN where the mode does not propagate (A1 below its cut-off).
    """

    frequency_hz: np.ndarray
    phase_velocity: dict[str, np.ndarray]
    group_velocity: dict[str, np.ndarray]
    wavenumber: dict[str, np.ndarray]
    thickness: float
    material: Material


def lamb_dispersion(thickness: float, material: Material, frequencies: ArrayLike,
                    resolution: int = 2000) -> LambDispersion:
    """Trace A0, S0 and A1 over ascending positive ``frequencies`` (Hz) for a plate.

    Parameters
    ----------
    thickness: plate thickness t, m.
    material: plate material.
    frequencies: ascending frequencies > 0, Hz.
    resolution: k-grid points used to bracket roots at each frequency (refined on demand).
    """
    f = np.asarray(frequencies, dtype=float)
    if f.ndim != 1 or f.size == 0 or not np.all(np.isfinite(f)) or f.min() <= 0.0:
        raise ValueError("frequencies must be a non-empty 1-D array of positive numbers")
    if np.any(np.diff(f) <= 0.0):
        raise ValueError("frequencies must be strictly ascending")
    if not thickness > 0.0:
        raise ValueError(f"thickness must be > 0, got {thickness!r}")
    h = 0.5 * thickness
    c_t = material.shear_velocity
    kappa = c_t / material.longitudinal_velocity
    c_r = rayleigh_velocity(material)
    W = 2.0 * pi * f * h / c_t
    # A0 has the largest k; its phase velocity stays below both c_R and the Kirchhoff value but
    # not far below the smaller of them (0.77 of it at worst for nu in [0, 0.49]), so 3x the
    # larger wavenumber bounds every root; the tracer also checks A0 stays clear of the bound.
    kirchhoff_kh = sqrt(h * h * sqrt(12.0) / (thickness * material.plate_velocity))

    def k_bound(w: np.ndarray) -> np.ndarray:
        """3 max(K_Rayleigh, K_Kirchhoff) at W (K = k h)."""
        return 3.0 * np.maximum(w / (c_r / c_t), kirchhoff_kh * np.sqrt(w * c_t / h))

    k = {m: np.full(f.size, np.nan) for m in MODES}
    first_pass = {fam: _roots(fam, W, kappa, k_bound(W), resolution) for fam in "AS"}
    tracer = _Tracer(kappa, resolution, k_bound)
    for j in range(f.size):
        precomputed = {fam: first_pass[fam][j] for fam in "AS"}
        found = tracer.advance(W[j], precomputed)
        if found is None:
            raise SimulationError(
                f"Lamb root tracing lost a branch at {f[j]:.6g} Hz (t = {thickness} m)")
        for m in MODES:
            k[m][j] = found[m]
    phase = {}
    group = {}
    wavenumber = {}
    for m in MODES:
        family = m[0]
        K = k[m]
        phase[m] = c_t * W / K
        group[m] = c_t * _group_velocity_ratio(family, K, W, kappa)
        wavenumber[m] = K / h
    return LambDispersion(f, phase, group, wavenumber, thickness, material)


class _Tracer:
    """Follows A0, S0 and A1 along increasing frequency, remembering the last two points.

    A step is accepted when the roots bracketed at the new frequency continue every branch (see
    :meth:`_continues`). When they do not, the k grid is refined (a root pair may share a grid
    cell) and, failing that, the frequency step is split into four and walked in small steps.
    """

    def __init__(self, kappa: float, resolution: int,
                 k_bound: Callable[[np.ndarray], np.ndarray]) -> None:
        self.kappa = kappa
        self.resolution = resolution
        self.k_bound = k_bound
        self.history: list[tuple[float, dict[str, float]]] = []

    def _found(self, W: float, n: int,
               roots: dict[str, np.ndarray] | None) -> tuple[dict[str, float], bool]:
        k_max = float(self.k_bound(np.array(W)))
        if roots is None:
            roots = {fam: _roots(fam, np.array([W]), self.kappa, np.array([k_max]), n)[0]
                     for fam in "AS"}
        a_roots, s_roots = roots["A"], roots["S"]
        found = {
            "A0": a_roots[0] if a_roots.size else np.nan,
            "A1": a_roots[1] if a_roots.size > 1 else np.nan,
            "S0": s_roots[0] if s_roots.size else np.nan,
        }
        cell = k_max / n
        crowded = any(bool(np.any(np.diff(r[::-1]) < 3.0 * cell)) for r in (a_roots, s_roots))
        if np.isfinite(found["A0"]) and found["A0"] > 0.7 * k_max:
            raise SimulationError(f"A0 root near the search bound at W = {W:.6g}")
        return found, crowded

    def advance(self, W: float, roots: dict[str, np.ndarray] | None = None,
                depth: int = 0) -> dict[str, float] | None:
        """Roots at W continuing the traced branches, or None if they cannot be followed."""
        for attempt in range(3):
            n = self.resolution * 8**attempt
            found, crowded = self._found(W, n, roots if attempt == 0 else None)
            if not crowded and self._continues(W, found):
                self.history = [*self.history[-1:], (W, found)]
                return found
        if depth >= 4 or not self.history:
            return None
        w_prev = self.history[-1][0]
        for w_sub in np.linspace(w_prev, W, 5)[1:-1]:
            if self.advance(w_sub, None, depth + 1) is None:
                return None
        return self.advance(W, None, depth + 1)

    def _continues(self, W: float, found: dict[str, float]) -> bool:
        """Whether ``found`` at W continues the branches traced so far without a jump.

        A0 and S0 must exist at every frequency; A1 may appear (cut-off) but never disappear,
        and stays below A0 in k. A0 and S0 are extrapolated in log-log coordinates from their
        last two points (slope 1 when there is only one: A0's k grows as w^(1/2) to w^1, S0's as
        w^1 to about w^2.5 where its phase velocity drops); the new root must land within
        0.02 + 0.3 |d ln w| of that (0.02 + 1.5 |d ln w| without a slope). A1 is extrapolated as
        k^2 linear in w, exact at its cut-off (k ~ sqrt(f - f_c)), and must land within 5 % of
        its last k^2 plus the last change. A jump to a neighbouring mode (at least 7 % in k, even
        where A0 and A1 approach c_R and c_T) fails once the steps are small, and the tracer
        makes them small.
        """
        if not (np.isfinite(found["A0"]) and np.isfinite(found["S0"])):
            return False
        if np.isfinite(found["A1"]) and not found["A1"] < found["A0"]:
            return False
        if not self.history:
            return True
        w_prev, k_prev = self.history[-1]
        before = self.history[-2] if len(self.history) == 2 else None
        d_ln_w = np.log(W / w_prev)
        for m, value in found.items():
            prev = k_prev[m]
            if not np.isfinite(prev):
                continue
            if not np.isfinite(value):
                return False
            old = before[1][m] if before is not None else np.nan
            if m == "A1":
                if before is None or not np.isfinite(old):
                    continue  # second point after the cut-off: nothing to extrapolate from
                change = prev**2 - old**2
                guess = prev**2 + change * (W - w_prev) / (w_prev - before[0])
                if abs(value**2 - guess) > 0.05 * prev**2 + abs(change):
                    return False
                continue
            if before is not None and np.isfinite(old):
                slope = np.log(prev / old) / np.log(w_prev / before[0])
                tolerance = 0.02 + 0.3 * abs(d_ln_w)
            else:
                slope, tolerance = 1.0, 0.02 + 1.5 * abs(d_ln_w)
            if abs(np.log(value) - np.log(prev) - slope * d_ln_w) > tolerance:
                return False
        return True
