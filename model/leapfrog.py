"""Fused compiled driver for the elastic chain on a wall or a Zener dashpot (the fast path).

It integrates exactly the scheme of :func:`solitonde.model.tiers.dashpot.dashpot_steps_run`
(velocity Verlet for the chain inside a Strang splitting with the dashpot, the paper's Secs. 3.1
and 4.1.1) for the common case without dissipation, but arranged for speed:

* the closing half kick of one step and the opening half kick of the next are merged into one full
  kick (leapfrog form), so velocities are synchronous only at samples, where they are read;
* kick and drift share one pass over the particles and the Hertz forces another, both written
  without branches so that the compiler vectorises them (``max(delta, 0)`` is the no-tension
  rule); accelerations are never stored;
* the energy balance at a sample reuses the contact forces (``E = 2/5 delta F``) instead of
  evaluating ``delta^(5/2)`` again.

Because the plate moves between the two halves of a merged kick, the bottom particle's full kick
uses the mean of the bottom force before and after the dashpot sub-step, which is what the two
separate half kicks would give. The result agrees with the unfused driver to rounding.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .chain import PK_BOT_F, record_into, striker_mass_terms, track_peaks
from .laws import dashpot_step, hertz, hertz_energy
from .record import ChainRecord
from .status import RUN_NONFINITE, RUN_OK


@njit(cache=True)
def _hertz_forces(u: np.ndarray, a_s: float, f: np.ndarray) -> None:
    """Branch-free Hertz forces of the N sphere-sphere contacts (vectorises); a striker unlike
    the chain's spheres has its contact 0 redone by the caller."""
    for j in range(f.size):
        f[j] = hertz(a_s, u[j] - u[j + 1])


@njit(cache=True)
def _kick_drift(
    u: np.ndarray, v: np.ndarray, f: np.ndarray, f_bottom: float,
    inv_m: float, inv_m0: float, g: float, c: float, dt: float,
) -> None:
    """v += c a(f, f_bottom), then u += dt v, for every particle (``inv_m0``: the striker's)."""
    n = u.size - 1
    if n == 0:
        return
    v[0] += c * (g - f[0] * inv_m0)
    u[0] += dt * v[0]
    for i in range(1, n):
        v[i] += c * (g + (f[i - 1] - f[i]) * inv_m)
        u[i] += dt * v[i]
    v[n] += c * (g + (f[n - 1] - f_bottom) * inv_m)
    u[n] += dt * v[n]


@njit(cache=True)
def _close(
    u: np.ndarray, v: np.ndarray, u0: np.ndarray, f: np.ndarray, f_bottom: float,
    inv_m: float, inv_m0: float, g: float, c: float, m: float, m0: float,
) -> float:
    """Closing kick ``v += c a(f, f_bottom)`` and, in the same pass, the chain's kinetic +
    sphere-contact + gravity energy at the new velocities, J (the bottom contact's is not in it).
    """
    n = v.size - 1
    v[0] += c * (g - f[0] * inv_m0)
    kin = v[0] * v[0]
    grav = u[0] - u0[0]
    pot = (u[0] - u[1]) * f[0]
    for i in range(1, n):
        v[i] += c * (g + (f[i - 1] - f[i]) * inv_m)
        kin += v[i] * v[i]
        grav += u[i] - u0[i]
        pot += (u[i] - u[i + 1]) * f[i]
    v[n] += c * (g + (f[n - 1] - f_bottom) * inv_m)
    kin += v[n] * v[n]
    grav += u[n] - u0[n]
    return 0.5 * m * kin + 0.4 * pot - m * g * grav + striker_mass_terms(u, v, u0, m, m0, g)


@njit(cache=True)
def _energy(
    u: np.ndarray, v: np.ndarray, u0: np.ndarray, f: np.ndarray, w: float,
    m: float, g: float, a_b: float, m0: float,
) -> float:
    """Kinetic + contact + gravity energy, J, with ``f`` the forces at ``u`` (see chain_energy)."""
    kin = 0.0
    grav = 0.0
    for i in range(u.size):
        kin += v[i] * v[i]
        grav += u[i] - u0[i]
    pot = 0.0
    for j in range(f.size):
        pot += (u[j] - u[j + 1]) * f[j]
    n = u.size - 1
    return (0.5 * m * kin + 0.4 * pot + hertz_energy(a_b, u[n] - w) - m * g * grav
            + striker_mass_terms(u, v, u0, m, m0, g))


