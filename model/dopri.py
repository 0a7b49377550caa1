"""Adaptive Dormand-Prince 5(4) driver for the chain on a wall or a Zener dashpot (``dopri5``).

The same equations as :func:`solitonde.model.tiers.dashpot.dashpot_run` (the paper's Secs. 3.1,
3 and 5), written as one first-order system and integrated with the explicit Runge-Kutta pair of
Dormand and Prince (J. Comp. Appl. Math. 6, 19, 1980) in the form of Hairer's DOPRI5 (Hairer,
Norsett, Wanner, *Solving ODEs I*, 2nd ed., section II.5): FSAL, a PI step-size controller and the
4th-order continuous extension ("dense output") that fills the sample grid. It is the method of
scipy's ``solve_ivp(method="RK45")`` and MATLAB's ode45 (the paper's integrator), compiled.

State vector ``y`` (length 2 (N + 1) + 3)::

    y[0 : N+1]        u, downward displacements of particles 0..N (0 = striker), m
    y[N+1 : 2N+2]     v, velocities, m/s
    y[2N+2]           w, the plate's top surface under the chain, m (stays 0 on a wall)
    y[2N+3]           W, work done on the plate, J:  W' = F_b w'
    y[2N+4]           D, energy dissipated in the contacts, J:  D' = dissipated power

with ``u_i' = v_i``, ``v_i' = g + (F_{i-1} - F_i) / m_i`` (F_{-1} = 0, F_N = F_b; m_0 the
striker's mass, m_i = m otherwise; contact 0 has the striker's constant A_0),
``F_b = A_b [u_N - w]_+^(3/2)``, ``w' = (F_b - F_static) / Z`` (``inv_z = 1 / Z``, 0 for a wall)
and the sphere contacts elastic Hertz or, with ``tau > 0``, Kuwabara-Kono
``F = [A d^(3/2) + (3/2) A tau d^(1/2) d']_+`` as in :mod:`solitonde.model.chain`. Carrying W and D
as components makes the energy balance (chain energy + W + D) a by-product of the same solve.

Error control is scipy's: the RMS over the components of ``err_i / (atol_i + rtol max(|y_i|,
|y_i new|))`` with ``atol_i = rtol x scale_i`` (the caller's typical magnitude of component i), so
``rtol`` is the one accuracy knob.

Outputs per sample come from the dense output of the step that contains the sample time: the sensor
reading (from the few particles it involves: the sensor, its neighbours, the bottom particle and
the plate) and, when traces are on, every particle field. The energy balance (the chain energy of
:func:`solitonde.model.chain.chain_energy`, plus the plate work W and the dissipated energy D) is
computed from the integrator's own state at every accepted step end, not from the interpolant:
energy at samples is interpolated between step ends (linearly in time); energy_drift is measured at
step ends (the driver returns the largest deviation there). Peaks: the sampled readings go through
:func:`solitonde.model.chain.track_peaks` (which sorts incident from reflected around the
bottom-force maximum), and the three peaks it finds (incident, reflected, bottom) are then refined
on the dense output itself by a golden-section search over the two sample intervals around each, so
the peak truth carries the interpolant's accuracy, not the sample grid's.
"""

from __future__ import annotations

from math import exp, log, sqrt
from typing import Any, NamedTuple

import numpy as np
from numba import literal_unroll, njit

from .chain import (
    PK_BOT_F,
    PK_BOT_T,
    PK_INC_F,
    PK_INC_T,
    PK_REF_F,
    PK_REF_T,
    chain_energy,
    track_peaks,
)
from .laws import hertz, kuwabara_kono, sphere_contact
from .record import ChainRecord
from .status import RUN_NONFINITE, RUN_OK
from .status import RUN_STEP_BUDGET as RUN_STEP_BUDGET  # re-exported for simulate
from .status import RUN_STEP_TOO_SMALL as RUN_STEP_TOO_SMALL

# Dormand-Prince 5(4) tableau (Hairer's DOPRI5 constants).
C2, C3, C4, C5 = 1.0 / 5.0, 3.0 / 10.0, 4.0 / 5.0, 8.0 / 9.0
A21 = 1.0 / 5.0
A31, A32 = 3.0 / 40.0, 9.0 / 40.0
A41, A42, A43 = 44.0 / 45.0, -56.0 / 15.0, 32.0 / 9.0
A51, A52, A53, A54 = 19372.0 / 6561.0, -25360.0 / 2187.0, 64448.0 / 6561.0, -212.0 / 729.0
A61, A62, A63 = 9017.0 / 3168.0, -355.0 / 33.0, 46732.0 / 5247.0
A64, A65 = 49.0 / 176.0, -5103.0 / 18656.0
A71, A73, A74 = 35.0 / 384.0, 500.0 / 1113.0, 125.0 / 192.0
A75, A76 = -2187.0 / 6784.0, 11.0 / 84.0
E1, E3, E4 = 71.0 / 57600.0, -71.0 / 16695.0, 71.0 / 1920.0
E5, E6, E7 = -17253.0 / 339200.0, 22.0 / 525.0, -1.0 / 40.0
D1, D3, D4 = -12715105075.0 / 11282082432.0, 87487479700.0 / 32700410799.0, \
    -10690763975.0 / 1880347072.0
D5, D6, D7 = 701980252875.0 / 199316789632.0, -1453857185.0 / 822651844.0, \
    69997945.0 / 29380423.0

# Step-size control (Hairer's defaults for DOPRI5).
SAFETY = 0.9
FAC_MIN = 0.2  # the step shrinks at most 5-fold ...
FAC_MAX = 10.0  # ... and grows at most 10-fold per step
BETA = 0.04  # PI stabilisation
EXPO = 0.2 - 0.75 * BETA

