"""What a run of a scene will take, before it runs: ``plan(scene) -> RunPlan``.

The plate model the scene resolves to, the simulated duration (the scene's, or the theory's
:func:`auto_duration`), the integration step (:func:`choose_time_step`), the sample and step
counts, and the cost in chain particle-steps. :func:`solitonde.model.simulate.simulate` runs from
this plan and the service prices requests with it, so nothing above ``model/`` re-derives a step
or probes a plate's internals. A plate mesh is only built once a floor of its cost fits the
``budget``, so pricing an absurd mesh is itself cheap.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from .errors import SceneError, SimulationError
from .mindlin import SHEAR_FACTOR
from .scene import Scene, SceneConstants
from .tiers import (
    CONVOLVED_PLATE_MODELS,
    DOPRI5_PLATE_MODELS,
    MESHED_PLATE_MODELS,
    STATIC_PLATE_MODELS,
    TIERS,
    BottomBoundary,
    StepPlan,
    make_boundary,
    resolve_plate_model,
)

#: Verlet steps per period of the stiffest chain oscillation (see :func:`choose_time_step`).
STEPS_PER_PERIOD = 1600
#: Largest step, in units of the plate dashpot's relaxation time Z / k_b, at STEPS_PER_PERIOD; it
#: scales with the chain's step when ``steps_per_period`` changes (see :func:`choose_time_step`).
DASHPOT_STEP_FRACTION = 0.0125
#: Upper bound of that fraction at coarse resolution: the explicit midpoint sub-step of the
#: dashpot is stable up to h k_b / Z = 2 (linearised); half a relaxation time keeps a margin.
DASHPOT_STEP_FRACTION_MAX = 0.5
#: Sample counts beyond this are refused outright (steps and costs stay exact floats below it).
MAX_COUNTABLE = 2.0**53
#: Default limits on one run.
MAX_STEPS = 20_000_000
MAX_SAMPLES = 20_000_000


def _peak_force_bound(a: float, e_kin: float, f_static: float) -> float:
    """Largest force a contact can reach: all impact energy in it, on top of its static load."""
    overlap = (2.5 * e_kin / a) ** 0.4 + (f_static / a) ** (2.0 / 3.0)
    return a * overlap**1.5


def choose_time_step(
    scene: Scene, boundary: BottomBoundary, steps_per_period: int = STEPS_PER_PERIOD,
    constants: SceneConstants | None = None,
) -> tuple[float, int]:
    """Integration step and steps per sample (``constants``: the scene's, when the caller has
    them at hand; computed here when None).

    The step is a fixed fraction of the shortest oscillation period the chain can have: at the
    largest force any contact can reach (all the striker's energy in one contact on top of its
    static load) the Hertz contact stiffness is ``k = 1.5 A^(2/3) F^(1/3)``, and Gershgorin's
    bound puts the highest chain frequency below ``omega = 2 sqrt(k_max / m)``. With
    ``dt = 2 pi / (omega steps_per_period)`` velocity Verlet's relative energy error is
    ``C (omega dt)^2`` with C about 0.02-0.03 measured on the default scene (rigid, half-space and
    infinite plate, gravity on and off), so the default 1600 steps/period, ``(omega dt)^2 =
    1.5e-5``, is the step an energy-drift target of 1e-6 asks for with a margin of two to three
    (measured drift 3e-7 to 5e-7; tests/model/test_chain_physics.py); the error falls as dt^2. A
    plate with dynamics of its own (the dashpot) also needs ``dt <= 0.0125 Z / k_b``: the Strang
    splitting error grows with the dashpot rate ``k_b / Z`` and this keeps the drift below 1e-6
    up to D/t = 12. Both limits are resolutions of one second-order scheme, so one knob sets them:
    ``steps_per_period`` below the default loosens the dashpot limit in proportion (80 steps per
    relaxation time at 1600 steps/period, 1.25 at 25, never coarser than half a relaxation time),
    which is how a cheaper, coarser run is asked for (e.g. the peaks within 0.1 %, 25
    steps/period on the default scene; tests/model/bench_chain.py). The step is then shrunk so that
    a whole number ``n_sub`` of steps fits in one sample interval: samples fall on steps.
    """
    c = constants if constants is not None else scene.constants()
    m, g, a_s = c.sphere_mass, c.gravity, c.a_s
    n = scene.chain.n_particles
    e_kin = 0.5 * c.striker_mass * c.impact_velocity**2
    f_s = _peak_force_bound(a_s, e_kin, max(n - 1, 0) * m * g)
    f_b = _peak_force_bound(boundary.a_bottom, e_kin, n * m * g)
    k_s = 1.5 * a_s ** (2.0 / 3.0) * f_s ** (1.0 / 3.0)
    k_b = 1.5 * boundary.a_bottom ** (2.0 / 3.0) * f_b ** (1.0 / 3.0)
    omega = 2.0 * math.sqrt(max(k_s, k_b) / m)
    if c.striker_differs:  # its own contact and mass may be the stiffest pair
        f_0 = _peak_force_bound(c.a_0, e_kin, 0.0)
        k_0 = 1.5 * c.a_0 ** (2.0 / 3.0) * f_0 ** (1.0 / 3.0)
        omega = 2.0 * math.sqrt(max(k_s, k_b, k_0) / min(m, c.striker_mass))
    dt_max = 2.0 * math.pi / (omega * steps_per_period)
    rate = boundary.max_rate(k_b)
    if rate > 0.0:
        fraction = min(DASHPOT_STEP_FRACTION * STEPS_PER_PERIOD / steps_per_period,
                       DASHPOT_STEP_FRACTION_MAX)
        dt_max = min(dt_max, fraction / rate)
    interval = 1.0 / scene.output.sample_rate
    n_sub = max(1, math.ceil(interval / dt_max * (1.0 - 1e-12)))
    return interval / n_sub, n_sub


def auto_duration(scene: Scene, plate_model: str | None = None) -> float:
    """Simulated time for ``output.duration = 'auto'``: until the reflection has passed the sensor.

    From the theory of :mod:`solitonde.model.zener` for the plate model the scene runs with
    (``plate_model``, resolved from the scene when None): Zener's infinite plate for the plates
    that move (``infinite``, and the meshed plates, whose supports only shorten the TOF), and
    lambda = 0 with the wall's own Hertz constant for the static tiers (``rigid``,
    ``halfspace``): their reflection does not depend on the plate's thickness, and the infinite
    plate's TOF, which grows without bound as the plate thins, would stretch or refuse their runs.
    The incident pulse reaches the
    sensor after about (sensor_index + 1) D / V_s; the reflected one follows a TOF later. The run
    goes on for another quarter TOF plus two pulse widths (5 D / V_s each) so that the reflected
    pulse and the secondary pulses right behind it are recorded whole. This is ``predict``'s TOF
    (Eq. 15) assembled from zener's own functions with its tabulated restitution, which costs
    microseconds instead of an ODE solve per run.
    """
    name = plate_model if plate_model is not None else resolve_plate_model(scene)[0]
    c = scene.constants()
    if name in STATIC_PLATE_MODELS:
        a_bottom, z = make_boundary(scene, (name, "")).a_bottom, math.inf
    else:
        a_bottom, z = c.a_p, c.plate_impedance
    return _auto_duration(scene, c, a_bottom, z)


def _auto_duration(scene: Scene, c: SceneConstants, a_p: float, z: float) -> float:
    """:func:`auto_duration` with the scene's constants ``c`` at hand: ``a_p`` the bottom
    contact's Hertz constant, ``z`` the plate impedance (inf: a wall, lambda = 0)."""
    from . import zener

    d, m, a_s = scene.chain.diameter, c.sphere_mass, c.a_s
    v_in = zener.incident_velocity_from(
        c.impact_velocity, (c.striker_mass, m) if c.striker_differs else None)
    e, tau_c = zener.restitution_and_contact_time_one(zener.inelasticity_from(m, a_p, v_in, z))
    # e -> 0 sends Eq. 15's reflected trip to infinity; below e = 0.01 the reflection carries
    # ARR < 0.4 % and the record ends when a wave at 1 % of v_in would be back.
    e_floor = max(e, 0.01)
    speed = zener.solitary_wave_speed(d, a_s, m, v_in)
    trip = zener.travel_diameters(scene) * d
    tof = (trip / speed + trip / zener.solitary_wave_speed(d, a_s, m, e_floor * v_in)
           + tau_c * zener.time_scale(m, a_p, v_in))
    incident = (scene.chain.sensor_index + 1) * d / speed
    return incident + 1.25 * tof + 2.0 * (5.0 * d / speed)


