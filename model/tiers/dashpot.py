"""The tiers of an ODE plate: walls and Zener's dashpot, with their compiled drivers.

``rigid``
    An immovable wall of the sphere material: ``A_b`` is the sphere-on-flat constant with both
    bodies steel, ``w = 0``.
``halfspace``
    The plate material's sphere-on-flat constant ``A_p``; the plate does not move, ``w = 0``.
``infinite``
    Zener's infinite thin plate: a dashpot behind the Hertz spring, ``w' = (F - F_static) / Z``
    with ``Z = 8 sqrt(rho_p t D_p)`` (Zener's model, the paper's Sec. 4.1.1). With gravity on,
    the plate already carries the chain's static weight ``F_static = N m g`` through its
    supports before the impact, so the dashpot answers only to the change of force
    ``F - F_static``. An infinite plate has no static stiffness, so this is the only reading
    under which the chain can start at rest.

The last particle N touches the plate through a Hertz contact ``F = A_b [u_N - w]_+^(3/2)``
(the paper's Sec. 3); a tier decides ``A_b`` and how ``w`` moves. The drivers follow the step of
:mod:`.base`; :func:`dashpot_steps_run` is its reference form.
"""

from __future__ import annotations

import time

import numpy as np
from numba import njit

from ..chain import (
    PK_BOT_F,
    accelerations,
    bottom_acceleration,
    chain_energy,
    contact_forces,
    damped_contact_forces,
    record_into,
    sensor_reading,
    track_peaks,
    verlet_step,
)
from ..contact import hertz_sphere_flat
from ..dopri import integrate_dopri5
from ..laws import dashpot_step, hertz, hertz_energy
from ..leapfrog import integrate_elastic
from ..record import ChainRecord
from ..status import RUN_NONFINITE, RUN_OK
from .base import BottomBoundary, ChainRun, StepPlan, Tier


class Wall(BottomBoundary):
    """A bottom that never moves: ``rigid`` (steel on steel) or ``halfspace`` (steel on plate)."""

    def __init__(self, name: str, reason: str, a_bottom: float) -> None:
        self.name = name
        self.reason = reason
        self.a_bottom = a_bottom

    def integrate(self, record: ChainRecord, plan: StepPlan) -> ChainRun:
        return _run_dashpot(record, plan, inv_z=0.0)


class ZenerDashpot(BottomBoundary):
    """Zener's infinite plate: the contact point moves at ``(F - F_static) / Z``."""

    def __init__(self, reason: str, a_bottom: float, impedance: float) -> None:
        self.name = "infinite"
        self.reason = reason
        self.a_bottom = a_bottom
        self.impedance = impedance

    def max_rate(self, bottom_stiffness: float) -> float:
        return bottom_stiffness / self.impedance

    def integrate(self, record: ChainRecord, plan: StepPlan) -> ChainRun:
        return _run_dashpot(record, plan, inv_z=1.0 / self.impedance)


def _run_dashpot(record: ChainRecord, plan: StepPlan, inv_z: float) -> ChainRun:
    if plan.integrator == "dopri5":
        return _run_dopri5(record, plan, inv_z)
    args = (record, 0.0, float(inv_z), float(plan.dt), int(plan.n_sub), int(plan.n_samples))
    start = time.perf_counter()
    # The driver is chosen here, not in dashpot_run: compiled together, the damped driver's code
    # slows the elastic loop by about 10 % (3.3 against 3.8 ms on the default scene).
    if record.tau > 0.0:
        status, done, w, plate_work, dissipated = dashpot_steps_run(*args)
    else:
        status, done, w, plate_work = integrate_elastic(*args)
        dissipated = 0.0
    wall = time.perf_counter() - start
    return ChainRun(status, done, plate_work, dissipated, record.pk, wall, w_end=w)


def _run_dopri5(record: ChainRecord, plan: StepPlan, inv_z: float) -> ChainRun:
    """The same tiers with the adaptive Dormand-Prince driver (:mod:`~solitonde.model.dopri`)."""
    start = time.perf_counter()
    out = integrate_dopri5(record, 0.0, float(inv_z), float(plan.dt),
                           int(plan.n_samples), float(plan.rtol), int(plan.max_steps))
    wall = time.perf_counter() - start
    status, done, w, plate_work, dissipated, accepted, rejected, nfev, deviation = out
    return ChainRun(status, done, plate_work, dissipated, record.pk, wall, w_end=w, extra={
        "steps_accepted": accepted, "steps_rejected": rejected, "rhs_evaluations": nfev,
        "energy_deviation_step_ends_J": deviation,
    })


@njit(cache=True)
def dashpot_advance(
    w: float, u_n: float, a_b: float, f_static: float, inv_z: float, h: float
) -> float:
    """Advance the dashpot ``w' = (A_b [u_N - w]_+^1.5 - F_static) / Z`` over h with u_N frozen
    (:func:`solitonde.model.laws.dashpot_step` from the current bottom force)."""
    return dashpot_step(w, u_n, hertz(a_b, u_n - w), a_b, f_static, inv_z, h)