#: Floating-point licence of the kernels: reassociation (vectorised sums) and fused multiply-add,
#: but not "no NaN/inf", so the finiteness checks stay meaningful.
FASTMATH = {"reassoc", "contract", "nsz"}

# Rows of the driver's work array (see integrate_dopri5): the state and its 5th-order update,
# the stages k0 .. k6, atol, the dense output in Hairer's form (_RC, 5 rows) and in powers of
# theta (_PW, 5 rows), and a block's step fractions, sensor readings and bottom forces.
_Y, _Y1, _K0, _K1, _K2, _K3, _K4, _K5, _K6, _ATOL = 0, 1, 2, 3, 4, 5, 6, 7, 8, 9
_RC, _PW, _TH, _OUT, _FBOT, _ROWS = 10, 15, 20, 21, 22, 23

# Samples evaluated together (see _sample_block).
_BLOCK = 64

# Components whose dense output the peak refinement keeps per step.
_TRACK = 8


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _rhs(
    ws: np.ndarray, src: int, dst: int, n: int, inv_m: float, g: float, a_s: float, a_b: float,
    inv_z: float, f_static: float, tau: float, a0_scale: float, inv_m0: float,
) -> None:
    """Row ``dst`` of the work array ``ws`` = y'(row ``src``). The striker: ``a0_scale`` its
    contact constant over the chain's (1.0 for one of the chain's spheres), ``inv_m0`` 1 / its
    mass. One array, not three (see _KERNEL).

    Each contact force is evaluated once, going down the chain, and carried to the next
    particle in a scalar. Measured on the default scene (driver 50 us): storing the forces in a
    row first and differencing them took 58 us, forces evaluated twice in a vectorised loop
    85 us, and the elastic code with the damped form split off into a function of its own 60 us
    (the smaller function, presumably inlined into the driver's seven call sites); the damped
    scene ran 58 us stored, 53 carried.
    """
    y, dy = src, dst
    np1 = n + 1
    if tau <= 0.0 and n > 0:
        f_b = hertz(a_b, ws[y, n] - ws[y, 2 * np1])
        for i in range(np1):
            ws[dy, i] = ws[y, np1 + i]
        f_prev = hertz(a_s, ws[y, 0] - ws[y, 1]) * a0_scale  # Hertz is linear in the constant
        ws[dy, np1] = g - f_prev * inv_m0
        for i in range(1, n):
            f_i = hertz(a_s, ws[y, i] - ws[y, i + 1])
            ws[dy, np1 + i] = g + (f_prev - f_i) * inv_m
            f_prev = f_i
        ws[dy, np1 + n] = g + (f_prev - f_b) * inv_m
        w_dot = (f_b - f_static) * inv_z
        ws[dy, 2 * np1] = w_dot
        ws[dy, 2 * np1 + 1] = f_b * w_dot
        ws[dy, 2 * np1 + 2] = 0.0
        return
    # Damped contacts (and a striker alone): the same, with the dissipated power summed.
    f_b = hertz(a_b, ws[y, n] - ws[y, 2 * np1])
    for i in range(np1):
        ws[dy, i] = ws[y, np1 + i]
    power = 0.0
    if n == 0:
        ws[dy, np1] = g - f_b * inv_m0
    else:
        f_prev, lost_0 = kuwabara_kono(a_s, tau, ws[y, 0] - ws[y, 1],
                                       ws[y, np1] - ws[y, np1 + 1])
        power = lost_0
        f_prev *= a0_scale  # the force law is linear in the contact constant
        ws[dy, np1] = g - f_prev * inv_m0
        for i in range(1, n):
            f_i, lost = kuwabara_kono(a_s, tau, ws[y, i] - ws[y, i + 1],
                                      ws[y, np1 + i] - ws[y, np1 + i + 1])
            power += lost
            ws[dy, np1 + i] = g + (f_prev - f_i) * inv_m
            f_prev = f_i
        ws[dy, np1 + n] = g + (f_prev - f_b) * inv_m
        if a0_scale != 1.0:  # the striker's contact dissipates at its own constant
            power += (a0_scale - 1.0) * lost_0
    w_dot = (f_b - f_static) * inv_z
    ws[dy, 2 * np1] = w_dot
    ws[dy, 2 * np1 + 1] = f_b * w_dot
    ws[dy, 2 * np1 + 2] = power


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _poly(p: np.ndarray, i: int, x: float) -> float:
    """Component i of the dense output ``p`` (5 x M, powers of theta) at theta = x."""
    return p[0, i] + x * (p[1, i] + x * (p[2, i] + x * (p[3, i] + x * p[4, i])))


