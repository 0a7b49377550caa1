"""The chain's bottom boundary: one interface, several plate models ("tiers").

The last particle N touches the plate through a Hertz contact ``F = A_b [u_N - w]_+^(3/2)``
(the paper's Sec. 3). A tier decides two things: the Hertz constant ``A_b`` and how the plate's
top surface ``w`` under the chain moves. Tiers here:

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

The interface (what a new tier such as ``sem`` or ``greens`` implements)
------------------------------------------------------------------------
Subclass :class:`BottomBoundary`, give it ``name``, ``reason`` and ``a_bottom``, implement
:meth:`BottomBoundary.integrate` (and :meth:`BottomBoundary.max_rate` if the plate has a time
scale of its own), and add a factory with :func:`register_tier`. ``integrate`` receives a
:class:`ChainSetup` (initial state, constants, preallocated output arrays) and a :class:`StepPlan`
(dt, steps per sample, samples) and returns a :class:`ChainRun`. Its compiled driver loop calls
the kernels of :mod:`solitonde.model.chain` per step, as :func:`dashpot_steps_run` does:

    1. advance the plate by dt/2 with the chain frozen, book the work ``int F dw`` done on it,
       refresh the bottom force and ``acc[N]`` (:func:`~solitonde.model.chain.bottom_acceleration`);
    2. :func:`~solitonde.model.chain.verlet_step` with the plate frozen at w;
    3. advance the plate by the second dt/2 (merged with the next step's first half, except
       before a sample, where chain and plate must be at the same time);
    4. :func:`~solitonde.model.chain.track_peaks` each step and
       :func:`~solitonde.model.chain.record_sample` plus the energy balance every ``n_sub`` steps.

This Strang splitting keeps the chain update symplectic and the whole step second order; because
the plate moves while the chain is frozen, the work done on the plate in a sub-step is exactly the
drop of the bottom contact's elastic energy, so the energy balance stays exact up to the Verlet
error. A plate that must be stepped more finely (spectral elements) sub-cycles inside step 1 and 3.

Plate-model resolution (``auto``) lives in one place: :func:`resolve_plate_model`.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numba import njit

from .chain import (
    PK_BOT_F,
    accelerations,
    bottom_acceleration,
    chain_energy,
    contact_forces,
    damped_contact_forces,
    new_peak_tracker,
    record_into,
    sensor_reading,
    track_peaks,
    verlet_step,
)
from .contact import hertz_sphere_flat
from .dopri import integrate_dopri5
from .errors import SceneError
from .laws import dashpot_step, hertz, hertz_energy
from .leapfrog import integrate_elastic
from .record import ChainRecord, chain_record
from .scene import Scene
from .status import RUN_NONFINITE, RUN_OK

if TYPE_CHECKING:
    from .greens import GreensCache

#: Plate models that ``solver.integrator = "dopri5"`` can run (the ODE tiers of this module).
DOPRI5_PLATE_MODELS = ("rigid", "halfspace", "infinite")
#: Plate models on a mesh (:mod:`solitonde.model.sem_tier`): 3-D spectral elements or Mindlin,
#: stepped with the chain or convolved as a cached Green's function.
MESHED_PLATE_MODELS = ("sem", "greens", "mindlin", "mindlin_greens")
#: The meshed models that convolve a cached contact response.
CONVOLVED_PLATE_MODELS = ("greens", "mindlin_greens")


@dataclass
class ChainSetup:
    """Everything a driver needs about the chain; arrays are modified in place by the run.

    Attributes
    ----------
    u, v: displacements (down, m) and velocities (m/s) of particles 0..N (0 = striker).
    w: initial top-surface deflection of the plate under the chain, m.
    m: particle mass, kg. g: gravity, m/s^2 (0 when gravity is off).
    a_s: sphere-sphere Hertz constant, N/m^1.5. a_b: bottom contact constant, N/m^1.5.
    f_static: static force the bottom contact carries at the start, N (N m g, or 0).
    tau: Kuwabara-Kono dissipative time, s (0: elastic).
    sensor: sensor particle, 1..N.
    samples, energy: outputs per sample (sensor force N, energy balance J).
    u_trace, v_trace, f_trace, w_trace: per-sample fields, zero rows when traces are off.
    m0, a_0: the striker's mass and its contact constant with particle 1 (None: a chain sphere).
    """

    u: np.ndarray
    v: np.ndarray
    w: float
    m: float
    g: float
    a_s: float
    a_b: float
    f_static: float
    tau: float
    sensor: int
    samples: np.ndarray
    energy: np.ndarray
    u_trace: np.ndarray
    v_trace: np.ndarray
    f_trace: np.ndarray
    w_trace: np.ndarray
    m0: float | None = None
    a_0: float | None = None


@dataclass(frozen=True)
class StepPlan:
    """Time grid: ``n_sub`` steps of ``dt`` between samples, ``n_samples`` samples from t = 0.

    ``integrator`` "dopri5" (plate models in ``DOPRI5_PLATE_MODELS``) integrates
    adaptively to ``rtol`` instead (:mod:`~solitonde.model.dopri`; ``dt`` is then the sample
    interval, ``n_sub`` 1) within ``max_steps`` attempted steps.
    """

    dt: float
    n_sub: int
    n_samples: int
    integrator: str = "verlet"
    rtol: float = 1e-8  # SolverSpec.rtol's default
    max_steps: int = 20_000_000

    @property
    def steps(self) -> int:
        return self.n_sub * (self.n_samples - 1)


@dataclass
class ChainRun:
    """What a driver hands back (the arrays of the setup hold the sampled outputs)."""

    status: int
    samples_done: int
    plate_work: float
    dissipated: float
    peaks: np.ndarray
    wall_s: float
    extra: dict[str, Any] = field(default_factory=dict)


class BottomBoundary(ABC):
    """A plate model seen from the chain: a Hertz constant and a way to move the contact point."""

    name: str
    reason: str
    a_bottom: float

    def max_rate(self, bottom_stiffness: float) -> float:
        """Fastest rate (1/s) of the boundary's own dynamics at the given contact stiffness (N/m).

        The time step must resolve it; a static wall has none (0).
        """
        return 0.0

    @abstractmethod
    def integrate(self, setup: ChainSetup, plan: StepPlan) -> ChainRun:
        """Advance chain and plate over ``plan``, filling the setup's output arrays."""


