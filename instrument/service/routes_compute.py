"""``/v1/invert`` (features in, estimate out) and ``/v1/simulate`` (scene in, trace out).

A simulation is priced before it runs: integration steps (from the model's own step and duration
rules) times degrees of freedom (chain particles plus, for plate models that have them, plate
degrees of freedom). Above the service's budget the request gets a 422 naming the cost; below it
the run happens in a worker thread, one at a time per process, so the event loop keeps serving.
"""

from __future__ import annotations

import math
from typing import Any

import anyio
from fastapi import APIRouter, Request
from fastapi.concurrency import run_in_threadpool
from pydantic import ValidationError

from solitonde.instrument.inference.estimates import EstimateUnavailable
from solitonde.instrument.inference.table_set import TableChoiceError, TableSet
from solitonde.instrument.service.api_models import (
    Calibration,
    InversionInput,
    InvertIn,
    InvertOut,
    SimulateIn,
    SimulateOut,
)
from solitonde.instrument.service.heavy import run_for_client
from solitonde.instrument.service.problems import Problem, from_pydantic
from solitonde.instrument.service.routes_measurements import _PROBLEM, AUTH, ERRORS, require_json
from solitonde.instrument.service.state import service
from solitonde.signal.json_ready import json_ready

router = APIRouter(tags=["compute"], dependencies=[AUTH])

_SIMULATIONS = anyio.CapacityLimiter(1)

PLATE_DOF_WEIGHT = 4.0
"""One spectral-element degree of freedom advanced one step costs about as much as 4 chain
particles advanced one step, so plate work is counted in chain-equivalent units. Measured on one
idle core: the chain (Verlet, default scene) ~3.5e8 particle-steps/s; the coupled SEM plate with
the sum-factorised stiffness ~9e7 dof-steps/s (default mesh, 14,400 to 52,728 steps). The dense
stiffness this weight was first set for ran ~2.6e7 dof-steps/s (weight 25)."""

CONVOLUTION_WEIGHT = 0.25
"""The ``greens`` plate convolves the whole force history at every plate step (sum over the
steps s of s multiply-adds: plate_steps^2 / 2 in all), which dominates long runs. One
multiply-add costs about 0.25 chain particle-steps: measured on one core, 8e9/s while the history
fits the cache (1e5 steps) and 2e9/s beyond it (4e5 steps, 39 s), against ~3.5e8 particle-steps/s
(0.175 at the slower rate, rounded up)."""


async def _payload(request: Request, model: type[Any]) -> Any:
    """The request's JSON body validated as ``model``: 415 unless JSON, 422 naming the field."""
    require_json(request)
    body = await request.body()
    try:
        return model.model_validate_json(body or b"null")
    except ValidationError as exc:
        raise from_pydantic(exc, model) from None


def _json_body(model: Any) -> dict[str, Any]:
    return {"requestBody": {"required": True, "content": {
        "application/json": {"schema": {"$ref": f"#/components/schemas/{model.__name__}"}}}}}


@router.post("/invert", response_model=InvertOut, responses={**ERRORS, 503: _PROBLEM},
             openapi_extra=_json_body(InvertIn),
             summary="Estimate thickness and distance to support from TOF and ARR")
async def invert(request: Request) -> dict[str, Any]:
    """Per sphere size: mean TOF and ARR with their scatter and shot count. Needs a loaded table
    (503 otherwise)."""

    svc = service(request)
    payload = await _payload(request, InvertIn)
    inputs = [i.model_dump() for i in payload.inputs]
    calibration = payload.calibration.model_dump(exclude_none=True) if payload.calibration \
        else None
    if not svc.estimator.loaded:
        raise Problem(503, f"table: {svc.estimator.reason}", kind="no-table", field="table")
    try:
        estimate = await run_in_threadpool(_invert, svc.estimator, inputs, calibration,
                                           payload.table, payload.plate_material)
    except EstimateUnavailable as exc:
        raise Problem(503, f"table: {exc}", kind="no-table", field="table") from None
    except TableChoiceError as exc:
        raise Problem(422, f"{exc.field}: {exc.message}", kind="invalid-input",
                      field=exc.field) from None
    except ValueError as exc:  # InversionError, TableError, CalibrationError: they name a field
        field = getattr(exc, "field", None) or "inputs"
        if field in InversionInput.model_fields:
            field = f"inputs.{field}"
        elif field in Calibration.model_fields or field.startswith("per_diameter["):
            field = f"calibration.{field}"
        message = str(exc).partition(": ")[2] or str(exc)
        raise Problem(422, f"{field}: {message}", kind="invalid-input", field=field) from None
    return {"estimate": estimate}