def check_solver(scene: Scene) -> tuple[str, str] | None:
    """Refuse a solver that cannot run the scene's plate model, before any mesh is built.

    Returns the resolved (plate model, reason) for ``dopri5`` (to be reused), None for verlet.
    """
    if scene.solver.integrator != "dopri5":
        return None
    name, reason = resolve_plate_model(scene)
    if name not in DOPRI5_PLATE_MODELS:
        raise SceneError(
            "solver.integrator",
            f"dopri5 cannot run plate model {name!r} ({reason})",
            allowed=f"verlet with every plate model; dopri5 with "
                    f"{', '.join(DOPRI5_PLATE_MODELS)}",
        )
    return name, reason


CONVOLUTION_WEIGHT = 0.25
"""The ``greens`` plate convolves the whole force history at every plate step (sum over the
steps s of s multiply-adds: plate_steps^2 / 2 in all), which dominates long runs. One
multiply-add costs about 0.25 chain particle-steps: measured on one core, 8e9/s while the history
fits the cache (1e5 steps) and 2e9/s beyond it (4e5 steps, 39 s), against ~3.5e8 particle-steps/s
(0.175 at the slower rate, rounded up)."""


@dataclass(frozen=True)
class RunPlan:
    """A run of a scene before it runs (SI units).

    ``dt_s`` and ``n_sub`` are the grid the chain is sampled on (for ``dopri5`` the sample
    interval and 1: its steps adapt). ``chain_steps``, ``plate_steps`` and ``cost`` count Verlet
    steps, exact for ``verlet`` and an upper bound for ``dopri5``; ``estimate`` says which, or that
    the count is a floor because the plate mesh was not built (its floor exceeded the budget).
    """

    plate_model: str
    plate_model_reason: str
    integrator: str
    duration_s: float
    n_samples: int
    dt_s: float
    n_sub: int
    chain_steps: int
    plate_steps: int
    particles: int
    plate_dofs: int
    cost: float
    estimate: str

    @property
    def interval_s(self) -> float:
        """The sample interval, s."""
        return self.dt_s * self.n_sub

    def cost_dict(self) -> dict[str, Any]:
        """The price as the service reports it (``POST /v1/simulate``'s ``cost``)."""
        return {"plate_model": self.plate_model, "duration_s": self.duration_s,
                "n_samples": self.n_samples, "steps": max(self.chain_steps, self.plate_steps),
                "dof": self.particles + self.plate_dofs, "cost": self.cost,
                "estimate": self.estimate}