class Wall(BottomBoundary):
    """A bottom that never moves: ``rigid`` (steel on steel) or ``halfspace`` (steel on plate)."""

    def __init__(self, name: str, reason: str, a_bottom: float) -> None:
        self.name = name
        self.reason = reason
        self.a_bottom = a_bottom

    def integrate(self, setup: ChainSetup, plan: StepPlan) -> ChainRun:
        return _run_dashpot(setup, plan, inv_z=0.0)


class ZenerDashpot(BottomBoundary):
    """Zener's infinite plate: the contact point moves at ``(F - F_static) / Z``."""

    def __init__(self, reason: str, a_bottom: float, impedance: float) -> None:
        self.name = "infinite"
        self.reason = reason
        self.a_bottom = a_bottom
        self.impedance = impedance

    def max_rate(self, bottom_stiffness: float) -> float:
        return bottom_stiffness / self.impedance

    def integrate(self, setup: ChainSetup, plan: StepPlan) -> ChainRun:
        return _run_dashpot(setup, plan, inv_z=1.0 / self.impedance)


def setup_record(setup: ChainSetup, peaks: np.ndarray) -> ChainRecord:
    """The compiled drivers' view of a setup: its arrays (shared) and constants, u0 a copy of u."""
    return chain_record(
        setup.u, setup.v, setup.u.copy(), setup.m, setup.g, setup.a_s, setup.a_b, setup.f_static,
        setup.tau, setup.sensor, setup.samples, setup.energy, setup.u_trace, setup.v_trace,
        setup.f_trace, setup.w_trace, peaks, setup.m0, setup.a_0,
    )