def _invert(tables: TableSet, inputs: list[dict[str, Any]], calibration: dict[str, Any] | None,
            table: str | None, plate_material: Any) -> dict[str, Any]:
    """The request's inputs as FeatureSummary (InversionError naming a field) through the one
    estimate path."""
    from solitonde.instrument.inference.inversion import FeatureSummary
    from solitonde.instrument.inference.pipeline import estimate

    items = [FeatureSummary.from_any(i) for i in inputs]
    return estimate(tables, items, calibration, table=table,
                    plate_material=plate_material).to_dict()


def simulation_cost(scene: Any, budget: float = math.inf) -> dict[str, Any]:
    """Price of simulating ``scene``: steps, degrees of freedom, their product.

    Uses the model's own rules (:func:`~solitonde.model.simulate.choose_time_step`,
    :func:`~solitonde.model.simulate.auto_duration`, and for the spectral-element plate tiers
    their stable step). ``cost = chain steps x (particles + 1) + w x plate steps x plate dofs``
    with ``w`` = :data:`PLATE_DOF_WEIGHT`, in chain particle-steps (about 3.5e8 per CPU second);
    ``greens`` adds its convolution, :data:`CONVOLUTION_WEIGHT` x plate_steps^2 / 2.
    A plate mesh is only built once a floor of its cost fits the ``budget``, so pricing an absurd
    mesh is itself cheap: the floor counts a plate step per sample, or more where a
    longitudinal wave would cross an element through the thickness in less (no explicit
    spectral-element step can be longer than that, :func:`_plate_steps_floor`).
    """
    from solitonde.model.boundary import StepPlan, make_boundary, resolve_plate_model
    from solitonde.model.simulate import auto_duration, check_solver, choose_time_step

    check_solver(scene)  # SceneError (422) before any mesh is built
    plate_model, _ = resolve_plate_model(scene)
    duration = (auto_duration(scene, plate_model) if scene.output.duration == "auto"
                else float(scene.output.duration))
    n_samples = math.ceil(duration * scene.output.sample_rate * (1.0 - 1e-12)) + 1
    particles = scene.chain.n_particles + 1
    out: dict[str, Any] = {"plate_model": plate_model, "duration_s": duration,
                           "n_samples": int(n_samples)}
    if plate_model in ("sem", "greens"):
        steps = max(n_samples - 1, _plate_steps_floor(scene, duration))
        floor = float(steps) * (particles + PLATE_DOF_WEIGHT * _sem_dofs(scene))
        if plate_model == "greens":
            floor += CONVOLUTION_WEIGHT * 0.5 * float(steps) ** 2
        if floor > budget:
            return {**out, "steps": steps, "dof": particles + _sem_dofs(scene),
                    "cost": floor, "estimate": "floor (before the plate mesh is built)"}
    boundary = make_boundary(scene)
    dt, n_sub = choose_time_step(scene, boundary)
    chain_steps, plate_steps, plate_dofs = (n_samples - 1) * n_sub, 0, 0
    plate = getattr(boundary, "plate", None)
    if plate is not None and hasattr(boundary, "steps"):
        _, r, per_sample = boundary.steps(StepPlan(dt, n_sub, n_samples))
        plate_steps = per_sample * (n_samples - 1)
        chain_steps = plate_steps * r
        plate_dofs = int(plate.n_dofs)
    cost = float(chain_steps) * particles + PLATE_DOF_WEIGHT * float(plate_steps) * plate_dofs
    if plate_model == "greens":
        cost += CONVOLUTION_WEIGHT * 0.5 * float(plate_steps) ** 2
    # dopri5 adapts its step (far fewer than verlet's): verlet's count bounds its cost above.
    estimate = ("upper bound (verlet step counts)" if scene.solver.integrator == "dopri5"
                else "exact step counts")
    return {**out, "steps": int(max(chain_steps, plate_steps)), "dof": particles + plate_dofs,
            "cost": cost, "estimate": estimate}