def plan(
    scene: Scene,
    boundary: BottomBoundary | None = None,
    *,
    budget: float = math.inf,
    steps_per_period: int = STEPS_PER_PERIOD,
    constants: SceneConstants | None = None,
) -> RunPlan:
    """The plan of a run of ``scene`` on ``boundary`` (built here when None and its cost floor
    fits ``budget``); ``constants``: the scene's (:meth:`Scene.constants`), when the caller has
    them at hand.

    Raises SceneError for a solver that cannot run the scene's plate model (before any mesh).
    ``cost = chain steps x (particles + 1) + dof weight x plate steps x plate dofs`` (the
    tier's ``dof_weight``), plus ``CONVOLUTION_WEIGHT x plate_steps^2 / 2`` for the convolved
    tiers; about 3.5e8-4.6e8 per CPU second.
    """
    if boundary is not None:  # built by the caller, after its own check_solver
        name, reason = boundary.name, boundary.reason
    else:
        name, reason = check_solver(scene) or resolve_plate_model(scene)
    c = constants if constants is not None else scene.constants()
    if scene.output.duration != "auto":
        duration = float(scene.output.duration)
    elif boundary is not None:
        static = boundary.name in STATIC_PLATE_MODELS
        duration = _auto_duration(scene, c, boundary.a_bottom,
                                  math.inf if static else c.plate_impedance)
    else:
        duration = auto_duration(scene, name)
    interval = 1.0 / scene.output.sample_rate
    n_samples = _sample_count(duration, interval)
    particles = scene.chain.n_particles + 1
    integrator = scene.solver.integrator
    if boundary is None and name in MESHED_PLATE_MODELS:
        steps = max(n_samples - 1, _plate_steps_floor(scene, duration, name))
        dofs = _plate_dofs(scene, name)
        floor = float(steps) * (particles + TIERS[name].dof_weight * dofs)
        if name in CONVOLVED_PLATE_MODELS:
            floor += CONVOLUTION_WEIGHT * 0.5 * float(steps) ** 2
        if floor > budget:
            return RunPlan(name, reason, integrator, duration, n_samples, math.nan, 0, steps,
                           0, particles, dofs, floor, "floor (before the plate mesh is built)")
    if boundary is None:
        boundary = make_boundary(scene, (name, reason))
    dt, n_sub = choose_time_step(scene, boundary, steps_per_period, c)
    if integrator == "dopri5":
        # The step adapts to rtol; samples come from the dense output, not from steps.
        run_dt, run_sub = interval, 1
    else:
        run_dt, run_sub = dt, n_sub
    n_samples = _sample_count(duration, run_dt * run_sub)
    chain_steps, plate_steps, plate_dofs = (n_samples - 1) * n_sub, 0, 0
    plate = getattr(boundary, "plate", None)
    if plate is not None and hasattr(boundary, "steps"):
        _, r, per_sample = boundary.steps(StepPlan(dt, n_sub, n_samples))
        plate_steps = per_sample * (n_samples - 1)
        chain_steps = plate_steps * r
        plate_dofs = int(plate.n_dofs)
    cost = (float(chain_steps) * particles
            + TIERS[name].dof_weight * float(plate_steps) * plate_dofs)
    if name in CONVOLVED_PLATE_MODELS:
        cost += CONVOLUTION_WEIGHT * 0.5 * float(plate_steps) ** 2
    estimate = ("upper bound (verlet step counts)" if integrator == "dopri5"
                else "exact step counts")
    return RunPlan(name, reason, integrator, duration, n_samples, run_dt, run_sub, chain_steps,
                   plate_steps, particles, plate_dofs, cost, estimate)