@njit(cache=True, nogil=True)
def integrate_elastic(
    rec: ChainRecord, w: float, inv_z: float, dt: float, n_sub: int, n_samples: int
) -> tuple[int, int, float, float]:
    """Elastic chain on a wall (``inv_z = 0``) or a dashpot; arguments as
    :func:`solitonde.model.tiers.dashpot.dashpot_run`.

    Returns (status, samples recorded, final w, work done on the plate J).
    """
    u, v, u0, m, g, a_s, a_b = rec.u, rec.v, rec.u0, rec.m, rec.g, rec.a_s, rec.a_b
    f_static, sensor, samples, energy, pk = (rec.f_static, rec.sensor, rec.samples, rec.energy,
                                             rec.pk)
    n = u.size - 1
    inv_m = 1.0 / m
    m0, a_0 = rec.m0, rec.a_0
    inv_m0 = 1.0 / m0
    half = 0.5 * dt
    f = np.empty(n)
    striker = a_0 != a_s  # a striker of another material: its contact 0 has its own constant
    _hertz_forces(u, a_s, f)
    if striker:
        f[0] = hertz(a_0, u[0] - u[1])
    plate_work = 0.0
    moving = inv_z > 0.0
    step = 0
    traces = rec.u_trace.shape[0] > 0
    f_bottom = hertz(a_b, u[n] - w)
    e_chain = _energy(u, v, u0, f, w, m, g, a_b, m0)
    for k in range(n_samples):
        # Here u, v, w are synchronous; f and f_bottom are the forces at (u, w).
        below = f[sensor] if sensor < n else f_bottom
        samples[k] = 0.5 * (f[sensor - 1] + below)
        if traces:
            record_into(rec, k, f, w)
        energy[k] = e_chain + plate_work
        if not np.isfinite(samples[k]) or not np.isfinite(energy[k]):
            return RUN_NONFINITE, k + 1, w, plate_work
        if k == n_samples - 1:
            break
        if moving:
            # Opening half step of the dashpot; its later half steps merge into full ones.
            e_before = 0.4 * (u[n] - w) * f_bottom
            w = dashpot_step(w, u[n], f_bottom, a_b, f_static, inv_z, half)
            f_bottom = hertz(a_b, u[n] - w)
            plate_work += e_before - 0.4 * (u[n] - w) * f_bottom
        c = half
        f_kick = f_bottom
        f_after = f_bottom
        for sub in range(n_sub):
            _kick_drift(u, v, f, f_kick, inv_m, inv_m0, g, c, dt)
            _hertz_forces(u, a_s, f)
            if striker:
                f[0] = hertz(a_0, u[0] - u[1])
            f_bottom = hertz(a_b, u[n] - w)
            f_after = f_bottom
            if moving:
                e_before = 0.4 * (u[n] - w) * f_bottom
                w = dashpot_step(w, u[n], f_bottom, a_b, f_static, inv_z,
                                 half if sub == n_sub - 1 else dt)
                f_after = hertz(a_b, u[n] - w)
                plate_work += e_before - 0.4 * (u[n] - w) * f_after
            step += 1
            below = f[sensor] if sensor < n else f_bottom
            track_peaks(pk, step * dt, dt, 0.5 * (f[sensor - 1] + below), f_bottom)
            c = dt
            f_kick = 0.5 * (f_bottom + f_after)
        # Closing half kick (with the bottom force before the plate's last half step), fused with
        # the energy sum; then the state is synchronous again.
        e_chain = (_close(u, v, u0, f, f_bottom, inv_m, inv_m0, g, half, m, m0)
                   + 0.4 * (u[n] - w) * f_after)
        f_bottom = f_after
    if not pk[PK_BOT_F] >= 0.0:
        return RUN_NONFINITE, n_samples, w, plate_work
    return RUN_OK, n_samples, w, plate_work
