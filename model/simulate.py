"""Run a scene through the discrete element chain: ``simulate(scene) -> SimulationResult``.

The chain starts in static equilibrium (gravity on: the contact below particle k carries k m g,
the plate contact N m g) with the striker just touching particle 1 and moving at v_imp, so nothing
moves before the impact. The bottom boundary comes from :mod:`solitonde.model.tiers`; the time
step, the duration (the Zener/Nesterenko theory unless the scene gives one) and the sample count
from :func:`solitonde.model.plan.plan`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numba import njit

from .chain import PK_BOT_F, PK_BOT_T, PK_INC_F, PK_INC_T, PK_REF_F, PK_REF_T, new_peak_tracker
from .errors import SimulationError
from .greens import GreensCache
from .plan import MAX_SAMPLES, MAX_STEPS, STEPS_PER_PERIOD, RunPlan, check_solver, plan
from .record import ChainRecord, chain_record
from .scene import Scene, SceneConstants
from .status import RUN_OK, RUN_SHORT_RESPONSE, RUN_STEP_BUDGET, RUN_STEP_TOO_SMALL
from .tiers import ChainRun, StepPlan, make_boundary


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
    if run.status == RUN_SHORT_RESPONSE:  # an internal inconsistency, never the user's input
        return (f"internal: the plate response of plate model {plate_model} is shorter than "
                "the run; please report this scene")
    return (f"nonfinite: the run produced non-finite values after {run.samples_done} samples "
            f"(dt = {plan.dt:.3g} s, plate model {plate_model})")


def simulate(
    scene: Scene,
    *,
    max_steps: int = MAX_STEPS,
    max_samples: int = MAX_SAMPLES,
    steps_per_period: int = STEPS_PER_PERIOD,
    greens_cache: GreensCache | None = None,
) -> SimulationResult:
    """Simulate one shot of ``scene`` and return the sensor trace with diagnostics.

    ``greens_cache`` keeps the plate responses of the ``greens`` tier (any object with
    ``load(key)`` and ``store(key, array)``); None uses the process's memory cache.

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
    boundary = make_boundary(scene, check_solver(scene), greens_cache)
    constants = scene.constants()  # once: every step below reads them
    planned = plan(scene, boundary, steps_per_period=steps_per_period, constants=constants)
    _check_budget(planned, adaptive, max_steps, max_samples)
    n_samples, interval = planned.n_samples, planned.interval_s
    record = _start_record(scene, constants, boundary.a_bottom, n_samples)
    step_plan = StepPlan(planned.dt_s, planned.n_sub, n_samples, integrator=solver.integrator,
                         rtol=solver.rtol, max_steps=max_steps)
    run = boundary.integrate(record, step_plan)
    if run.status != RUN_OK:
        raise SimulationError(_failure(run, step_plan, boundary.name))
    steps, dt = (n_samples - 1) * planned.n_sub, planned.dt_s
    if adaptive:
        steps = int(run.extra["steps_accepted"])
        dt = interval * (n_samples - 1) / max(steps, 1)
    truth, valid = _truth(scene, constants, run)
    auto = scene.output.duration == "auto"
    diagnostics: dict[str, Any] = {
        # auto: the record was meant to pass the reflection; say so only when one was found
        "status": ("reflection_passed" if valid else "reflection_not_found") if auto
                  else "duration_reached",
        **_energy(constants, run, record.energy, adaptive),
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
    if scene.output.traces:
        traces = {
            "u_m": record.u_trace,
            "v_m_s": record.v_trace,
            "contact_force_N": record.f_trace,
            "plate_deflection_m": record.w_trace,
        }
    return SimulationResult(
        scene=scene,
        plate_model=boundary.name,
        plate_model_reason=boundary.reason,
        t0=0.0,
        dt=interval,
        samples=record.samples,
        diagnostics=diagnostics,
        truth=truth,
        traces=traces,
        energy=record.energy,
    )


def _check_budget(planned: RunPlan, adaptive: bool, max_steps: int, max_samples: int) -> None:
    """Refuse a run whose fixed steps or samples exceed the budget (before any work)."""
    dt, n_samples, interval = planned.dt_s, planned.n_samples, planned.interval_s
    steps = (n_samples - 1) * planned.n_sub
    if (steps > max_steps and not adaptive) or n_samples > max_samples:
        duration = planned.duration_s
        advice = ("shorten output.duration, lower output.sample_rate or raise the budget"
                  if interval <= duration else
                  f"raise output.sample_rate: one sample interval ({interval:.4g} s) is longer "
                  "than the record, which is run to the end of its last interval")
        raise SimulationError(
            f"step_budget_exceeded: output.duration of {duration:.4g} s needs {steps:,.0f} "
            f"steps of {dt:.3g} s and {n_samples:,.0f} samples (budget: {max_steps:,} steps, "
            f"{max_samples:,} samples); {advice}"
        )


def _start_record(
    scene: Scene, c: SceneConstants, a_bottom: float, n_samples: int
) -> ChainRecord:
    """The chain at the instant of impact and room for ``n_samples`` samples (and the traces
    when the scene asks for them); ``c`` the scene's constants."""
    n = scene.chain.n_particles
    m, g, a_s = c.sphere_mass, c.gravity, c.a_s
    tau = scene.effects.damping if scene.effects.dissipation else 0.0
    u, v = initial_state(n, m, g, a_s, a_bottom, c.impact_velocity)
    rows = n_samples if scene.output.traces else 0
    return chain_record(
        u, v, u.copy(), m, g, a_s, a_bottom, n * m * g, tau, scene.chain.sensor_index,
        np.empty(n_samples), np.empty(n_samples), np.empty((rows, n + 1)),
        np.empty((rows, n + 1)), np.empty((rows, n + 1)), np.empty(rows), new_peak_tracker(),
        c.striker_mass, c.a_0,
    )


def _truth(scene: Scene, c: SceneConstants, run: ChainRun) -> tuple[dict[str, float], bool]:
    """The model's own peaks (see :class:`SimulationResult`), and whether the sensor told the
    incident and the reflected pulse apart; ``c`` the scene's constants."""
    static_sensor = (scene.chain.sensor_index - 0.5) * c.sphere_mass * c.gravity
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
    return truth, valid


def _energy(
    c: SceneConstants, run: ChainRun, balance: np.ndarray, adaptive: bool
) -> dict[str, float]:
    """The energy balance's diagnostics: drift and final error relative to the energy in play,
    that scale, and the energy that left the chain (``c`` the scene's constants)."""
    # Relative to the energy in play: the striker's, or what left the chain if that is more
    # (with gravity a chain that keeps sinking into an infinite plate feeds it without end).
    e_scale = max(0.5 * c.striker_mass * c.impact_velocity**2,
                  abs(run.plate_work) + run.dissipated)
    if adaptive:
        # dopri5's samples interpolate the balance between step ends: drift is measured there.
        drift = float(run.extra["energy_deviation_step_ends_J"])
        final = abs(balance[-1] - balance[0])
    else:
        deviation = np.abs(balance - balance[0])
        drift, final = deviation.max(), deviation[-1]
    return {
        "energy_drift": float(drift / e_scale),
        "energy_error_final": float(final / e_scale),
        "energy_scale_J": e_scale,
        "plate_work_J": run.plate_work,
        "dissipated_J": run.dissipated,
    }