def _sample_count(duration: float, interval: float) -> int:
    """Samples from t = 0 through the end of the interval that holds ``duration``."""
    intervals = duration / interval * (1.0 - 1e-12)
    if not intervals <= MAX_COUNTABLE:  # a huge duration: refuse before counts overflow floats
        raise SimulationError(f"step_budget_exceeded: output.duration of {duration:.4g} s needs "
                              f"{intervals:.3g} samples of {interval:.3g} s (at most "
                              f"{MAX_COUNTABLE:.3g} can even be counted); shorten it")
    return math.ceil(intervals) + 1


def _plate_steps_floor(scene: Scene, duration: float, name: str) -> int:
    """Fewest explicit plate steps ``duration`` can take.

    3-D plate: the stable step of a spectral-element mesh is below the time a longitudinal wave
    takes to cross its thinnest element (2 h / c_L is the 1-D linear element's own limit; higher
    orders and more dimensions only shorten it), and through the thickness no element is thicker
    than t / elements_z. Mindlin plate: a uniform rotation of the free nodes has the Rayleigh
    quotient of the thickness-shear mode, omega^2 = 12 kappa G / (rho t^2), so the step is below
    2 / omega whatever the mesh.
    """
    sem = getattr(scene, "sem", None)
    if sem is None:
        return 0
    t = scene.plate.thickness
    mat = scene.plate_material
    if name.startswith("mindlin"):
        omega = math.sqrt(12.0 * SHEAR_FACTOR * mat.shear_modulus / mat.density) / t
        return math.ceil(duration * omega / 2.0)
    h = t / sem.elements[2]
    return math.ceil(duration * mat.longitudinal_velocity / (2.0 * h))


def _plate_dofs(scene: Scene, name: str) -> int:
    """Dofs of the nominal mesh (before local refinement): three per node, one layer of nodes
    for the Mindlin plate."""
    sem = getattr(scene, "sem", None)
    if sem is None:
        return 0
    nodes = 1
    counts = zip(sem.elements, sem.order, strict=True)
    for axis, (n_el, p) in enumerate(counts):
        if axis < 2 or not name.startswith("mindlin"):
            nodes *= n_el * p + 1
    return 3 * nodes