def _plate_steps_floor(scene: Any, duration: float) -> int:
    """Fewest explicit plate steps ``duration`` can take: the stable step of a spectral-element
    mesh is below the time a longitudinal wave takes to cross its thinnest element (2 h / c_L is
    the 1-D linear element's own limit; higher orders and more dimensions only shorten it), and
    through the thickness no element is thicker than t / elements_z."""
    sem = getattr(scene, "sem", None)
    if sem is None:
        return 0
    h = scene.plate.thickness / sem.elements[2]
    return math.ceil(duration * scene.plate_material.longitudinal_velocity / (2.0 * h))


def _sem_dofs(scene: Any) -> int:
    sem = getattr(scene, "sem", None)
    if sem is None:
        return 0
    nodes = 1
    for n_el, p in zip(sem.elements, sem.order, strict=True):
        nodes *= n_el * p + 1
    return 3 * nodes


@router.post("/simulate", response_model=SimulateOut, responses={**ERRORS},
             openapi_extra=_json_body(SimulateIn),
             summary="Simulate a scene; trace and measured features out (cost-limited)")
async def simulate(request: Request) -> dict[str, Any]:
    """Runs the chain model on the scene and measures the sensor trace like a recorded shot.

    The scene has the keys of a scene file (chain, striker, plate, effects, output, ...). A scene
    whose cost (steps x degrees of freedom) exceeds the service's budget is refused with 422.
    """

    svc = service(request)
    payload = await _payload(request, SimulateIn)
    return await run_for_client(request, _SIMULATIONS, _simulate, payload,
                                svc.settings.max_simulation_cost, svc.settings.max_samples_per_shot)


def _simulate(payload: SimulateIn, budget: float, max_samples: int) -> dict[str, Any]:
    from solitonde.instrument.tables.measured import as_measured, check_resolved
    from solitonde.model.errors import SceneError, SimulationError
    from solitonde.model.scene import scene_from_dict
    from solitonde.model.simulate import simulate as run_scene
    from solitonde.signal.errors import WaveformError
    from solitonde.signal.features import extract

    try:
        scene = scene_from_dict(payload.scene)
        if scene.output.traces:
            # The response carries the sensor trace only: per-particle traces (3 x samples x
            # particles floats, gigabytes within the cost budget) would be computed for nothing.
            scene = scene.with_overrides({"output.traces": False})
        check_resolved(scene)
        cost = simulation_cost(scene, budget)
    except WaveformError as exc:  # a sample rate that cannot resolve the pulse
        field = f"scene.{exc.field}"
        raise Problem(422, f"{field}: {str(exc).partition(': ')[2]}", kind="invalid-input",
                      field=field) from None
    except SceneError as exc:
        field = f"scene.{exc.field}"
        raise Problem(422, f"{field}: {str(exc).partition(': ')[2]}", kind="invalid-input",
                      field=field) from None
    except SimulationError as exc:
        raise Problem(422, f"scene: cannot be simulated ({exc})", kind="invalid-input",
                      field="scene") from None
    if cost["cost"] > budget:
        raise Problem(422, f"scene: too expensive for a request: {cost['steps']:,} steps x "
                      f"{cost['dof']:,} degrees of freedom = {cost['cost']:.3g} > budget "
                      f"{budget:.3g}; shorten output.duration, use fewer particles or a cheaper "
                      "plate model, or run `solitonde simulate` locally",
                      kind="simulation-budget", field="scene")
    if cost["n_samples"] > max_samples:
        raise Problem(422, f"scene.output: {cost['n_samples']:,} samples; at most "
                      f"{max_samples:,} (lower output.sample_rate or output.duration)",
                      kind="simulation-budget", field="scene.output")
    try:
        result = run_scene(scene)
    except SceneError as exc:
        field = f"scene.{exc.field}"
        raise Problem(422, f"{field}: {str(exc).partition(': ')[2]}", kind="invalid-input",
                      field=field) from None
    except SimulationError as exc:
        raise Problem(422, f"scene: the simulation could not be carried out ({exc})",
                      kind="simulation-failed", field="scene") from None
    wf = as_measured(result, {"source": "simulate"})  # as the table measures its points
    try:
        features = extract(wf).to_dict()
    except WaveformError as exc:
        features = {"error": str(exc)}
    return {
        "t0": float(wf.t0),
        "dt": float(wf.dt),
        "n_samples": int(wf.n),
        "samples": wf.samples.tolist() if payload.include_trace else None,
        "units": "N",
        "features": json_ready(features),
        "diagnostics": json_ready({"plate_model": result.plate_model,
                                  "plate_model_reason": result.plate_model_reason,
                                  **result.diagnostics, "truth": result.truth}),
        "cost": cost,
    }