@njit(cache=True, inline="always")
def _difference(ws: np.ndarray, i: int, j: int) -> tuple[float, float, float, float, float]:
    """Coefficients (powers of theta) of component i minus component j of the dense output in
    rows _PW .. _PW + 4 of ``ws``: the polynomial of an overlap or an approach rate, one Horner
    chain instead of two."""
    return (ws[_PW, i] - ws[_PW, j], ws[_PW + 1, i] - ws[_PW + 1, j],
            ws[_PW + 2, i] - ws[_PW + 2, j], ws[_PW + 3, i] - ws[_PW + 3, j],
            ws[_PW + 4, i] - ws[_PW + 4, j])


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _sample_sensor(
    ws: np.ndarray, cnt: int, n: int, a_s: float, a_b: float, tau: float, sensor: int,
    a_up: float,
) -> None:
    """Sensor readings at the step fractions ``ws[_TH, :cnt]`` from the dense output in rows
    _PW .. _PW + 4 of the work array, into ``ws[_OUT, :cnt]``, and the bottom forces (for the
    peak tracker) into ``ws[_FBOT, :cnt]`` (``a_up``: the constant of the sensor's upper
    contact, the striker's when the sensor is particle 1).

    Evaluates only what a reading needs (traces off): the overlaps of the sensor's two contacts
    (the lower one the bottom contact when the sensor is particle N) and of the bottom contact,
    and the approach rates of the sensor's contacts only when they are damped (tau > 0). Each is
    one polynomial in theta, the difference of two components' coefficients, taken once per
    step; the loops over the samples then have no branches and vectorise.
    """
    np1 = n + 1
    iw = 2 * np1
    up = sensor - 1
    last = sensor == n
    a_dn = a_b if last else a_s
    b0, b1, b2, b3, b4 = _difference(ws, n, iw)  # u[N] - w
    c0, c1, c2, c3, c4 = _difference(ws, up, sensor)  # the contact above the sensor
    d0, d1, d2, d3, d4 = _difference(ws, sensor, iw if last else sensor + 1)  # the one below
    if tau > 0.0:
        r0, r1, r2, r3, r4 = _difference(ws, np1 + up, np1 + sensor)
        q0, q1, q2, q3, q4 = 0.0, 0.0, 0.0, 0.0, 0.0
        if not last:
            q0, q1, q2, q3, q4 = _difference(ws, np1 + sensor, np1 + sensor + 1)
        # The bottom contact is elastic: at rate 0 the Kuwabara-Kono force is Hertz's exactly.
        for s in range(cnt):
            x = ws[_TH, s]
            fb = hertz(a_b, b0 + x * (b1 + x * (b2 + x * (b3 + x * b4))))
            above = kuwabara_kono(a_up, tau, c0 + x * (c1 + x * (c2 + x * (c3 + x * c4))),
                                  r0 + x * (r1 + x * (r2 + x * (r3 + x * r4))))[0]
            below = kuwabara_kono(a_dn, tau, d0 + x * (d1 + x * (d2 + x * (d3 + x * d4))),
                                  q0 + x * (q1 + x * (q2 + x * (q3 + x * q4))))[0]
            ws[_OUT, s] = 0.5 * (above + below)
            ws[_FBOT, s] = fb
    else:
        for s in range(cnt):
            x = ws[_TH, s]
            fb = hertz(a_b, b0 + x * (b1 + x * (b2 + x * (b3 + x * b4))))
            above = hertz(a_up, c0 + x * (c1 + x * (c2 + x * (c3 + x * c4))))
            below = hertz(a_dn, d0 + x * (d1 + x * (d2 + x * (d3 + x * d4))))
            ws[_OUT, s] = 0.5 * (above + below)
            ws[_FBOT, s] = fb


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _sample_block(
    p: np.ndarray, th: np.ndarray, cnt: int, k0: int, n: int, a_s: float, a_b: float,
    tau: float, sensor: int, scratch: np.ndarray, samples: np.ndarray, u_trace: np.ndarray,
    v_trace: np.ndarray, f_trace: np.ndarray, w_trace: np.ndarray, a_0: float,
) -> None:
    """Samples k0 .. k0 + cnt - 1 with every particle field (traces on), from one step's dense
    output ``p`` (5 x M, powers of theta) at step fractions ``th[:cnt]``.

    The samples of one step are evaluated together, particle by particle, so that the inner
    loops run over samples (they vectorise). Fills the sensor reading, the traces and
    ``scratch[9, :cnt]`` with the bottom force for the peak tracker. ``scratch`` is (10, >= cnt)
    work space.
    """
    np1 = n + 1
    u_cur, u_prev, v_cur, v_prev = scratch[0], scratch[1], scratch[2], scratch[3]
    force, f_up, f_bot = scratch[7], scratch[8], scratch[9]
    for s in range(cnt):
        f_up[s] = 0.0
    for i in range(np1):
        a0, a1, a2, a3, a4 = p[0, i], p[1, i], p[2, i], p[3, i], p[4, i]
        b0, b1, b2, b3, b4 = p[0, np1 + i], p[1, np1 + i], p[2, np1 + i], p[3, np1 + i], \
            p[4, np1 + i]
        for s in range(cnt):
            x = th[s]
            u_cur[s] = a0 + x * (a1 + x * (a2 + x * (a3 + x * a4)))
            v_cur[s] = b0 + x * (b1 + x * (b2 + x * (b3 + x * b4)))
        if i > 0:
            j = i - 1
            a_j = a_0 if j == 0 else a_s  # contact 0 is the striker's
            if tau > 0.0:
                for s in range(cnt):
                    force[s] = kuwabara_kono(a_j, tau, u_prev[s] - u_cur[s],
                                             v_prev[s] - v_cur[s])[0]
            else:
                for s in range(cnt):
                    force[s] = hertz(a_j, u_prev[s] - u_cur[s])
            # The sensor's contacts: j = sensor - 1 above it, j = sensor below it.
            if j == sensor - 1:
                for s in range(cnt):
                    f_up[s] = force[s]
            elif j == sensor:
                for s in range(cnt):
                    f_up[s] += force[s]
            for s in range(cnt):
                f_trace[k0 + s, j] = force[s]
        for s in range(cnt):
            u_trace[k0 + s, i] = u_cur[s]
            v_trace[k0 + s, i] = v_cur[s]
        u_cur, u_prev = u_prev, u_cur
        v_cur, v_prev = v_prev, v_cur
    iw = 2 * np1
    for s in range(cnt):
        w = _poly(p, iw, th[s])
        fb = hertz(a_b, u_prev[s] - w)
        f_bot[s] = fb
        reading = f_up[s] + fb if sensor == n else f_up[s]
        samples[k0 + s] = 0.5 * reading
        f_trace[k0 + s, n] = fb
        w_trace[k0 + s] = w


