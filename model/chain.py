"""Compiled per-step kernels of the discrete element chain (the paper's Sec. 3.1, Eqs. 1-2).

Particles are numbered 0..N: 0 is the striker, 1..N the chain, N stands on the plate. ``u[n]`` is
the downward displacement of particle n from a reference in which neighbours just touch, so the
overlap of contact j (between particles j and j + 1) is ``u[j] - u[j + 1]`` and the overlap with the
plate is ``u[N] - w`` (w: the plate's top surface under the chain). Contact forces are Hertzian,
``A [delta]_+^(3/2)``: an open contact carries nothing (no tension).

The contact laws themselves live in :mod:`solitonde.model.laws` (written once for every driver).
Every function here is a small ``@njit(cache=True)`` kernel that knows nothing about the plate:
a driver loop in :mod:`solitonde.model.tiers` (or a later plate tier) owns the bottom surface
``w``, advances it, and calls these kernels in the order

    plate half step -> :func:`verlet_step` (w frozen) -> plate half step -> :func:`track_peaks`
    and, every ``n_sub`` steps, :func:`record_sample`.

Time stepping is velocity Verlet (kick-drift-kick), symplectic and second order; see
:func:`solitonde.model.plan.choose_time_step` for the step size and its error.

Dissipation (optional) is the Kuwabara-Kono viscoelastic Hertz law as written by Brilliantov,
Spahn, Hertzsch and Pöschel (Phys. Rev. E 53, 5382, 1996; Kuwabara & Kono, Jpn. J. Appl. Phys. 26,
1230, 1987): ``F = A delta^(3/2) + (3/2) A tau sqrt(delta) delta'``, clamped at zero so that a
separating contact never pulls. ``tau`` (s) is the material's dissipative time constant. It acts
on the sphere-sphere contacts only; the bottom contact stays elastic so that the plate model alone
decides what the plate takes.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .laws import hertz, kuwabara_kono, overlap_52
from .record import ChainRecord

# Layout of the peak tracker array used by :func:`track_peaks`.
PK_PREV2, PK_PREV1 = 0, 1
PK_INC_F, PK_INC_T = 2, 3
PK_REF_F, PK_REF_T = 4, 5
PK_BOT_F, PK_BOT_T = 6, 7
PK_SIZE = 8


_FRESH_TRACKER = np.full(PK_SIZE, -np.inf)
_FRESH_TRACKER[[PK_INC_T, PK_REF_T, PK_BOT_T]] = np.nan
_FRESH_TRACKER.flags.writeable = False


def new_peak_tracker() -> np.ndarray:
    """A fresh tracker: no peak seen yet (values -inf, times NaN); a copy of one made at import
    (a quarter of the time np.full and three stores take, once a run)."""
    return _FRESH_TRACKER.copy()


@njit(cache=True)
def contact_forces(u: np.ndarray, a_s: float, a_0: float, f: np.ndarray) -> None:
    """Elastic forces of the N sphere-sphere contacts into ``f`` (len N); u has len N + 1.
    Contact 0 (striker on particle 1) has the constant ``a_0``, the others ``a_s``."""
    for j in range(f.size):
        f[j] = hertz(a_s, u[j] - u[j + 1])
    if a_0 != a_s:  # after the loop, which stays one vectorised pass
        f[0] = hertz(a_0, u[0] - u[1])


@njit(cache=True)
def damped_contact_forces(
    u: np.ndarray, v: np.ndarray, a_s: float, a_0: float, tau: float, f: np.ndarray
) -> float:
    """Kuwabara-Kono forces of the sphere-sphere contacts into ``f``; returns the dissipated power.

    ``v`` is the velocity at which the viscous part is evaluated (a second-order predictor in
    :func:`verlet_step`). The dissipated power is the viscous force times the approach rate, over
    the closed contacts; it is >= 0 because the clamp only removes pulling force.
    """
    power = 0.0
    for j in range(f.size):
        f[j], lost = kuwabara_kono(a_s, tau, u[j] - u[j + 1], v[j] - v[j + 1])
        power += lost
    if a_0 != a_s:  # the striker's contact, redone with its own constant
        _, lost = kuwabara_kono(a_s, tau, u[0] - u[1], v[0] - v[1])
        f[0], lost_0 = kuwabara_kono(a_0, tau, u[0] - u[1], v[0] - v[1])
        power += lost_0 - lost
    return power


@njit(cache=True)
def accelerations(
    f: np.ndarray, f_bottom: float, inv_m: float, inv_m0: float, g: float, acc: np.ndarray
) -> None:
    """Newton's law for every particle: gravity, the contact above pushes down, below pushes up
    (``inv_m0``: 1 / the striker's mass)."""
    n = acc.size - 1
    acc[0] = g - f[0] * inv_m0
    for i in range(1, n):
        acc[i] = g + (f[i - 1] - f[i]) * inv_m
    acc[n] = g + (f[n - 1] - f_bottom) * inv_m


@njit(cache=True)
def kick(v: np.ndarray, acc: np.ndarray, h: float) -> None:
    """v += h a."""
    for i in range(v.size):
        v[i] += h * acc[i]


@njit(cache=True)
def drift(u: np.ndarray, v: np.ndarray, h: float) -> None:
    """u += h v."""
    for i in range(u.size):
        u[i] += h * v[i]


@njit(cache=True)
def bottom_acceleration(
    acc: np.ndarray, f: np.ndarray, f_bottom: float, inv_m: float, g: float
) -> None:
    """Refresh the last particle's acceleration after the plate moved (w changed, u did not)."""
    n = acc.size - 1
    acc[n] = g + (f[n - 1] - f_bottom) * inv_m


@njit(cache=True)
def verlet_step(
    u: np.ndarray,
    v: np.ndarray,
    acc: np.ndarray,
    f: np.ndarray,
    vp: np.ndarray,
    w: float,
    a_s: float,
    a_0: float,
    a_b: float,
    inv_m: float,
    inv_m0: float,
    g: float,
    tau: float,
    dt: float,
) -> tuple[float, float]:
    """One kick-drift-kick step of the chain with the bottom surface frozen at ``w``.

    On entry ``acc`` must hold the accelerations at (u, w) (and ``f`` the matching contact
    forces); on exit u, v, f, acc are advanced by ``dt``. ``vp`` is scratch of len N + 1 used only
    with dissipation (``tau > 0``): the viscous force is evaluated at the predicted end-of-step
    velocity, which keeps the scheme second order. Returns (bottom force, dissipated power), both
    at the end of the step.
    """
    half = 0.5 * dt
    kick(v, acc, half)
    drift(u, v, dt)
    n = u.size - 1
    f_bottom = hertz(a_b, u[n] - w)
    power = 0.0
    if tau > 0.0:
        # Two fixed-point passes for the end-of-step velocity the viscous force depends on:
        # the first (elastic force only) is O(dt) off, the second O(dt^2), keeping order two.
        contact_forces(u, a_s, a_0, f)
        for _ in range(2):
            accelerations(f, f_bottom, inv_m, inv_m0, g, acc)
            for i in range(v.size):
                vp[i] = v[i] + half * acc[i]
            power = damped_contact_forces(u, vp, a_s, a_0, tau, f)
    else:
        contact_forces(u, a_s, a_0, f)
    accelerations(f, f_bottom, inv_m, inv_m0, g, acc)
    kick(v, acc, half)
    return f_bottom, power


@njit(cache=True)
def sensor_reading(f: np.ndarray, f_bottom: float, sensor: int) -> float:
    """Mean of the sensor particle's two contact forces; ``sensor`` is 1..N (striker excluded)."""
    above = f[sensor - 1]
    below = f[sensor] if sensor < f.size else f_bottom
    return 0.5 * (above + below)


@njit(cache=True, fastmath={"reassoc", "contract", "nsz"}, error_model="numpy")
def chain_energy(
    u: np.ndarray,
    v: np.ndarray,
    u0: np.ndarray,
    w: float,
    m: float,
    g: float,
    a_s: float,
    a_b: float,
    m0: float,
    a_0: float,
) -> float:
    """Kinetic + contact (including the bottom contact) + gravity energy of the chain, J.

    Gravity energy is ``-m g sum(u - u0)``: measured from the start so that it stays small. The
    contact energies ``(2/5) A d^(5/2)`` are summed branch-free (open contacts as d = 0) with
    reassociation allowed, so the loops vectorise: the adaptive driver evaluates this at every
    step end. The striker's own mass ``m0`` and contact ``a_0`` enter as corrections to the
    uniform sums, exactly zero when the striker is one of the chain's spheres.
    """
    kin = 0.0
    grav = 0.0
    for i in range(u.size):
        kin += v[i] * v[i]
        grav += u[i] - u0[i]
    pot = 0.0
    for j in range(u.size - 1):
        pot += overlap_52(u[j] - u[j + 1])
    n = u.size - 1
    return (0.5 * m * kin + 0.4 * (a_s * pot + a_b * overlap_52(u[n] - w)) - m * g * grav
            + striker_correction(u, v, u0, m, g, a_s, m0, a_0))


@njit(cache=True, inline="always")
def striker_mass_terms(u: np.ndarray, v: np.ndarray, u0: np.ndarray, m: float, m0: float,
                       g: float) -> float:
    """Kinetic and gravity energy that sums over uniform masses miss for a striker of mass
    ``m0``; 0.0 exactly when m0 = m."""
    if m0 == m:
        return 0.0
    return 0.5 * (m0 - m) * v[0] * v[0] - (m0 - m) * g * (u[0] - u0[0])


@njit(cache=True, inline="always")
def striker_correction(u: np.ndarray, v: np.ndarray, u0: np.ndarray, m: float, g: float,
                       a_s: float, m0: float, a_0: float) -> float:
    """What the uniform chain energy misses when the striker differs: its mass in the kinetic and
    gravity terms, its contact constant in the first contact's energy; 0.0 exactly otherwise."""
    if a_0 == a_s:
        return striker_mass_terms(u, v, u0, m, m0, g)
    return (striker_mass_terms(u, v, u0, m, m0, g)
            + 0.4 * (a_0 - a_s) * overlap_52(u[0] - u[1]))


@njit(cache=True)
def track_peaks(pk: np.ndarray, t: float, dt: float, f_sensor: float, f_bottom: float) -> None:
    """Step-resolution truth: the incident and reflected peaks of the sensor reading.

    The incident peak is the largest local maximum of the sensor reading before the bottom
    contact force reaches its maximum, the reflected peak the largest one after it. A local
    maximum found at step t - dt is refined by the parabola through its three samples, which makes
    the peak time and height accurate to O(dt^2) and O(dt^3) of the smooth pulse.
    """
    f2 = pk[PK_PREV2]
    f1 = pk[PK_PREV1]
    if f1 > f2 and f1 >= f_sensor:
        denom = f2 - 2.0 * f1 + f_sensor
        shift = 0.0
        if denom < 0.0:
            shift = 0.5 * (f2 - f_sensor) / denom
        t_peak = t - dt + shift * dt
        f_peak = f1 - 0.25 * (f2 - f_sensor) * shift
        if t - dt <= pk[PK_BOT_T] or np.isnan(pk[PK_BOT_T]):
            if f_peak > pk[PK_INC_F]:
                pk[PK_INC_F] = f_peak
                pk[PK_INC_T] = t_peak
        elif f_peak > pk[PK_REF_F]:
            pk[PK_REF_F] = f_peak
            pk[PK_REF_T] = t_peak
    if f_bottom > pk[PK_BOT_F]:
        pk[PK_BOT_F] = f_bottom
        pk[PK_BOT_T] = t
        if pk[PK_REF_F] > pk[PK_INC_F]:
            pk[PK_INC_F] = pk[PK_REF_F]
            pk[PK_INC_T] = pk[PK_REF_T]
        pk[PK_REF_F] = -np.inf
        pk[PK_REF_T] = np.nan
    pk[PK_PREV2] = f1
    pk[PK_PREV1] = f_sensor


@njit(cache=True)
def record_sample(
    k: int,
    u: np.ndarray,
    v: np.ndarray,
    f: np.ndarray,
    w: float,
    a_b: float,
    sensor: int,
    samples: np.ndarray,
    u_trace: np.ndarray,
    v_trace: np.ndarray,
    f_trace: np.ndarray,
    w_trace: np.ndarray,
) -> None:
    """Store sample k: the sensor reading and, when trace arrays have rows, the particle fields.

    The bottom force is recomputed from (u, w) because a plate tier may have moved w after the
    last force evaluation. Trace arrays with zero rows mean traces are off and cost nothing.
    """
    n = u.size - 1
    f_bottom = hertz(a_b, u[n] - w)
    samples[k] = sensor_reading(f, f_bottom, sensor)
    if u_trace.shape[0] > 0:
        for i in range(n + 1):
            u_trace[k, i] = u[i]
            v_trace[k, i] = v[i]
        for j in range(n):
            f_trace[k, j] = f[j]
        f_trace[k, n] = f_bottom
        w_trace[k] = w


@njit(cache=True)
def record_into(rec: ChainRecord, k: int, f: np.ndarray, w: float) -> None:
    """:func:`record_sample` of sample k into the run record's own arrays."""
    record_sample(k, rec.u, rec.v, f, w, rec.a_b, rec.sensor, rec.samples, rec.u_trace,
                  rec.v_trace, rec.f_trace, rec.w_trace)
