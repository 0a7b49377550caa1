"""REST routes for plates: the plates in the store, each plate's map and its picture.

A plate is the measurements that share a ``plate_id``; those whose metadata carry ``x_m`` and
``y_m`` are its scan. The map pools the shots of each position and inverts them once, then
locates the clamped edge from the positions' distance answers (instrument.plate_map). With
``joint=true`` the scan is inverted as one unknown (the plate's edges and every position's
thickness) and with ``suggest=N`` the N positions to measure next are added; the same query
draws ``map.png``. The last few maps are kept (a plate's map changes only when its measurements
do), so the page's JSON and picture of one map cost one inversion.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import TYPE_CHECKING, Any, Literal, TypedDict
from urllib.parse import quote

from fastapi import APIRouter, Depends, Path, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import Response

from solitonde.instrument.service.authentication import AUTH
from solitonde.instrument.service.dependencies import ServiceDep
from solitonde.instrument.service.problems import ERRORS, PROBLEM_RESPONSE, Problem
from solitonde.instrument.service.state import Service
from solitonde.instrument.service.work_lanes import run_for_client

if TYPE_CHECKING:
    from solitonde.instrument.inference.plate_map import JointOptions, PlateMap
    from solitonde.instrument.reports.content import DataDigest, DigestEntry

router = APIRouter(tags=["plates"], dependencies=[AUTH])
MAP_POSITIONS_MAX = 5_000
"""Measurements read for one map; a plate with more is refused with 422 (a limit, stated)."""

PlateId = Path(..., min_length=1, max_length=200, description="the plate's plate_id, "
               "percent-encoded (a / in it as %2F, or as it is)")


class PlateLinks(TypedDict):
    map: str
    map_png: str


class PlateLine(TypedDict):
    """A plate of ``GET /v1/plates``: its counts, its last activity (ISO 8601 UTC), links."""

    plate_id: str
    n_measurements: int
    n_shots: int
    n_positions: int
    last_activity: str | None
    links: PlateLinks


class PlateListing(TypedDict):
    items: list[PlateLine]


class PlateDigest(TypedDict):
    """``GET /v1/plates/{id}/digest``: each measurement's digest entry and the plate's."""

    plate_id: str
    measurements: list[DigestEntry]
    digest: DataDigest


def plate_links(plate_id: str) -> PlateLinks:
    """A plate's links, its id percent-encoded whole (a ``/``, a space or a ``?`` in it stays
    part of the id)."""
    key = quote(plate_id, safe="")
    return {"map": f"/v1/plates/{key}/map", "map_png": f"/v1/plates/{key}/map.png"}


@router.get("/plates", responses=ERRORS, response_model=dict,
            summary="Plates in the store, with counts")
async def list_plates(svc: ServiceDep) -> PlateListing:
    """Every plate_id with its measurement, shot and position counts and last activity (ISO
    8601 UTC)."""
    from solitonde.instrument.inference.estimate_rows import iso_utc

    plates = await run_in_threadpool(svc.store.plates)
    return {"items": [{"plate_id": p["plate_id"], "n_measurements": p["n_measurements"],
                       "n_shots": p["n_shots"], "n_positions": p["n_positions"],
                       "last_activity": iso_utc(p["last_activity"]),
                       "links": plate_links(p["plate_id"])} for p in plates]}


MAPS_KEPT = 8
_kept: OrderedDict[tuple[Any, ...], PlateMap] = OrderedDict()
_kept_lock = threading.Lock()


class MapQuery:
    """The map's query: the joint answer, its thickness prior, the next positions."""

    def __init__(
        self,
        joint: bool = Query(False, description="invert the scan as one unknown: the plate's "
                            "edges and every position's thickness, with the joint fit and "
                            "warnings"),
        suggest: int = Query(0, ge=0, le=20, description="the N positions where a measurement "
                             "would shrink the edge's (or the thickness map's) interval most"),
        suggest_for: Literal["edge", "thickness"] = Query(
            "edge", description="what the suggestions shrink"),
        thickness_prior: Literal["free", "common"] = Query(
            "free", description="each position's thickness free, or tied to the plate's "
            "common mean with thickness_spread"),
        thickness_spread: float | None = Query(
            None, ge=1e-3, le=1.0, description="with thickness_prior=common: each position's "
            "relative spread around the mean (1 sd; default 0.05)"),
    ) -> None:
        from solitonde.instrument.inference.joint_map import DEFAULT_SPREAD, JointMapError
        from solitonde.instrument.inference.plate_map import JointOptions

        if thickness_spread is not None and thickness_prior != "common":
            raise Problem(422, "thickness_spread: only with thickness_prior=common (the "
                          "positions' spread around their common mean)", field="thickness_spread")
        try:
            self.options = JointOptions(joint, suggest, suggest_for, thickness_prior,
                                        DEFAULT_SPREAD if thickness_spread is None
                                        else thickness_spread)
        except JointMapError as exc:
            raise Problem(422, str(exc), field=exc.field) from None


def _map(svc: Service, plate_id: str, options: JointOptions | None = None) -> PlateMap:
    from solitonde.instrument.inference import plate_map
    from solitonde.instrument.inference.joint_map import JointMapError
    from solitonde.instrument.inference.table_set import TableChoiceError

    records = svc.store.all_of_plate(plate_id, MAP_POSITIONS_MAX + 1)
    if not records:
        raise Problem(404, f"plate_id: no measurement of plate {plate_id!r}", kind="not-found",
                      field="plate_id")
    if len(records) > MAP_POSITIONS_MAX:
        raise Problem(422, f"plate_id: more than {MAP_POSITIONS_MAX:,} measurements of plate "
                      f"{plate_id!r}; a map reads at most {MAP_POSITIONS_MAX:,}", kind="limit",
                      field="plate_id")
    key = (id(svc), plate_id, tuple((r.id, r.created_at) for r in records), options)
    with _kept_lock:
        if key in _kept:
            _kept.move_to_end(key)
            return _kept[key]
    try:
        result = plate_map.of_records(plate_id, records, svc.tables, options)
    except (JointMapError, TableChoiceError) as exc:
        raise Problem(422, str(exc), field=exc.field) from None
    with _kept_lock:
        _kept[key] = result
        while len(_kept) > MAPS_KEPT:
            _kept.popitem(last=False)
    return result