@njit(cache=True)
def _tracked_value(
    which: int, t: float, hist_t: np.ndarray, hist_h: np.ndarray, hist_c: np.ndarray,
    n_hist: int, n: int, a_s: float, a_b: float, tau: float, sensor: int, a_up: float,
) -> float:
    """Sensor reading (``which`` 0) or bottom force (1) at time t from the kept dense output
    (``a_up``: the constant of the sensor's upper contact).

    ``hist_c[k]`` holds rcont1..5 of step k for the components u[s-1], u[s], u[s+1], u[N], w,
    v[s-1], v[s], v[s+1] (indices clipped to the chain), in that order.
    """
    lo, hi = 0, n_hist - 1
    while lo < hi:  # last step starting at or before t
        mid = (lo + hi + 1) // 2
        if hist_t[mid] <= t:
            lo = mid
        else:
            hi = mid - 1
    theta = (t - hist_t[lo]) / hist_h[lo]
    theta = min(max(theta, 0.0), 1.0)
    rc = hist_c[lo]
    f_b = hertz(a_b, _at(rc, 3, theta) - _at(rc, 4, theta))
    if which == 1:
        return f_b
    above = _contact_at(rc, 0, theta, a_up, tau)
    below = f_b if sensor == n else _contact_at(rc, 1, theta, a_s, tau)
    return 0.5 * (above + below)


@njit(cache=True)
def _at(rc: np.ndarray, i: int, theta: float) -> float:
    """Component i of the continuous extension with coefficients ``rc`` (5 x M) at theta."""
    t1 = 1.0 - theta
    return rc[0, i] + theta * (rc[1, i] + t1 * (rc[2, i] + theta * (rc[3, i] + t1 * rc[4, i])))


@njit(cache=True)
def _contact_at(rc: np.ndarray, c: int, theta: float, a_s: float, tau: float) -> float:
    """Force of the sensor's contact c (0 above, 1 below) from the kept components at theta."""
    d = _at(rc, c, theta) - _at(rc, c + 1, theta)
    rate = _at(rc, 5 + c, theta) - _at(rc, 6 + c, theta) if tau > 0.0 else 0.0
    return sphere_contact(a_s, tau, d, rate)


@njit(cache=True)
def _refine_peak(
    which: int, t_guess: float, width: float, t_max: float, hist_t: np.ndarray,
    hist_h: np.ndarray, hist_c: np.ndarray, n_hist: int, n: int, a_s: float, a_b: float,
    tau: float, sensor: int, a_up: float,
) -> tuple[float, float]:
    """(time, value) of the maximum of the tracked quantity within ``t_guess +- width``.

    Golden-section search until the bracket is below 1e-5 ``width`` (26 iterations): the time is
    then known to 1e-5 of a sample interval, far below the interpolant's own error, and the value,
    flat at the top, to about (1e-5 width / pulse width)^2, i.e. 1e-12 relative.
    """
    a = max(t_guess - width, 0.0)
    b = min(t_guess + width, t_max)
    r = 0.5 * (sqrt(5.0) - 1.0)
    x1 = b - r * (b - a)
    x2 = a + r * (b - a)
    f1 = _tracked_value(which, x1, hist_t, hist_h, hist_c, n_hist, n, a_s, a_b, tau, sensor,
                        a_up)
    f2 = _tracked_value(which, x2, hist_t, hist_h, hist_c, n_hist, n, a_s, a_b, tau, sensor,
                        a_up)
    tol = 1e-5 * width
    while b - a > tol:
        if f1 >= f2:
            b, x2, f2 = x2, x1, f1
            x1 = b - r * (b - a)
            f1 = _tracked_value(which, x1, hist_t, hist_h, hist_c, n_hist, n, a_s, a_b, tau,
                                sensor, a_up)
        else:
            a, x1, f1 = x1, x2, f2
            x2 = a + r * (b - a)
            f2 = _tracked_value(which, x2, hist_t, hist_h, hist_c, n_hist, n, a_s, a_b, tau,
                                sensor, a_up)
    if f1 >= f2:
        return x1, f1
    return x2, f2


class Ode(NamedTuple):
    """Constants of the right-hand side :func:`_rhs` (n: the chain's last particle index)."""

    n: int
    inv_m: float
    g: float
    a_s: float
    a_b: float
    inv_z: float
    f_static: float
    tau: float
    a0_scale: float  # the striker's contact constant over the chain's
    inv_m0: float


# The kernels of integrate_dopri5 that the loop calls (not inlined). Each takes one array, the
# work array (see _work_array), and the driver keeps its other arrays in locals: numba takes and
# drops a reference to every array a call or an inlined helper receives (atomic operations on
# the array's reference count), and it prunes those pairs only in a function that handles one
# array. Measured on the default scene, these updates took about a third of the run.
_KERNEL: dict[str, Any] = {"cache": True, "fastmath": FASTMATH, "error_model": "numpy"}

# Helpers that run once per run, inlined into the driver (numba IR inlining).
_STEP: dict[str, Any] = {"cache": True, "inline": "always", "fastmath": FASTMATH,
                         "error_model": "numpy"}