@njit(cache=True, nogil=True)
def dashpot_run(
    rec: ChainRecord, w: float, inv_z: float, dt: float, n_sub: int, n_samples: int
) -> tuple[int, int, float, float, float]:
    """Driver for the wall and dashpot tiers (``inv_z = 0``: the plate never moves).

    ``rec`` holds the chain's state, constants and outputs; ``w`` is the plate's initial top
    surface, ``inv_z`` 1 / impedance, and the grid ``n_samples`` samples from t = 0, ``n_sub``
    steps of ``dt`` apart. Returns (status, samples recorded, final w, work done on the plate J,
    dissipated energy J). ``rec.energy[k]`` holds the balance chain energy + plate work +
    dissipated energy at sample k. Without dissipation it runs the fused leapfrog form of the
    same scheme (:func:`solitonde.model.leapfrog.integrate_elastic`); with it,
    :func:`dashpot_steps_run`. It releases the GIL, so that threads run scenes in parallel
    (:mod:`~solitonde.model.batch`).
    """
    if rec.tau > 0.0:
        return dashpot_steps_run(rec, w, inv_z, dt, n_sub, n_samples)
    status, done, w_end, plate_work = integrate_elastic(rec, w, inv_z, dt, n_sub, n_samples)
    return status, done, w_end, plate_work, 0.0


@njit(cache=True)
def initial_forces(
    rec: ChainRecord, w: float, f: np.ndarray, acc: np.ndarray, vp: np.ndarray
) -> float:
    """Contact forces ``f`` and accelerations ``acc`` at t = 0; returns the dissipated power.

    With dissipation the viscous force uses the initial velocities (``vp`` receives a copy).
    """
    u, n, inv_m = rec.u, rec.u.size - 1, 1.0 / rec.m
    contact_forces(u, rec.a_s, rec.a_0, f)
    power = 0.0
    if rec.tau > 0.0:
        for i in range(n + 1):
            vp[i] = rec.v[i]
        power = damped_contact_forces(u, vp, rec.a_s, rec.a_0, rec.tau, f)
    accelerations(f, hertz(rec.a_b, u[n] - w), inv_m, 1.0 / rec.m0, rec.g, acc)
    return power


@njit(cache=True)
def plate_half_step(
    rec: ChainRecord, w: float, e_before: float, inv_z: float, h: float, f: np.ndarray,
    acc: np.ndarray,
) -> tuple[float, float]:
    """Dashpot step of h with the chain frozen: returns (new w, work done on the plate J).

    The work is the drop of the bottom contact's elastic energy (2/5) delta F (``e_before`` at
    the old w), exact while u is frozen; ``acc[N]`` is refreshed for the new bottom force.
    """
    n = rec.u.size - 1
    u_n = rec.u[n]
    w = dashpot_advance(w, u_n, rec.a_b, rec.f_static, inv_z, h)
    f_new = hertz(rec.a_b, u_n - w)
    bottom_acceleration(acc, f, f_new, 1.0 / rec.m, rec.g)
    return w, e_before - 0.4 * (u_n - w) * f_new


@njit(cache=True, nogil=True)
def dashpot_steps_run(
    rec: ChainRecord, w: float, inv_z: float, dt: float, n_sub: int, n_samples: int
) -> tuple[int, int, float, float, float]:
    """Step-by-step driver built from the :mod:`~solitonde.model.chain` kernels (any ``tau``).

    The reference form of the scheme, which plate tiers imitate; arguments and return as
    :func:`dashpot_run`.
    """
    u, v, a_b, sensor, pk = rec.u, rec.v, rec.a_b, rec.sensor, rec.pk
    n = u.size - 1
    inv_m = 1.0 / rec.m
    half = 0.5 * dt
    f = np.empty(n)
    acc = np.empty(n + 1)
    vp = np.empty(n + 1)
    power = initial_forces(rec, w, f, acc, vp)
    plate_work = 0.0
    dissipated = 0.0
    moving = inv_z > 0.0
    step = 0
    for k in range(n_samples):
        record_into(rec, k, f, w)
        rec.energy[k] = (chain_energy(u, v, rec.u0, w, rec.m, rec.g, rec.a_s, a_b, rec.m0,
                                      rec.a_0) + plate_work + dissipated)
        if not np.isfinite(rec.samples[k]) or not np.isfinite(rec.energy[k]):
            return RUN_NONFINITE, k + 1, w, plate_work, dissipated
        if k == n_samples - 1:
            break
        # Strang splitting D(dt/2) V(dt) D(dt/2); the inner half steps of consecutive steps are
        # merged into one D(dt), so the state is synchronous only at samples (where it is read).
        if moving:
            w, work = plate_half_step(rec, w, hertz_energy(a_b, u[n] - w), inv_z, half, f, acc)
            plate_work += work
        for sub in range(n_sub):
            power_before = power
            f_bottom, power = verlet_step(u, v, acc, f, vp, w, rec.a_s, rec.a_0, a_b, inv_m,
                                          1.0 / rec.m0, rec.g, rec.tau, dt)
            dissipated += half * (power_before + power)
            if moving:
                # (2/5) delta F from the step's own bottom force, as the energy before the step
                e_before = 0.4 * (u[n] - w) * f_bottom
                h = half if sub == n_sub - 1 else dt
                w, work = plate_half_step(rec, w, e_before, inv_z, h, f, acc)
                plate_work += work
            step += 1
            track_peaks(pk, step * dt, dt, sensor_reading(f, f_bottom, sensor), f_bottom)
    if not pk[PK_BOT_F] >= 0.0:
        return RUN_NONFINITE, n_samples, w, plate_work, dissipated
    return RUN_OK, n_samples, w, plate_work, dissipated


TIERS = (
    Tier("rigid", lambda scene, reason, cache: Wall(
        "rigid", reason,
        hertz_sphere_flat(scene.chain.diameter, scene.sphere_material, scene.sphere_material)),
        static=True, dopri5=True),
    Tier("halfspace", lambda scene, reason, cache: Wall("halfspace", reason, scene.a_p),
         static=True, dopri5=True),
    Tier("infinite",
         lambda scene, reason, cache: ZenerDashpot(reason, scene.a_p, scene.plate_impedance),
         dopri5=True),
)
"""The ODE tiers, for :mod:`.registry`."""