@router.get("/plates/{plate_id:path}/map", responses={**ERRORS, 404: PROBLEM_RESPONSE},
            operation_id="plate_map", response_model=dict,
            summary="A plate's map: positions, estimates, the located support")
async def get_map(svc: ServiceDep, plate_id: str = PlateId,
                  query: MapQuery = Depends()) -> PlateMap:
    """Per position: coordinates, shot count, thickness and distance (median, intervals,
    status); then ``support`` (``normal_angle_deg``, ``offset_m``, ``ci95_offset_m``,
    ``n_positions``, ``residual_m``) or null with ``support_reason``.

    ``joint=true``: the positions' thickness and distance from one posterior over the plate's
    edges (each position's own answer under ``per_position``), ``support`` from it (with
    ``ci95_normal_angle_deg``, ``model``, ``second_offset_m``, ``status``), ``fit``
    (``chi2``, ``dof``, ``p_value``: do the positions agree with one straight edge?),
    ``warnings`` and ``thickness_prior``. ``suggest=N``: ``suggestions``, N positions
    ``{x_m, y_m, expected_gain, distance_m}`` and ``suggestions_basis`` (what the gain
    measures)."""

    return await run_in_threadpool(_map, svc, plate_id, query.options)


@router.get("/plates/{plate_id:path}/map.png", response_class=Response,
            responses={**ERRORS, 404: PROBLEM_RESPONSE, 200: {"content": {"image/png": {}}}},
            operation_id="plate_map_png",
            summary="PNG of a plate's thickness and distance-to-support maps")
async def get_map_png(request: Request, svc: ServiceDep, plate_id: str = PlateId,
                      query: MapQuery = Depends()) -> Response:
    """The map's picture; with ``joint`` and ``suggest`` as for the map's JSON (the suggested
    positions marked as stars)."""
    from solitonde.instrument.plotting import map_png

    data = await run_in_threadpool(_map, svc, plate_id, query.options)
    png = await run_for_client(request, svc.plot_lane, map_png, data)
    return Response(png, media_type="image/png")


REPORT_MEDIA = {"pdf": "application/pdf", "html": "text/html; charset=utf-8",
                "json": "application/json"}


@router.get("/plates/{plate_id:path}/digest", responses={**ERRORS, 404: PROBLEM_RESPONSE},
            response_model=dict,
            summary="The plate's data digest as stored now (what `report verify` compares)")
async def get_digest(svc: ServiceDep, plate_id: str = PlateId) -> PlateDigest:
    """Per measurement its digest entry (id, position, shot sample hashes, stored result) and
    its digest, and the plate's data digest: what a report of the plate printed, if nothing
    changed since."""
    from solitonde.instrument.reports import digest
    from solitonde.instrument.service import plate_report

    items = await run_in_threadpool(plate_report.entries, svc.store, plate_id)
    if not items:
        raise Problem(404, f"plate_id: no measurement of plate {plate_id!r}", kind="not-found",
                      field="plate_id")
    return {"plate_id": plate_id, "measurements": items,
            "digest": {"algorithm": digest.ALGORITHM, "value": digest.data_digest(
                [{k: v for k, v in e.items() if k != "digest"} for e in items])}}


@router.get("/plates/{plate_id:path}/report.{fmt}",
            responses={**ERRORS, 404: PROBLEM_RESPONSE,
                       200: {"content": {"application/pdf": {}, "text/html": {},
                                         "application/json": {}}}},
            operation_id="plate_report", response_class=Response,
            summary="The plate's inspection report: PDF, HTML, or the data they show (JSON)")
async def get_report(request: Request, svc: ServiceDep, plate_id: str = PlateId,
                     fmt: Literal["pdf", "html", "json"] = Path(..., description="pdf, html "
                                                                "or json"),
                     joint: bool = Query(True, description="invert the scan jointly (three "
                                         "positions with coordinates or more)"),
                     suggest: int | None = Query(None, ge=0, le=20, description="the next "
                                                 "positions suggested (default 3 up to 50 "
                                                 "positions, none beyond)")) -> Response:
    """A report a reviewer signs: the title block (set-up labels), the maps, the positions'
    answers with their intervals, status, warnings and readings, each position's shots and a
    trace, the chain calibration, the table and software, the data digest (``report verify``
    recomputes it) and a signature block."""
    from solitonde.instrument.service import plate_report

    source = {"server": str(request.base_url).rstrip("/"), "plate_id": plate_id}

    def make() -> bytes:
        try:
            return plate_report.report_bytes(svc.store, svc.tables, plate_id, source, fmt,
                                             joint=joint, suggest=suggest)
        except plate_report.NoSuchPlate:
            raise Problem(404, f"plate_id: no measurement of plate {plate_id!r}",
                          kind="not-found", field="plate_id") from None

    data = await run_for_client(request, svc.plot_lane, make)
    safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in plate_id)[:80]
    return Response(data, media_type=REPORT_MEDIA[fmt], headers={
        "Content-Disposition": f'inline; filename="report_{safe}.{fmt}"'})