@njit(**_STEP)
def _work_array(size: int) -> np.ndarray:
    """The driver's work array: _ROWS rows of at least max(size, _BLOCK) numbers, each row
    starting on a 64-byte boundary.

    numba aligns new arrays to 32 bytes only; a 512-bit load from a row 32 bytes off a cache line
    straddles two lines, and whether that happened depended on where the allocator put the
    array (run-to-run differences of 15 % in the driver's time were measured).
    """
    stride = (max(size, _BLOCK) + 7) // 8 * 8
    buf = np.empty(_ROWS * stride + 8)
    start = (-(buf.ctypes.data // 8)) % 8
    return buf[start:start + _ROWS * stride].reshape((_ROWS, stride))


@njit(**_STEP)
def _tolerances(
    u: np.ndarray, v: np.ndarray, m: float, a_s: float, rtol: float, atol: np.ndarray,
) -> None:
    """atol per component into ``atol``: rtol x (dynamic overlap, impact velocity, overlap,
    kinetic energy)."""
    np1 = u.size
    v_imp = 1e-9
    for i in range(np1):
        v_imp = max(v_imp, abs(v[i]))
    e_kin = 0.5 * m * v_imp * v_imp
    overlap = (2.5 * e_kin / a_s) ** 0.4
    atol[:np1] = rtol * overlap
    atol[np1:2 * np1] = rtol * v_imp
    atol[2 * np1] = rtol * overlap
    atol[2 * np1 + 1:2 * np1 + 3] = rtol * e_kin


@njit(**_STEP)
def _initial_step(ode: Ode, ws: np.ndarray, rtol: float, t_end: float) -> float:
    """Hairer's HINIT with RMS norms as scipy's select_initial_step (one RHS evaluation), from
    the state in row _Y and its derivative in row _K0 (rows _Y1 and _K1 are overwritten)."""
    size = 2 * ode.n + 5
    d0 = 0.0
    d1 = 0.0
    for i in range(size):
        sc = ws[_ATOL, i] + rtol * abs(ws[_Y, i])
        d0 += (ws[_Y, i] / sc) ** 2
        d1 += (ws[_K0, i] / sc) ** 2
    d0 = sqrt(d0 / size)
    d1 = sqrt(d1 / size)
    h = 1e-6 if (d0 < 1e-5 or d1 < 1e-5) else 0.01 * d0 / d1
    h = min(h, t_end)
    for i in range(size):
        ws[_Y1, i] = ws[_Y, i] + h * ws[_K0, i]
    _rhs(ws, _Y1, _K1, ode.n, ode.inv_m, ode.g, ode.a_s, ode.a_b, ode.inv_z, ode.f_static,
         ode.tau, ode.a0_scale, ode.inv_m0)
    d2 = 0.0
    for i in range(size):
        sc = ws[_ATOL, i] + rtol * abs(ws[_Y, i])
        d2 += ((ws[_K1, i] - ws[_K0, i]) / sc) ** 2
    d2 = sqrt(d2 / size) / h
    h1 = max(1e-6, h * 1e-3) if d1 <= 1e-15 and d2 <= 1e-15 else (0.01 / max(d1, d2)) ** 0.2
    return min(100.0 * h, h1, t_end)


@njit(**_KERNEL)
def _error_norm(
    ws: np.ndarray, iy: int, iy1: int, ik0: int, ik6: int, h: float, rtol: float, size: int,
) -> float:
    """scipy's error norm: RMS of err_i / (atol_i + rtol max(|y_i|, |y1_i|)) over the ``size``
    components (rows of ``ws``: y ``iy``, y1 ``iy1``, k0 ``ik0``, k6 ``ik6``)."""
    err = 0.0
    for i in range(size):
        r = h * (E1 * ws[ik0, i] + E3 * ws[_K2, i] + E4 * ws[_K3, i] + E5 * ws[_K4, i]
                 + E6 * ws[_K5, i] + E7 * ws[ik6, i]) / (
            ws[_ATOL, i] + rtol * max(abs(ws[iy, i]), abs(ws[iy1, i])))
        err += r * r
    return sqrt(err / size)


@njit(**_KERNEL)
def _dense_output(
    ws: np.ndarray, iy: int, iy1: int, ik0: int, ik6: int, h: float, i: int,
) -> None:
    """Dense output of component i over the accepted step (rows of ``ws`` as in
    :func:`_error_norm`): Hairer's CONTD5 coefficients into rows _RC .. _RC + 4 (for the peak
    refinement), and the same polynomial in powers of theta into rows _PW .. _PW + 4 (for Horner
    evaluation)."""
    dy = ws[iy1, i] - ws[iy, i]
    bspl = h * ws[ik0, i] - dy
    r3 = dy - h * ws[ik6, i] - bspl
    r4 = h * (D1 * ws[ik0, i] + D3 * ws[_K2, i] + D4 * ws[_K3, i] + D5 * ws[_K4, i]
              + D6 * ws[_K5, i] + D7 * ws[ik6, i])
    ws[_RC, i] = ws[iy, i]
    ws[_RC + 1, i] = dy
    ws[_RC + 2, i] = bspl
    ws[_RC + 3, i] = r3
    ws[_RC + 4, i] = r4
    ws[_PW, i] = ws[iy, i]
    ws[_PW + 1, i] = dy + bspl
    ws[_PW + 2, i] = r3 + r4 - bspl
    ws[_PW + 3, i] = -r3 - 2.0 * r4
    ws[_PW + 4, i] = r4


@njit(**_KERNEL)
def _dense_outputs(
    ws: np.ndarray, iy: int, iy1: int, ik0: int, ik6: int, h: float, size: int,
    tracked: tuple[int, int, int, int, int, int, int, int],
) -> None:
    """:func:`_dense_output` of every component (``size`` > 0: traces on), or else only of the
    ``tracked`` ones, all that the sensor reading and the peak refinement read (a fifth of the
    components on the default scene)."""
    if size > 0:
        for i in range(size):
            _dense_output(ws, iy, iy1, ik0, ik6, h, i)
    else:
        for i in literal_unroll(tracked):
            _dense_output(ws, iy, iy1, ik0, ik6, h, i)


@njit(**_STEP)
def _track_indices(n: int, sensor: int) -> tuple[int, int, int, int, int, int, int, int]:
    """Components kept for the peak refinement: u[s-1], u[s], u[s+1], u[N], w, v[s-1], v[s],
    v[s+1] (indices clipped to the chain); a tuple, not an array (see _KERNEL)."""
    np1 = n + 1
    below = min(sensor + 1, n)
    return (sensor - 1, sensor, below, n, 2 * np1, np1 + sensor - 1, np1 + sensor, np1 + below)


@njit(cache=True)
def _grown(
    hist_t: np.ndarray, hist_h: np.ndarray, hist_c: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The step history at twice its capacity, its steps copied."""
    n_hist = hist_t.size
    grown_t = np.empty(2 * n_hist)
    grown_h = np.empty(2 * n_hist)
    grown_c = np.empty((2 * n_hist, 5, _TRACK))
    grown_t[:n_hist] = hist_t
    grown_h[:n_hist] = hist_h
    grown_c[:n_hist] = hist_c
    return grown_t, grown_h, grown_c


@njit(**_STEP)
def _refine_peaks(
    rec: ChainRecord, interval: float, t_end: float, hist_t: np.ndarray, hist_h: np.ndarray,
    hist_c: np.ndarray, n_hist: int, n: int,
) -> None:
    """Refine the three peaks on the dense output (each within one sample interval of the
    parabola through its samples)."""
    pk = rec.pk
    for slot_f, slot_t, which in ((PK_INC_F, PK_INC_T, 0), (PK_REF_F, PK_REF_T, 0),
                                  (PK_BOT_F, PK_BOT_T, 1)):
        if np.isfinite(pk[slot_t]):
            tp, fp = _refine_peak(which, pk[slot_t], interval, t_end, hist_t, hist_h, hist_c,
                                  n_hist, n, rec.a_s, rec.a_b, rec.tau, rec.sensor,
                                  rec.a_0 if rec.sensor == 1 else rec.a_s)
            pk[slot_t] = tp
            pk[slot_f] = fp


# One compiled loop over the steps (try, accept or reject, emit samples, check energy), kept in one
# body so that numba compiles it as one loop with its state in locals (C901 exempt).
@njit(cache=True, nogil=True, fastmath=FASTMATH, error_model="numpy")
def integrate_dopri5(  # noqa: C901
    rec: ChainRecord, w: float, inv_z: float, interval: float, n_samples: int, rtol: float,
    max_steps: int,
) -> tuple[int, int, float, float, float, int, int, int, float]:
    """Integrate chain + plate from t = 0 to (n_samples - 1) x interval with DOPRI5.

    ``rec`` holds the chain's state, constants and outputs (:class:`~solitonde.model.record.
    ChainRecord`); ``w`` the plate's initial top surface, ``inv_z`` 1 / impedance (0: a wall),
    ``interval`` the sample interval, ``rtol`` the tolerance and ``max_steps`` the budget of
    attempted steps. ``rec.u``, ``rec.v`` are left at the final state; ``rec.pk`` gets the peaks
    (dense-output refined, see the module docstring).

    ``atol = rtol x scale`` per component, with the scales of the benchmark's RK45 run
    (tests/model/bench_chain.py): the striker's dynamic Hertz overlap ``(5 E / (2 A_0))^(2/5)`` for
    positions and the plate deflection, the impact velocity (the largest initial speed) for
    velocities, and the striker's kinetic energy E for the plate work and dissipated energy.

    ``energy`` is the balance (chain energy + plate work + dissipated) computed from the
    integrator's state at the accepted step ends; energy at samples is interpolated between step
    ends (linearly in time), and the largest deviation from the start is measured at the step
    ends themselves (the last value returned). Traces (``u_trace`` with rows) evaluate every
    particle at every sample; without them a sample evaluates only the sensor's neighbours, the
    bottom particle and the plate.

    Returns (status, samples recorded, final w, work done on the plate J, dissipated energy J,
    accepted steps, rejected steps, right-hand-side evaluations, largest |balance - start| over
    the step ends J).
    """
    # The record's fields once, into locals: the loop below reads only these.
    u, v, u0, m, g, a_s, a_b = rec.u, rec.v, rec.u0, rec.m, rec.g, rec.a_s, rec.a_b
    tau, sensor, m0, a_0 = rec.tau, rec.sensor, rec.m0, rec.a_0
    samples, energy, pk = rec.samples, rec.energy, rec.pk
    u_trace, v_trace, f_trace, w_trace = rec.u_trace, rec.v_trace, rec.f_trace, rec.w_trace
    traces = u_trace.shape[0] > 0
    a_up = a_0 if sensor == 1 else a_s  # the constant of the sensor's upper contact
    n = u.size - 1
    np1 = n + 1
    size = 2 * np1 + 3
    ode = Ode(n, 1.0 / m, g, a_s, a_b, inv_z, rec.f_static, tau, a_0 / a_s, 1.0 / m0)
    t_end = (n_samples - 1) * interval

    # The vectors of a step are rows of one work array (see _KERNEL and _work_array): y and y1
    # (the 5th-order solution), k0 .. k6 (k0 = y'(y), k6 = y'(y1)), atol, the dense output, the
    # step fractions of a block of samples, their readings and bottom forces. y and y1, k0 and
    # k6 trade rows at every accepted step.
    ws = _work_array(size)
    iy, iy1, ik0, ik6 = _Y, _Y1, _K0, _K6
    _tolerances(u, v, m0, a_0, rtol, ws[_ATOL])  # the striker: the largest speed
    for i in range(np1):
        ws[_Y, i] = u[i]
        ws[_Y, np1 + i] = v[i]
    ws[_Y, 2 * np1] = w
    ws[_Y, 2 * np1 + 1] = 0.0
    ws[_Y, 2 * np1 + 2] = 0.0
    # Positions and velocities of both state rows, for the energy balance.
    u_a, v_a = ws[_Y, :np1], ws[_Y, np1:2 * np1]
    u_b, v_b = ws[_Y1, :np1], ws[_Y1, np1:2 * np1]
    scratch = np.empty((10 if traces else 1, _BLOCK))  # _sample_block's work space
    track_idx = _track_indices(n, sensor)
    hist_t = np.empty(256)
    hist_h = np.empty(256)
    hist_c = np.empty((256, 5, _TRACK))
    n_hist = 0

    _rhs(ws, iy, ik0, ode.n, ode.inv_m, ode.g, ode.a_s, ode.a_b, ode.inv_z, ode.f_static,
         ode.tau, ode.a0_scale, ode.inv_m0)
    nfev = 1

    # Sample 0 is the initial state (a constant "interpolant").
    for i in range(size):
        ws[_PW, i] = ws[_Y, i]
        for j in range(1, 5):
            ws[_PW + j, i] = 0.0
    ws[_TH, 0] = 0.0
    if traces:
        _sample_block(ws[_PW:_PW + 5], ws[_TH], 1, 0, n, a_s, a_b, tau, sensor, scratch,
                      samples, u_trace, v_trace, f_trace, w_trace, a_0)
        ws[_FBOT, 0] = scratch[9, 0]
    else:
        _sample_sensor(ws, 1, n, a_s, a_b, tau, sensor, a_up)
        samples[0] = ws[_OUT, 0]
    e_start = (chain_energy(u_a, v_a, u0, ws[_Y, 2 * np1], m, g, a_s, a_b, m0, a_0)
               + ws[_Y, 2 * np1 + 1] + ws[_Y, 2 * np1 + 2])
    energy[0] = e_start
    e_prev = e_start
    deviation = 0.0
    if not (np.isfinite(samples[0]) and np.isfinite(e_start)):
        return RUN_NONFINITE, 1, w, 0.0, 0.0, 0, 0, nfev, deviation
    if n_samples == 1:
        pk[PK_BOT_F] = ws[_FBOT, 0]
        pk[PK_BOT_T] = 0.0
        return RUN_OK, 1, w, 0.0, 0.0, 0, 0, nfev, deviation

    h = _initial_step(ode, ws, rtol, t_end)
    nfev += 1
    t = 0.0
    next_k = 1
    accepted = 0
    rejected = 0
    log_fac_old = log(1e-4)  # Hairer's facold, kept as its logarithm
    last_rejected = False
    h_min = 1e-14 * t_end
    iw = 2 * np1  # w, then W and D
    # The outer loop only grows the step history: arrays reassigned inside the step loop cost
    # numba reference-count updates at every step (2.5 of 63 us measured).
    while next_k < n_samples:
        if n_hist == hist_t.size:
            hist_t, hist_h, hist_c = _grown(hist_t, hist_h, hist_c)
        while next_k < n_samples and n_hist < hist_t.size:
            if accepted + rejected >= max_steps:
                return (RUN_STEP_BUDGET, next_k, ws[iy, iw], ws[iy, iw + 1], ws[iy, iw + 2],
                        accepted, rejected, nfev, deviation)
            if h < h_min:
                return (RUN_STEP_TOO_SMALL, next_k, ws[iy, iw], ws[iy, iw + 1], ws[iy, iw + 2],
                        accepted, rejected, nfev, deviation)
            last = t + h >= t_end * (1.0 - 1e-13)
            if last:
                h = t_end - t
            # Stages 2..7 from (y, k0 = y'(y)): y1 the 5th-order solution, k6 = y'(y1) (FSAL).
            # Written here, not in a helper: numba's inlined helper ran the driver 8 % slower
            # (127 against 117 us on the default scene at rtol 3.2e-5).
            for i in range(size):
                ws[iy1, i] = ws[iy, i] + h * A21 * ws[ik0, i]
            _rhs(ws, iy1, _K1, ode.n, ode.inv_m, ode.g, ode.a_s, ode.a_b, ode.inv_z,
                 ode.f_static, ode.tau, ode.a0_scale, ode.inv_m0)
            for i in range(size):
                ws[iy1, i] = ws[iy, i] + h * (A31 * ws[ik0, i] + A32 * ws[_K1, i])
            _rhs(ws, iy1, _K2, ode.n, ode.inv_m, ode.g, ode.a_s, ode.a_b, ode.inv_z,
                 ode.f_static, ode.tau, ode.a0_scale, ode.inv_m0)
            for i in range(size):
                ws[iy1, i] = ws[iy, i] + h * (A41 * ws[ik0, i] + A42 * ws[_K1, i]
                                              + A43 * ws[_K2, i])
            _rhs(ws, iy1, _K3, ode.n, ode.inv_m, ode.g, ode.a_s, ode.a_b, ode.inv_z,
                 ode.f_static, ode.tau, ode.a0_scale, ode.inv_m0)
            for i in range(size):
                ws[iy1, i] = ws[iy, i] + h * (A51 * ws[ik0, i] + A52 * ws[_K1, i]
                                              + A53 * ws[_K2, i] + A54 * ws[_K3, i])
            _rhs(ws, iy1, _K4, ode.n, ode.inv_m, ode.g, ode.a_s, ode.a_b, ode.inv_z,
                 ode.f_static, ode.tau, ode.a0_scale, ode.inv_m0)
            for i in range(size):
                ws[iy1, i] = ws[iy, i] + h * (A61 * ws[ik0, i] + A62 * ws[_K1, i]
                                              + A63 * ws[_K2, i] + A64 * ws[_K3, i]
                                              + A65 * ws[_K4, i])
            _rhs(ws, iy1, _K5, ode.n, ode.inv_m, ode.g, ode.a_s, ode.a_b, ode.inv_z,
                 ode.f_static, ode.tau, ode.a0_scale, ode.inv_m0)
            for i in range(size):
                ws[iy1, i] = ws[iy, i] + h * (A71 * ws[ik0, i] + A73 * ws[_K2, i]
                                              + A74 * ws[_K3, i] + A75 * ws[_K4, i]
                                              + A76 * ws[_K5, i])
            _rhs(ws, iy1, ik6, ode.n, ode.inv_m, ode.g, ode.a_s, ode.a_b, ode.inv_z,
                 ode.f_static, ode.tau, ode.a0_scale, ode.inv_m0)
            nfev += 6
            err = _error_norm(ws, iy, iy1, ik0, ik6, h, rtol, size)
            if not np.isfinite(err):
                return (RUN_NONFINITE, next_k, ws[iy, iw], ws[iy, iw + 1], ws[iy, iw + 2],
                        accepted, rejected, nfev, deviation)
            # err^EXPO and facold^BETA through exp/log, cheaper than two pow calls.
            log_err = log(err) if err > 0.0 else -745.0
            fac11 = exp(EXPO * log_err)
            if err > 1.0:
                rejected += 1
                last_rejected = True
                h = h / min(1.0 / FAC_MIN, fac11 / SAFETY)
                continue

            # Accepted: dense output of [t, t + h]; its tracked components kept for the peak
            # refinement.
            _dense_outputs(ws, iy, iy1, ik0, ik6, h, size if traces else 0, track_idx)
            hist_t[n_hist] = t
            hist_h[n_hist] = h
            for c in range(_TRACK):
                for p in range(5):
                    hist_c[n_hist, p, c] = ws[_RC + p, track_idx[c]]
            n_hist += 1

            t_new = t_end if last else t + h
            # The energy balance (chain energy + plate work + dissipated) of the new state.
            if iy1 == _Y:
                e_new = chain_energy(u_a, v_a, u0, ws[iy1, iw], m, g, a_s, a_b, m0, a_0)
            else:
                e_new = chain_energy(u_b, v_b, u0, ws[iy1, iw], m, g, a_s, a_b, m0, a_0)
            e_new = e_new + ws[iy1, iw + 1] + ws[iy1, iw + 2]
            if not np.isfinite(e_new):
                return (RUN_NONFINITE, next_k, ws[iy1, iw], ws[iy1, iw + 1], ws[iy1, iw + 2],
                        accepted + 1, rejected, nfev, deviation)
            deviation = max(deviation, abs(e_new - e_start))
            # The samples in (t, t + h], in blocks of at most _BLOCK: the sensor reading from the
            # dense output, the energy balance interpolated between the step ends, the peak tracker.
            # Written here, not in a helper, for the reason of _KERNEL.
            # The first sample past the step: the comparisons decide, started from the estimate
            # t_new / interval (counting up from next_k cost a comparison per sample).
            stop = min(max(int(t_new / interval), next_k), n_samples)
            while stop > next_k and not ((stop - 1) * interval <= t_new or last):
                stop -= 1
            while stop < n_samples and (stop * interval <= t_new or (last and stop ==
                                                                      n_samples - 1)):
                stop += 1
            while next_k < stop:
                cnt = min(stop - next_k, _BLOCK)
                for c in range(cnt):
                    ws[_TH, c] = ((next_k + c) * interval - t) / h
                if last and next_k + cnt == n_samples:
                    ws[_TH, cnt - 1] = 1.0  # the run's last sample is the last step's end
                if traces:
                    _sample_block(ws[_PW:_PW + 5], ws[_TH], cnt, next_k, n, a_s, a_b, tau, sensor,
                                  scratch, samples, u_trace, v_trace, f_trace, w_trace, a_0)
                    for c in range(cnt):
                        ws[_FBOT, c] = scratch[9, c]
                else:
                    _sample_sensor(ws, cnt, n, a_s, a_b, tau, sensor, a_up)
                    for c in range(cnt):
                        samples[next_k + c] = ws[_OUT, c]
                for c in range(cnt):
                    energy[next_k + c] = (1.0 - ws[_TH, c]) * e_prev + ws[_TH, c] * e_new
                for c in range(cnt):
                    kk = next_k + c
                    if not np.isfinite(samples[kk]):
                        return (RUN_NONFINITE, kk + 1, ws[iy1, iw], ws[iy1, iw + 1],
                                ws[iy1, iw + 2], accepted + 1, rejected, nfev, deviation)
                    track_peaks(pk, kk * interval, interval, samples[kk], ws[_FBOT, c])
                next_k += cnt

            accepted += 1
            # PI controller; no growth right after a rejection.
            fac = fac11 * exp(-BETA * log_fac_old)
            fac = max(1.0 / FAC_MAX, min(1.0 / FAC_MIN, fac / SAFETY))
            h_new = h / fac
            if last_rejected:
                h_new = min(h_new, h)
            log_fac_old = max(log_err, log(1e-4))
            last_rejected = False
            iy, iy1 = iy1, iy
            ik0, ik6 = ik6, ik0
            t = t_new
            h = h_new
            e_prev = e_new

    for i in range(np1):
        u[i] = ws[iy, i]
        v[i] = ws[iy, np1 + i]
    if not pk[PK_BOT_F] >= 0.0:
        return (RUN_NONFINITE, n_samples, ws[iy, iw], ws[iy, iw + 1], ws[iy, iw + 2], accepted,
                rejected, nfev, deviation)
    _refine_peaks(rec, interval, t_end, hist_t, hist_h, hist_c, n_hist, n)
    return (RUN_OK, n_samples, ws[iy, iw], ws[iy, iw + 1], ws[iy, iw + 2], accepted, rejected,
            nfev, deviation)
