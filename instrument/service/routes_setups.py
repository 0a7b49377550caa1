"""REST routes for instrument set-ups, their chain calibration, and the jobs they start.

A set-up (:class:`~solitonde.instrument.inference.setups.Setup`) is what a lab configures once:
sphere sizes, the table, labels, and a chain calibration fitted on a reference plate. Every
change makes a new, immutable revision; a measurement names the revision it used. Calibrating
a set-up (from stored reference measurements, or a file ``solitonde calibrate`` wrote)
re-estimates the measurements that name it in a background job (``GET /v1/jobs/{id}``), each
keeping its earlier result.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any, TypedDict
from urllib.parse import quote

from fastapi import APIRouter, Depends, Path, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel, ConfigDict, Field

from solitonde.instrument.inference.calibration import (
    Calibration,
    CalibrationDict,
    CalibrationError,
)
from solitonde.instrument.inference.setups import (
    CalibrationSource,
    Setup,
    SetupDict,
    SetupError,
)
from solitonde.instrument.service import jobs, setup_book
from solitonde.instrument.service.authentication import AUTH
from solitonde.instrument.service.dependencies import ServiceDep, require_json
from solitonde.instrument.service.problems import ERRORS, Problem
from solitonde.instrument.service.setup_book import RevisionLine
from solitonde.instrument.service.state import Service

if TYPE_CHECKING:
    from solitonde.instrument.tables.family import Family

router = APIRouter(tags=["setups"], dependencies=[AUTH])

SetupIdPath = Path(..., min_length=1, max_length=128, description="the set-up's id, "
                   "percent-encoded (a / in it as %2F, or as it is)")
JobIdPath = Path(..., min_length=1, max_length=64, description="the job's id")


class SetupIn(BaseModel):
    """A set-up as a client states it (the service adds revision, time and calibration)."""

    model_config = ConfigDict(extra="allow")
    id: str = Field(description="the set-up's name, e.g. lab-a-chain-1 (printable, <= 128)")
    sphere_diameters_m: list[float] = Field(description="the chain's sphere sizes, m")
    table: str = Field(description="the id of the table its plates are read against "
                       "(GET /v1/tables)")
    plate_material: Any = Field(None, description="the plate family's material (a library "
                                "name or its properties), for the material spread")
    chain: dict[str, Any] | None = Field(None, description="the chain as mounted (material, "
                                         "n_particles, sensor_index ...), kept as given")
    striker: dict[str, Any] | None = Field(None, description="the striker (drop_height ...)")
    labels: dict[str, Any] | None = Field(None, description="operator, instrument, lab ...: "
                                          "what a report's title block names")


class ReferenceIn(BaseModel):
    """Stored measurements on a reference plate of known thickness and position."""

    model_config = ConfigDict(extra="forbid")
    measurement_ids: list[int] = Field(min_length=1, max_length=1000)
    thickness_m: float = Field(gt=0, le=1.0, description="the reference plate's thickness, m")
    distance_m: float = Field(ge=0, le=100.0, description="the chain's distance to the "
                              "support there, m")


class CalibrationIn(BaseModel):
    """The references a chain calibration is fitted on."""

    model_config = ConfigDict(extra="forbid")
    references: list[ReferenceIn] = Field(min_length=1, max_length=100)


class SetupLinks(TypedDict):
    self: str
    calibration: str


class LinkedSetup(SetupDict):
    """A set-up revision with its links (``GET .../revisions/{n}``, a listing's item)."""

    links: SetupLinks


class SetupOut(LinkedSetup):
    """A set-up's newest revision with the list of its revisions, then its links."""

    revisions: list[RevisionLine]


class SetupListing(TypedDict):
    items: list[LinkedSetup]


class Recalibration(TypedDict):
    """A set-up's new calibrated revision and the job re-estimating its measurements."""

    setup: SetupOut
    revision: int
    chain_calibration: CalibrationDict | None
    job: jobs.Job


def setup_links(setup_id: str) -> SetupLinks:
    """A set-up's links, its id percent-encoded whole."""
    key = quote(setup_id, safe="")
    return {"self": f"/v1/setups/{key}", "calibration": f"/v1/setups/{key}/calibration"}


def _invalid(exc: SetupError | CalibrationError, prefix: str = "") -> Problem:
    field = f"{prefix}{exc.field}"
    return Problem(422, f"{field}: {exc.full_message}", kind="invalid-input", field=field)


def setup_out(svc: Service, setup: Setup) -> SetupOut:
    """A set-up's newest revision, its revisions and links (saved as a file, what
    ``analyze --setup`` reads)."""
    return {**setup.to_dict(), "revisions": setup_book.revisions(svc.store, setup.id),
            "links": setup_links(setup.id)}


def check_against_tables(svc: Service, setup: Setup) -> None:
    """A 422 naming ``table`` (or ``plate_material``) when the service has no such table, or it
    does not serve the set-up's sizes; ``chain_calibration`` when the table cannot read it."""
    from solitonde.instrument.inference.calibration import calibrated_table
    from solitonde.instrument.inference.table_set import TableChoiceError

    if not svc.tables.loaded:
        raise Problem(422, f"table: this service has no table ({svc.tables.reason})",
                      kind="invalid-input", field="table")
    try:
        chosen = svc.tables.choose(setup.sphere_diameters_m, setup.table, setup.plate_material)
    except TableChoiceError as exc:
        raise Problem(422, f"{exc.field}: {exc.message}", kind="invalid-input",
                      field=exc.field) from None
    from solitonde.instrument.tables.table import TableError

    _chain_matches(setup, chosen.model.family)
    for i, d in enumerate(setup.sphere_diameters_m):
        try:
            chosen.model.diameter_index(d)
        except TableError as exc:
            raise Problem(422, f"sphere_diameters_m[{i}]: {exc.full_message} (table "
                          f"{setup.table!r})", kind="invalid-input",
                          field=f"sphere_diameters_m[{i}]") from None
    try:
        calibrated_table(chosen.model, setup.calibration())
    except CalibrationError as exc:
        raise _invalid(exc, "chain_calibration.") from None


CHAIN_FAMILY = {("chain", "material"): "sphere_material",
                ("chain", "n_particles"): "n_particles",
                ("chain", "sensor_index"): "sensor_index",
                ("striker", "material"): "striker_material"}
"""The set-up's chain and striker entries a table's family states, and the family key of each:
a set-up whose chain is not the one its table was simulated with is refused."""


def _chain_matches(setup: Setup, family: Family | None) -> None:
    """A 422 naming ``chain.<key>`` (or ``striker.<key>``) where the set-up's chain differs
    from the one ``family`` (the table's) was simulated with."""
    from solitonde.instrument.tables.family import describe, differences
    from solitonde.model.materials import properties_from

    if not family:
        return
    for (part, key), family_key in CHAIN_FAMILY.items():
        value = (getattr(setup, part) or {}).get(key)
        if value is None:
            continue
        field = f"{part}.{key}"
        try:
            stated = properties_from(value) if key == "material" else value
        except ValueError as exc:
            raise Problem(422, f"{field}: {exc}", kind="invalid-input", field=field) from None
        if differences({family_key: stated}, family):
            raise Problem(422, f"{field}: {describe(stated)} differs from table "
                          f"{setup.table!r}'s chain ({describe(family.get(family_key))}): its "
                          "answers would be for another instrument", kind="invalid-input",
                          field=field)


def resolve(svc: Service, setup_id: str | None, field: str = "setup") -> Setup | None:
    """The newest revision of the set-up a request names, or a 422 naming ``field``."""
    if setup_id is None:
        return None
    found = setup_book.revision(svc.store, setup_id)
    if found is None:
        known = [s.id for s in setup_book.newest(svc.store)]
        raise Problem(422, f"{field}: no set-up {setup_id!r} (known: "
                      f"{', '.join(known) if known else 'none yet; POST /v1/setups'})",
                      kind="invalid-input", field=field)
    return found


async def _body(request: Request, model: type[BaseModel]) -> Any:
    from pydantic import ValidationError

    from solitonde.instrument.service.problems import from_pydantic

    try:
        return model.model_validate_json(await request.body())
    except ValidationError as exc:
        raise from_pydantic(exc, model) from None


def _new_setup(svc: Service, body: SetupIn, setup_id: str | None = None) -> Setup:
    data = body.model_dump(exclude_none=True)
    if setup_id is not None and data.get("id", setup_id) != setup_id:
        raise Problem(422, f"id: {data['id']!r} differs from the path's {setup_id!r}",
                      kind="invalid-input", field="id")
    try:
        setup = Setup.from_dict(data, inputs_only=True)
    except SetupError as exc:
        raise _invalid(exc) from None
    check_against_tables(svc, setup)
    return setup


@router.post("/setups", status_code=201, responses=ERRORS,
             dependencies=[Depends(require_json)], summary="Create a set-up (revision 1)")
async def create_setup(request: Request, svc: ServiceDep) -> Any:
    """``{"id", "sphere_diameters_m", "table", "plate_material"?, "chain"?, "striker"?,
    "labels"?}``: 201 with revision 1; 409 when the id exists (``PUT`` revises it)."""
    setup = await run_in_threadpool(_new_setup, svc, await _body(request, SetupIn))
    stored = await run_in_threadpool(_add, svc, setup, 0)
    out = await run_in_threadpool(setup_out, svc, stored)
    return JSONResponse(out, status_code=201, headers={"Location": out["links"]["self"]})


@router.put("/setups/{setup_id:path}/calibration", status_code=201, responses=ERRORS,
            dependencies=[Depends(require_json)], response_model=dict,
            summary="Give a set-up a chain calibration written by `solitonde calibrate`")
async def put_calibration(request: Request, svc: ServiceDep,
                          setup_id: str = SetupIdPath) -> Recalibration:
    """The calibration file as it is: a new revision holding it, and a job re-estimating the
    set-up's measurements with it."""
    current = await run_in_threadpool(_existing, svc, setup_id)
    try:
        data = json.loads(await request.body())
        calibration = Calibration.from_any(data)
    except json.JSONDecodeError as exc:
        raise Problem(422, f"body: not JSON ({exc})", kind="invalid-input", field="body") from None
    except CalibrationError as exc:
        raise _invalid(exc, "chain_calibration.") from None
    except UnicodeDecodeError:
        raise Problem(422, "body: not UTF-8 JSON", kind="invalid-input", field="body") from None
    if calibration is None:
        raise Problem(422, "body: null; send the calibration file `solitonde calibrate` wrote",
                      kind="invalid-input", field="body")
    _sizes_match(current, calibration)
    return await run_in_threadpool(_calibrate, svc, current, calibration,
                                   {"kind": "file", "reference": calibration.reference})


@router.post("/setups/{setup_id:path}/calibration", status_code=201, responses=ERRORS,
             dependencies=[Depends(require_json)], response_model=dict,
             summary="Fit a set-up's chain calibration on stored reference measurements")
async def post_calibration(request: Request, svc: ServiceDep,
                           setup_id: str = SetupIdPath) -> Recalibration:
    """``{"references": [{"measurement_ids": [..], "thickness_m", "distance_m"}]}``: fits what
    ``solitonde calibrate`` fits (the chain's damping against the table's dissipation layer,
    ARR factor, TOF offset, per sphere size; by distance where references sit at several) from
    the stored shots. 201 with the fit, its uncertainty, the new revision and the job that
    re-estimates the set-up's measurements."""
    current = _existing(svc, setup_id)
    body = await _body(request, CalibrationIn)
    return await run_in_threadpool(_fit_and_calibrate, svc, current, body)


def _add(svc: Service, setup: Setup, based_on: int) -> Setup:
    """The next revision stored, or a 409 where another change came first (a revision or a
    calibration sent at the same time: resend on the newest)."""
    from solitonde.instrument.service.store import SetupConflict

    try:
        return setup_book.add_revision(svc.store, setup, based_on)
    except SetupConflict as exc:
        raise Problem(409, f"{'id' if based_on == 0 else 'setup_id'}: {exc.message}",
                      kind="conflict", field="id" if based_on == 0 else "setup_id") from None


def _existing(svc: Service, setup_id: str) -> Setup:
    found = setup_book.revision(svc.store, setup_id)
    if found is None:
        raise Problem(404, f"setup_id: no set-up {setup_id!r}", kind="not-found",
                      field="setup_id")
    return found


def _sizes_match(setup: Setup, calibration: Calibration) -> None:
    sizes = [d for d in calibration.per_diameter if setup.size_of(d) is not None]
    if calibration.per_diameter and not sizes:
        listed = ", ".join(f"{d:g}" for d in calibration.per_diameter)
        mounted = ", ".join(f"{d:g}" for d in setup.sphere_diameters_m)
        raise Problem(422, f"chain_calibration.per_diameter: its sizes ({listed} m) are none of "
                      f"set-up {setup.id!r}'s sphere_diameters_m ({mounted} m)",
                      kind="invalid-input", field="chain_calibration.per_diameter")


def _fit_and_calibrate(svc: Service, setup: Setup, body: CalibrationIn) -> Recalibration:
    from solitonde.instrument.inference.calibration_fit import Reference, fit_calibration
    from solitonde.instrument.inference.inversion_inputs import InversionError
    from solitonde.instrument.inference.loaded_table import EstimateUnavailable
    from solitonde.instrument.inference.table_set import TableChoiceError
    from solitonde.instrument.service.ingest import (
        apply_setup,
        measure_shots,
        waveforms_from_records,
    )

    try:
        chosen = svc.tables.choose(setup.sphere_diameters_m, setup.table, setup.plate_material)
    except TableChoiceError as exc:
        raise Problem(422, f"{exc.field}: {exc.message}", kind="invalid-input",
                      field=exc.field) from None
    seen: set[int] = set()
    references = []
    for i, ref in enumerate(body.references):
        for j, mid in enumerate(ref.measurement_ids):
            if mid in seen:
                field = f"references.{i}.measurement_ids.{j}"
                raise Problem(422, f"{field}: measurement {mid} is named twice (its shots "
                              "would count twice)", kind="invalid-input", field=field)
            seen.add(mid)
        waveforms = []
        for j, mid in enumerate(ref.measurement_ids):
            record = svc.store.get(mid, with_samples=True)
            if record is None:
                raise Problem(422, f"references.{i}.measurement_ids.{j}: no measurement {mid}",
                              kind="invalid-input", field=f"references.{i}.measurement_ids.{j}")
            waveforms += waveforms_from_records(record.shots)
        waveforms = apply_setup(waveforms, setup, f"references.{i}.shots")
        _, _, summaries = measure_shots(waveforms, f"references.{i}.shots")
        for s in summaries:
            try:
                references.append(Reference(ref.thickness_m, ref.distance_m, s.inputs()))
            except EstimateUnavailable as exc:
                raise Problem(422, f"references.{i}: {exc}", kind="invalid-input",
                              field=f"references.{i}") from None
            if s.hidden:
                raise Problem(422, f"references.{i}: the shots of D = {s.diameter_m:g} m show "
                              "no reflection; a reference needs one", kind="invalid-input",
                              field=f"references.{i}")
    try:
        calibration = fit_calibration(chosen.model, references)
    except (CalibrationError, InversionError) as exc:
        field = exc.field if exc.field.startswith("references") else f"references.{exc.field}"
        raise Problem(422, f"{field}: {exc.full_message}", kind="invalid-input",
                      field=field) from None
    source: CalibrationSource = {"kind": "references", "references": [
        {"measurement_ids": list(r.measurement_ids), "thickness_m": r.thickness_m,
         "distance_m": r.distance_m} for r in body.references]}
    return _calibrate(svc, setup, calibration, source)


def _calibrate(svc: Service, setup: Setup, calibration: Calibration,
               source: CalibrationSource) -> Recalibration:
    """A new revision holding ``calibration``, and the job that re-estimates its
    measurements."""
    from solitonde.instrument.service.reanalysis import recompute

    revised = Setup.from_dict({**setup.to_dict(), "chain_calibration": calibration.to_dict(),
                               "calibration_source": source})
    check_against_tables(svc, revised)
    stored = _add(svc, revised, setup.revision)

    def older() -> list[int]:
        return [m for m, r in setup_book.users(svc.store, setup.id) if r < stored.revision]

    ids = older()

    def work(progress: jobs.Progress) -> jobs.Steps:
        failed: list[jobs.Failure] = []
        done, tried = 0, set()
        todo = ids
        while todo:  # and those an upload named the older revision in while this ran
            for mid in todo:
                tried.add(mid)
                try:
                    recompute(svc.store, svc.tables, mid, stored)
                except Exception as exc:  # that measurement keeps its result; the job says why
                    failed.append({"id": mid,
                                   "reason": getattr(exc, "detail", None) or str(exc)})
                done += 1
                progress({"done": done, "total": max(done, len(ids)), "failed": failed})
            todo = [m for m in older() if m not in tried]
        return {"done": done, "total": done, "failed": failed}

    job = jobs.start(svc.store, "recalibration", len(ids),
                     {"setup": stored.reference()}, work)
    return {"setup": setup_out(svc, stored), "revision": stored.revision,
            "chain_calibration": stored.chain_calibration, "job": job}


@router.get("/setups/{setup_id:path}/revisions/{number}", responses=ERRORS,
            response_model=dict, summary="One revision of a set-up, as it was written")
async def get_revision(svc: ServiceDep, setup_id: str = SetupIdPath,
                       number: int = Path(..., ge=1, le=2**31, description="the revision")
                       ) -> LinkedSetup:
    """Revisions are immutable: what a measurement's ``provenance.setup`` names is here as it
    was when that measurement used it."""
    found = await run_in_threadpool(setup_book.revision, svc.store, setup_id, number)
    if found is None:
        _existing(svc, setup_id)
        raise Problem(404, f"number: set-up {setup_id!r} has no revision {number}",
                      kind="not-found", field="number")
    return {**found.to_dict(), "links": setup_links(found.id)}


@router.put("/setups/{setup_id:path}", status_code=200, responses=ERRORS,
            dependencies=[Depends(require_json)], response_model=dict,
            summary="Revise a set-up (a new revision)")
async def revise_setup(request: Request, svc: ServiceDep,
                       setup_id: str = SetupIdPath) -> SetupOut:
    """The set-up as a whole, as for ``POST``; its chain calibration carries over. Earlier
    revisions stay as they were, and measurements keep naming the one they used."""
    current = _existing(svc, setup_id)
    setup = _new_setup(svc, await _body(request, SetupIn), setup_id)
    revised = Setup.from_dict({**setup.to_dict(),
                               "chain_calibration": current.chain_calibration,
                               "calibration_source": current.calibration_source})
    await run_in_threadpool(check_against_tables, svc, revised)
    stored = await run_in_threadpool(_add, svc, revised, current.revision)
    return await run_in_threadpool(setup_out, svc, stored)


@router.get("/setups", responses=ERRORS, response_model=dict,
            summary="Every set-up's newest revision")
async def list_setups(svc: ServiceDep) -> SetupListing:
    setups = await run_in_threadpool(setup_book.newest, svc.store)
    return {"items": [{**s.to_dict(), "links": setup_links(s.id)} for s in setups]}


@router.get("/setups/{setup_id:path}", responses=ERRORS,
            response_model=dict,
            summary="A set-up's newest revision and the list of its revisions")
async def get_setup(svc: ServiceDep, setup_id: str = SetupIdPath) -> SetupOut:
    """Saved as a file, this is what ``solitonde analyze --setup FILE`` reads offline."""
    return await run_in_threadpool(setup_out, svc, _existing(svc, setup_id))


@router.delete("/setups/{setup_id:path}", status_code=204, response_class=Response,
               responses=ERRORS, summary="Delete a set-up no measurement names")
async def delete_setup(svc: ServiceDep, setup_id: str = SetupIdPath) -> Response:
    _existing(svc, setup_id)
    used = await run_in_threadpool(setup_book.users, svc.store, setup_id)
    try:
        if not used:
            await run_in_threadpool(setup_book.delete, svc.store, setup_id)
    except ValueError:
        used = await run_in_threadpool(setup_book.users, svc.store, setup_id)
    if used:
        raise Problem(409, f"setup_id: {len(used)} measurements name set-up {setup_id!r} "
                      f"(e.g. {used[0][0]}); it is kept", kind="conflict", field="setup_id")
    return Response(status_code=204)


@router.get("/jobs/{job_id}", responses=ERRORS, response_model=dict,
            summary="A background job's progress")
async def get_job(svc: ServiceDep, job_id: str = JobIdPath) -> jobs.Job:
    """``state`` (queued, running, done, failed, stalled), ``done`` of ``total``, ``failed``
    (each id and why); any worker process answers."""
    job = await run_in_threadpool(jobs.get, svc.store, job_id)
    if job is None:
        raise Problem(404, f"job_id: no job {job_id!r}", kind="not-found", field="job_id")
    return job