def _run_dashpot(setup: ChainSetup, plan: StepPlan, inv_z: float) -> ChainRun:
    if plan.integrator == "dopri5":
        return _run_dopri5(setup, plan, inv_z)
    peaks = new_peak_tracker()
    record = setup_record(setup, peaks)
    args = (record, float(setup.w), float(inv_z), float(plan.dt), int(plan.n_sub),
            int(plan.n_samples))
    start = time.perf_counter()
    # The driver is chosen here, not in dashpot_run: compiled together, the damped driver's code
    # slows the elastic loop by about 10 % (3.3 against 3.8 ms on the default scene).
    if setup.tau > 0.0:
        status, done, w, plate_work, dissipated = dashpot_steps_run(*args)
    else:
        status, done, w, plate_work = integrate_elastic(*args)
        dissipated = 0.0
    wall = time.perf_counter() - start
    setup.w = w
    return ChainRun(status, done, plate_work, dissipated, peaks, wall)


def _run_dopri5(setup: ChainSetup, plan: StepPlan, inv_z: float) -> ChainRun:
    """The same tiers with the adaptive Dormand-Prince driver (:mod:`~solitonde.model.dopri`)."""
    peaks = new_peak_tracker()
    record = setup_record(setup, peaks)
    start = time.perf_counter()
    out = integrate_dopri5(record, float(setup.w), float(inv_z), float(plan.dt),
                           int(plan.n_samples), float(plan.rtol), int(plan.max_steps))
    wall = time.perf_counter() - start
    status, done, w, plate_work, dissipated, accepted, rejected, nfev, deviation = out
    setup.w = w
    return ChainRun(status, done, plate_work, dissipated, peaks, wall, extra={
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


def _legacy(driver, u, v, w, u0, m, g, a_s, a_b, inv_z, f_static, tau, sensor, dt, n_sub,
            n_samples, samples, energy, u_trace, v_trace, f_trace, w_trace, pk):
    record = chain_record(u, v, u0, m, g, a_s, a_b, f_static, tau, sensor, samples, energy,
                          u_trace, v_trace, f_trace, w_trace, pk)
    return driver(record, float(w), float(inv_z), float(dt), int(n_sub), int(n_samples))


def integrate_dashpot(*args) -> tuple[int, int, float, float, float]:
    """:func:`dashpot_run` in the former positional form ``(u, v, w, u0, m, g, a_s, a_b, inv_z,
    f_static, tau, sensor, dt, n_sub, n_samples, samples, energy, u_trace, v_trace, f_trace,
    w_trace, pk)`` (kept for callers and tests written against it)."""
    return _legacy(dashpot_run, *args)


def integrate_dashpot_steps(*args) -> tuple[int, int, float, float, float]:
    """:func:`dashpot_steps_run` in the former positional form of :func:`integrate_dashpot`."""
    return _legacy(dashpot_steps_run, *args)


# Tier registry and plate-model resolution --------------------------------------------------

TierFactory = Callable[[Scene, str, "GreensCache | None"], BottomBoundary]
TIERS: dict[str, TierFactory] = {}


def register_tier(name: str, factory: TierFactory) -> None:
    """Make a plate model available: ``factory(scene, reason, greens_cache)`` builds its
    boundary (``greens_cache``: the plate-response cache, None for the process's; see
    :mod:`solitonde.model.greens`)."""
    TIERS[name] = factory


register_tier(
    "rigid",
    lambda scene, reason, cache: Wall(
        "rigid", reason,
        hertz_sphere_flat(scene.chain.diameter, scene.sphere_material, scene.sphere_material),
    ),
)
register_tier("halfspace", lambda scene, reason, cache: Wall("halfspace", reason, scene.a_p))
register_tier(
    "infinite",
    lambda scene, reason, cache: ZenerDashpot(reason, scene.a_p, scene.plate_impedance),
)


#: The smallest sphere-diameter-to-thickness ratio at which the Mindlin plate was measured within
#: the table budget (1 % TOF, 5 % ARR) of the 3-D plate on the same mesh (``solitonde bench
#: plates``: D 4.76-19.05 mm, t 1.5-9.53 mm, so D/t 0.5-12.7, L 0-457 mm, aluminium, steel and
#: titanium). Below it (a plate thick against the sphere) ``auto`` keeps the 3-D plate: not known
#: to fail there, but not measured. There is no upper end: a larger D/t is a plate thinner
#: against the flexural waves the contact drives (k t ~ sqrt(f t), and f falls as D grows), where
#: a plate theory only gets better.
MINDLIN_MIN_D_OVER_T = 0.5


def resolve_plate_model(scene: Scene) -> tuple[str, str]:
    """The plate model a scene runs with and why (the one place where ``auto`` is decided).

    ``auto``: the infinite plate (Zener dashpot) when the chain is farther from the nearest plate
    edge than ``sem.auto_margin`` times the critical distance L_c (Eq. 18, k = 0.57), since no
    guided wave then returns during contact; otherwise a finite plate's Green's function, of the
    Mindlin plate (``mindlin_greens``) or of the 3-D plate (``greens``), as ``sem.plate_theory``
    says (its ``auto``: Mindlin from :data:`MINDLIN_MIN_D_OVER_T` up).
    """
    requested = scene.effects.plate_model
    if requested != "auto":
        return requested, f"requested by effects.plate_model={requested}"
    from .zener import critical_distance

    l_c = critical_distance(scene, k=0.57)
    limit = scene.sem.auto_margin * l_c
    edge = nearest_edge_distance(scene)
    if edge > limit:
        return "infinite", (
            f"auto: the nearest plate edge is {edge * 1e3:.1f} mm away, beyond "
            f"{scene.sem.auto_margin:g} x L_c = {limit * 1e3:.1f} mm (Eq. 18, k = 0.57): "
            "no reflection returns during contact, so the infinite plate (Zener dashpot) applies"
        )
    near = (f"auto: the nearest plate edge is {edge * 1e3:.1f} mm away, within "
            f"{scene.sem.auto_margin:g} x L_c = {limit * 1e3:.1f} mm (Eq. 18, k = 0.57): guided "
            "waves return during contact, so a finite plate's Green's function is used")
    theory = scene.sem.plate_theory
    if theory != "auto":
        name = "mindlin_greens" if theory == "mindlin" else "greens"
        return name, f"{near}; {name} as sem.plate_theory={theory} asks"
    ratio = scene.chain.diameter / scene.plate.thickness
    if ratio >= MINDLIN_MIN_D_OVER_T * (1.0 - 1e-9):
        return "mindlin_greens", (
            f"{near}; the Mindlin plate (mindlin_greens): D/t = {ratio:.2f} is at least "
            f"{MINDLIN_MIN_D_OVER_T:g}, where it was measured within 1 % TOF and 5 % ARR of the "
            "3-D plate")
    return "greens", (
        f"{near}; the 3-D plate (greens): D/t = {ratio:.2f} is below {MINDLIN_MIN_D_OVER_T:g}, "
        "the smallest at which the Mindlin plate was measured against it")


def nearest_edge_distance(scene: Scene) -> float:
    """Distance from the chain (x = L on the centre line y = Ly/2) to the nearest plate edge, m.

    Every edge reflects, clamped or free, so all four count whatever ``plate.supports`` says.
    """
    lx, ly = scene.plate.size
    x = scene.plate.distance_to_support
    return float(min(x, lx - x, ly / 2.0))


def make_boundary(scene: Scene, resolved: tuple[str, str] | None = None,
                  greens_cache: GreensCache | None = None) -> BottomBoundary:
    """Build the bottom boundary of a scene, resolving ``auto`` (unless ``resolved`` already
    holds :func:`resolve_plate_model`'s answer); ``greens_cache`` serves the ``greens`` tier."""
    name, reason = resolved if resolved is not None else resolve_plate_model(scene)
    factory = TIERS.get(name)
    if factory is None:
        raise SceneError(
            "effects.plate_model",
            f"plate model {name!r} is not available in this build",
            allowed=", ".join([*sorted(TIERS), "auto"]),
        )
    return factory(scene, reason, greens_cache)


# The spectral-element tiers (sem, greens) build on this module and register themselves.
from . import sem_tier as _sem_tier  # noqa: E402, F401
