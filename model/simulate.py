"""Run a scene through the discrete element chain: ``simulate(scene) -> SimulationResult``.

The chain starts in static equilibrium (gravity on: the contact below particle k carries k m g,
the plate contact N m g) with the striker just touching particle 1 and moving at v_imp, so nothing
moves before the impact. The bottom boundary comes from :mod:`solitonde.model.boundary`; the time
step from :func:`choose_time_step`; the duration from the Zener/Nesterenko theory
(:func:`auto_duration`) unless the scene gives one.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numba import njit

from .boundary import (
    DOPRI5_PLATE_MODELS,
    RUN_OK,
    BottomBoundary,
    ChainRun,
    ChainSetup,
    StepPlan,
    make_boundary,
    resolve_plate_model,
)
from .chain import PK_BOT_F, PK_BOT_T, PK_INC_F, PK_INC_T, PK_REF_F, PK_REF_T
from .dopri import RUN_STEP_BUDGET, RUN_STEP_TOO_SMALL
from .errors import SceneError, SimulationError
from .scene import STANDARD_GRAVITY, Scene

#: Verlet steps per period of the stiffest chain oscillation (see :func:`choose_time_step`).
STEPS_PER_PERIOD = 1600
#: Largest step, in units of the plate dashpot's relaxation time Z / k_b, at STEPS_PER_PERIOD; it
#: scales with the chain's step when ``steps_per_period`` changes (see :func:`choose_time_step`).
DASHPOT_STEP_FRACTION = 0.0125
#: Upper bound of that fraction at coarse resolution: the explicit midpoint sub-step of the
#: dashpot is stable up to h k_b / Z = 2 (linearised); half a relaxation time keeps a margin.
DASHPOT_STEP_FRACTION_MAX = 0.5
#: Plate models whose plate never moves: their auto duration uses lambda = 0.
STATIC_PLATE_MODELS = ("rigid", "halfspace")
#: Default limits on one run.
MAX_STEPS = 20_000_000
MAX_SAMPLES = 20_000_000


@dataclass
class SimulationResult:
    """One simulated shot.

    Attributes
    ----------
    scene: the scene that was run.
    plate_model, plate_model_reason: the resolved plate model and why it was chosen.
    t0, dt: time of the first sample (0 = impact) and the sample interval, s.
    samples: sensor force per sample, N (float64).
    diagnostics: energy_drift (max over the samples of |balance - start|, relative to the larger
        of the striker's kinetic energy and the energy that left the chain; with dopri5 the max
        over its step ends, between which the sampled ``energy`` is interpolated),
        energy_error_final, steps, dt_s (integration step), wall_s, status and the energy
        components at the end (J).
    truth: the model's own peaks at integration-step resolution: incident/reflected time (s) and
        peak force (N, raw sensor reading), tof_s, arr (of the rises above the static reading),
        static_sensor_N, bottom_peak_N and bottom_peak_time_s.
    traces: None, or per-sample ``u_m``, ``v_m_s`` ((n_samples, N + 1), particle 0 the striker),
        ``contact_force_N`` ((n_samples, N + 1): contact j between particles j and j + 1, the last
        column the plate contact) and ``plate_deflection_m`` (n_samples).
    """

    scene: Scene
    plate_model: str
    plate_model_reason: str
    t0: float
    dt: float
    samples: np.ndarray
    diagnostics: dict[str, Any]
    truth: dict[str, float]
    traces: dict[str, np.ndarray] | None = None
    energy: np.ndarray = field(default_factory=lambda: np.empty(0))

    @property
    def time(self) -> np.ndarray:
        """Sample times, s."""
        return self.t0 + self.dt * np.arange(self.samples.size)


@njit(cache=True)
def initial_state(
    n: int, m: float, g: float, a_s: float, a_b: float, v_imp: float
) -> tuple[np.ndarray, np.ndarray]:
    """Positions and velocities of striker + N particles at the instant of impact (w = 0).

    Static equilibrium: contact j (below particle j, j = 1..N-1) carries j m g, the plate N m g;
    the striker (particle 0) just touches particle 1. ``u[N]`` is the plate overlap and
    ``u[j] = u[j + 1] + delta_j`` going up.
    """
    u = np.empty(n + 1)
    u[n] = (n * m * g / a_b) ** (2.0 / 3.0)
    for j in range(n - 1, -1, -1):
        u[j] = u[j + 1] + (j * m * g / a_s) ** (2.0 / 3.0)
    v = np.zeros(n + 1)
    v[0] = v_imp
    return u, v


def _peak_force_bound(a: float, e_kin: float, f_static: float) -> float:
    """Largest force a contact can reach: all impact energy in it, on top of its static load."""
    overlap = (2.5 * e_kin / a) ** 0.4 + (f_static / a) ** (2.0 / 3.0)
    return a * overlap**1.5


def choose_time_step(
    scene: Scene, boundary: BottomBoundary, steps_per_period: int = STEPS_PER_PERIOD
) -> tuple[float, int]:
    """Integration step and steps per sample.

    The step is a fixed fraction of the shortest oscillation period the chain can have: at the
    largest force any contact can reach (all the striker's energy in one contact on top of its
    static load) the Hertz contact stiffness is ``k = 1.5 A^(2/3) F^(1/3)``, and Gershgorin's
    bound puts the highest chain frequency below ``omega = 2 sqrt(k_max / m)``. With
    ``dt = 2 pi / (omega steps_per_period)`` velocity Verlet's relative energy error is
    ``C (omega dt)^2`` with C about 0.02-0.03 measured on the default scene (rigid, half-space and
    infinite plate, gravity on and off), so the default 1600 steps/period, ``(omega dt)^2 =
    1.5e-5``, is the step an energy-drift target of 1e-6 asks for with a margin of two to three
    (measured drift 3e-7 to 5e-7; tests/test_chain_physics.py); the error falls as dt^2. A plate
    with dynamics of its own (the dashpot) also needs ``dt <= 0.0125 Z / k_b``: the Strang
    splitting error grows with the dashpot rate ``k_b / Z`` and this keeps the drift below 1e-6
    up to D/t = 12. Both limits are resolutions of one second-order scheme, so one knob sets them:
    ``steps_per_period`` below the default loosens the dashpot limit in proportion (80 steps per
    relaxation time at 1600 steps/period, 1.25 at 25, never coarser than half a relaxation time),
    which is how a cheaper, coarser run is asked for (e.g. the peaks within 0.1 %, 25
    steps/period on the default scene; tests/bench_chain.py). The step is then shrunk so that a
    whole number ``n_sub`` of steps fits in one sample interval: samples fall on steps.
    """
    m = scene.sphere_mass
    g = STANDARD_GRAVITY if scene.effects.gravity else 0.0
    n = scene.chain.n_particles
    e_kin = 0.5 * m * scene.impact_velocity**2
    f_s = _peak_force_bound(scene.a_s, e_kin, max(n - 1, 0) * m * g)
    f_b = _peak_force_bound(boundary.a_bottom, e_kin, n * m * g)
    k_s = 1.5 * scene.a_s ** (2.0 / 3.0) * f_s ** (1.0 / 3.0)
    k_b = 1.5 * boundary.a_bottom ** (2.0 / 3.0) * f_b ** (1.0 / 3.0)
    omega = 2.0 * math.sqrt(max(k_s, k_b) / m)
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
    that move (``infinite``, and ``sem``/``greens``, whose supports only shorten the TOF), and
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
    if name in STATIC_PLATE_MODELS:
        a_bottom, z = make_boundary(scene, (name, "")).a_bottom, math.inf
    else:
        a_bottom, z = scene.a_p, scene.plate_impedance
    return _auto_duration(scene, scene.sphere_mass, scene.a_s, a_bottom, z)


def _auto_duration(scene: Scene, m: float, a_s: float, a_p: float, z: float) -> float:
    """:func:`auto_duration` with the constants at hand: ``a_p`` the bottom contact's Hertz
    constant, ``z`` the plate impedance (inf: a wall, lambda = 0)."""
    from . import zener

    d = scene.chain.diameter
    v_in = zener.CHATTERJEE_RATIO * scene.impact_velocity
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


def _failure(run: ChainRun, plan: StepPlan, plate_model: str) -> str:
    """The SimulationError message for a run that did not finish (status code of the driver)."""
    where = f"after {run.samples_done} of {plan.n_samples} samples"
    if plan.integrator == "dopri5":
        setting = f"dopri5, rtol {plan.rtol:.3g}, plate model {plate_model}"
        if run.status == RUN_STEP_BUDGET:
            return (f"step_budget_exceeded: {setting} needed more than {plan.max_steps:,} steps "
                    f"({where}); raise solver.rtol or the budget, or shorten output.duration")
        if run.status == RUN_STEP_TOO_SMALL:
            return (f"step_too_small: {setting}: the step size fell below 1e-14 of the duration "
                    f"({where}); raise solver.rtol")
        return f"nonfinite: the run produced non-finite values {where} ({setting})"
    return (f"nonfinite: the run produced non-finite values after {run.samples_done} samples "
            f"(dt = {plan.dt:.3g} s, plate model {plate_model})")


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


def simulate(
    scene: Scene,
    *,
    max_steps: int = MAX_STEPS,
    max_samples: int = MAX_SAMPLES,
    steps_per_period: int = STEPS_PER_PERIOD,
) -> SimulationResult:
    """Simulate one shot of ``scene`` and return the sensor trace with diagnostics.

    Raises
    ------
    SimulationError
        When the request cannot be carried out: the duration needs more than ``max_steps`` steps
        or ``max_samples`` samples (status ``step_budget_exceeded``), or the run produced
        non-finite values.
    """
    started = time.perf_counter()
    solver = scene.solver
    adaptive = solver.integrator == "dopri5"
    resolved = check_solver(scene)
    boundary = make_boundary(scene, resolved)
    n = scene.chain.n_particles
    m = scene.sphere_mass
    a_s = scene.a_s
    g = STANDARD_GRAVITY if scene.effects.gravity else 0.0
    v_imp = scene.impact_velocity
    tau = scene.effects.damping if scene.effects.dissipation else 0.0

    auto = scene.output.duration == "auto"
    if auto:
        static = boundary.name in STATIC_PLATE_MODELS
        duration = _auto_duration(scene, m, a_s, boundary.a_bottom,
                                  math.inf if static else scene.plate_impedance)
    else:
        duration = float(scene.output.duration)
    if adaptive:
        # The step adapts to rtol; samples come from the dense output, not from steps.
        dt, n_sub = 1.0 / scene.output.sample_rate, 1
    else:
        dt, n_sub = choose_time_step(scene, boundary, steps_per_period)
    interval = dt * n_sub
    intervals = duration / interval * (1.0 - 1e-12)
    # a huge finite duration overflows to inf here: refuse it before math.ceil would
    n_samples = math.ceil(intervals) + 1 if intervals <= max_samples else math.inf
    steps = (n_samples - 1) * n_sub
    if (steps > max_steps and not adaptive) or n_samples > max_samples:
        advice = ("shorten output.duration, lower output.sample_rate or raise the budget"
                  if interval <= duration else
                  f"raise output.sample_rate: one sample interval ({interval:.4g} s) is longer "
                  "than the record, which is run to the end of its last interval")
        raise SimulationError(
            f"step_budget_exceeded: output.duration of {duration:.4g} s needs {steps:,.0f} "
            f"steps of {dt:.3g} s and {n_samples:,.0f} samples (budget: {max_steps:,} steps, "
            f"{max_samples:,} samples); {advice}"
        )

    u, v = initial_state(n, m, g, a_s, boundary.a_bottom, v_imp)
    traces_on = scene.output.traces
    rows = n_samples if traces_on else 0
    setup = ChainSetup(
        u=u, v=v, w=0.0, m=m, g=g, a_s=a_s, a_b=boundary.a_bottom,
        f_static=n * m * g, tau=tau, sensor=scene.chain.sensor_index,
        samples=np.empty(n_samples), energy=np.empty(n_samples),
        u_trace=np.empty((rows, n + 1)), v_trace=np.empty((rows, n + 1)),
        f_trace=np.empty((rows, n + 1)), w_trace=np.empty(rows),
    )
    plan = StepPlan(dt, n_sub, n_samples, integrator=solver.integrator, rtol=solver.rtol,
                    max_steps=max_steps)
    run = boundary.integrate(setup, plan)
    if run.status != RUN_OK:
        raise SimulationError(_failure(run, plan, boundary.name))
    if adaptive:
        steps = int(run.extra["steps_accepted"])
        dt = interval * (n_samples - 1) / max(steps, 1)

    # Relative to the energy in play: the striker's, or what left the chain if that is more
    # (with gravity a chain that keeps sinking into an infinite plate feeds it without end).
    e_scale = max(0.5 * m * v_imp**2, abs(run.plate_work) + run.dissipated)
    balance = setup.energy
    if adaptive:
        # dopri5's samples interpolate the balance between step ends: drift is measured there.
        drift = float(run.extra["energy_deviation_step_ends_J"])
        final = abs(balance[-1] - balance[0])
    else:
        deviation = np.abs(balance - balance[0])
        drift, final = deviation.max(), deviation[-1]
    static_sensor = (scene.chain.sensor_index - 0.5) * m * g
    pk = run.peaks.tolist()
    inc_f, ref_f = pk[PK_INC_F], pk[PK_REF_F]
    rise_inc, rise_ref = inc_f - static_sensor, ref_f - static_sensor
    # Undefined when the sensor cannot tell the pulses apart (e.g. it is the last particle).
    valid = (math.isfinite(rise_inc) and math.isfinite(rise_ref) and rise_inc > 0.0
             and rise_ref > 0.0)
    arr = rise_ref / rise_inc if valid else math.nan
    truth = {
        "incident_time_s": float(pk[PK_INC_T]),
        "incident_peak_N": inc_f if math.isfinite(inc_f) else math.nan,
        "reflected_time_s": float(pk[PK_REF_T]),
        "reflected_peak_N": ref_f if math.isfinite(ref_f) else math.nan,
        "tof_s": float(pk[PK_REF_T] - pk[PK_INC_T]) if valid else math.nan,
        "arr": float(arr),
        "static_sensor_N": static_sensor,
        "bottom_peak_N": float(pk[PK_BOT_F]),
        "bottom_peak_time_s": float(pk[PK_BOT_T]),
    }
    diagnostics: dict[str, Any] = {
        # auto: the record was meant to pass the reflection; say so only when one was found
        "status": ("reflection_passed" if valid else "reflection_not_found") if auto
                  else "duration_reached",
        "energy_drift": float(drift / e_scale),
        "energy_error_final": float(final / e_scale),
        "energy_scale_J": e_scale,
        "plate_work_J": run.plate_work,
        "dissipated_J": run.dissipated,
        "integrator": solver.integrator,
        **({"rtol": solver.rtol} if adaptive else {}),
        "steps": steps,
        "dt_s": dt,
        "duration_s": interval * (n_samples - 1),
        "wall_s": time.perf_counter() - started,
        "integration_wall_s": run.wall_s,
        **run.extra,
    }
    traces = None
    if traces_on:
        traces = {
            "u_m": setup.u_trace,
            "v_m_s": setup.v_trace,
            "contact_force_N": setup.f_trace,
            "plate_deflection_m": setup.w_trace,
        }
    return SimulationResult(
        scene=scene,
        plate_model=boundary.name,
        plate_model_reason=boundary.reason,
        t0=0.0,
        dt=interval,
        samples=setup.samples,
        diagnostics=diagnostics,
        truth=truth,
        traces=traces,
        energy=balance,
    )
