"""``/v1/invert`` (features in, estimate out) and ``/v1/simulate`` (scene in, trace out).

A simulation is priced before it runs: integration steps (from the model's own step and duration
rules) times degrees of freedom (chain particles plus, for plate models that have them, plate
degrees of freedom). Above the service's budget the request gets a 422 naming the cost; below it
the run happens in a worker thread, one at a time per process, so the event loop keeps serving.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, TypedDict, cast

import anyio
from fastapi import APIRouter, Request
from fastapi.concurrency import run_in_threadpool
from pydantic import ValidationError

from solitonde.instrument.errors import InstrumentError
from solitonde.instrument.inference.loaded_table import EstimateUnavailable
from solitonde.instrument.inference.pipeline import TableEstimateDict
from solitonde.instrument.inference.table_set import TableChoiceError, TableSet
from solitonde.instrument.service.api_models import (
    Calibration,
    InversionInput,
    InvertIn,
    InvertOut,
    SimulateIn,
    SimulateOut,
    plate_material_value,
)
from solitonde.instrument.service.authentication import AUTH
from solitonde.instrument.service.dependencies import ServiceDep, require_json
from solitonde.instrument.service.problems import ERRORS, PROBLEM_RESPONSE, Problem, from_pydantic
from solitonde.instrument.service.work_lanes import run_for_client
from solitonde.signal.features import FeatureDict
from solitonde.signal.json_ready import json_ready

router = APIRouter(tags=["compute"], dependencies=[AUTH])

_SIMULATIONS = anyio.CapacityLimiter(1)


class InvertJSON(TypedDict):
    """``POST /v1/invert``'s answer (:class:`InvertOut`'s keys)."""

    estimate: TableEstimateDict


class SimulationCost(TypedDict):
    """What a simulation costs (:meth:`solitonde.model.plan.RunPlan.cost_dict`)."""

    plate_model: str
    duration_s: float
    n_samples: int
    steps: int
    dof: int
    cost: float
    estimate: str


class SimulationJSON(TypedDict):
    """``POST /v1/simulate``'s answer (:class:`SimulateOut`'s keys)."""

    t0: float
    dt: float
    n_samples: int
    samples: list[float] | None
    units: str
    features: FeatureDict | dict[str, str]
    """The extractor's reading of the trace (or ``{"error"}``), JSON-ready."""
    diagnostics: dict[str, Any]
    """The model's own diagnostics and truth, JSON-ready."""
    cost: SimulationCost

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


@router.post("/invert", response_model=InvertOut, responses={**ERRORS, 503: PROBLEM_RESPONSE},
             openapi_extra=_json_body(InvertIn),
             summary="Estimate thickness and distance to support from TOF and ARR")
async def invert(request: Request, svc: ServiceDep) -> InvertJSON:
    """Per sphere size: mean TOF and ARR with their scatter and shot count. Needs a loaded table
    (503 otherwise)."""

    payload = await _payload(request, InvertIn)
    if not svc.tables.loaded:
        raise Problem(503, f"table: {svc.tables.reason}", kind="no-table", field="table")
    try:
        estimate = await run_in_threadpool(_invert, svc.tables, payload.inputs,
                                           payload.calibration, payload.table,
                                           plate_material_value(payload.plate_material))
    except EstimateUnavailable as exc:
        raise Problem(503, f"table: {exc}", kind="no-table", field="table") from None
    except TableChoiceError as exc:
        raise Problem(422, f"{exc.field}: {exc.message}", kind="invalid-input",
                      field=exc.field) from None
    except ValueError as exc:  # InversionError, TableError, CalibrationError: they name a field
        field = getattr(exc, "field", None) or "inputs"
        if field in InversionInput.model_fields:
            field = f"inputs.{field}"
        elif (field in Calibration.model_fields or field.startswith("per_diameter[")
              or field == "damping_s"):
            field = f"calibration.{field}"
        message = exc.full_message if isinstance(exc, InstrumentError) else str(exc)
        raise Problem(422, f"{field}: {message}", kind="invalid-input", field=field) from None
    return {"estimate": estimate}


def _invert(tables: TableSet, inputs: Sequence[InversionInput], calibration: Calibration | None,
            table: str | None, plate_material: Any) -> TableEstimateDict:
    """The request's inputs as FeatureSummary (InversionError naming a field) through the one
    estimate path."""
    from solitonde.instrument.inference.inversion_inputs import FeatureSummary
    from solitonde.instrument.inference.pipeline import estimate

    items = [FeatureSummary.from_any(i.model_dump()) for i in inputs]
    stated = calibration.model_dump(exclude_none=True) if calibration else None
    return estimate(tables, items, stated, table=table,
                    plate_material=plate_material).to_dict()


def simulation_cost(scene: Any, budget: float = math.inf) -> SimulationCost:
    """Price of simulating ``scene`` (:func:`solitonde.model.plan.plan`): plate model, duration,
    samples, steps, degrees of freedom and their product, in chain particle-steps (about 3.5e8
    per CPU second). A plate mesh is only built once a floor of its cost fits ``budget``."""
    from solitonde.model.plan import plan

    return cast(SimulationCost, plan(scene, budget=budget).cost_dict())


@router.post("/simulate", response_model=SimulateOut, responses={**ERRORS},
             openapi_extra=_json_body(SimulateIn),
             summary="Simulate a scene; trace and measured features out (cost-limited)")
async def simulate(request: Request, svc: ServiceDep) -> SimulationJSON:
    """Runs the chain model on the scene and measures the sensor trace like a recorded shot.

    The scene has the keys of a scene file (chain, striker, plate, effects, output, ...). A scene
    whose cost (steps x degrees of freedom) exceeds the service's budget is refused with 422.
    """

    payload = await _payload(request, SimulateIn)
    return await run_for_client(request, _SIMULATIONS, _simulate, payload,
                                svc.settings.max_simulation_cost, svc.settings.max_samples_per_shot)


def _simulate(payload: SimulateIn, budget: float, max_samples: int) -> SimulationJSON:
    from solitonde.instrument.tables.measured import as_measured, check_resolved, detect_options
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
        raise Problem(422, f"{field}: {exc.full_message}", kind="invalid-input",
                      field=field) from None
    except SceneError as exc:
        field = f"scene.{exc.field}"
        raise Problem(422, f"{field}: {exc.full_message}", kind="invalid-input",
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
        raise Problem(422, f"{field}: {exc.full_message}", kind="invalid-input",
                      field=field) from None
    except SimulationError as exc:
        raise Problem(422, f"scene: the simulation could not be carried out ({exc})",
                      kind="simulation-failed", field="scene") from None
    wf = as_measured(result, {"source": "simulate"})  # as the table measures its points
    try:
        features = extract(wf, **detect_options(result.scene)).to_dict()
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
