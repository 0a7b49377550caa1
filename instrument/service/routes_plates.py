"""REST routes for plates: the plates in the store, each plate's map and its picture.

A plate is the measurements that share a ``plate_id``; those whose metadata carry ``x_m`` and
``y_m`` are its scan. The map pools the shots of each position and inverts them once, then
locates the clamped edge from the positions' distance answers (instrument.plate_map).
"""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Path, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import Response

from solitonde.instrument.service.heavy import run_for_client
from solitonde.instrument.service.problems import Problem
from solitonde.instrument.service.routes_measurements import _PROBLEM, AUTH, ERRORS
from solitonde.instrument.service.state import service

router = APIRouter(tags=["plates"], dependencies=[AUTH])
MAP_POSITIONS_MAX = 5_000
"""Measurements read for one map; a plate with more is refused with 422 (a limit, stated)."""

PlateId = Path(..., min_length=1, max_length=200, description="the plate's plate_id")


@router.get("/plates", responses=ERRORS, summary="Plates in the store, with counts")
async def list_plates(request: Request) -> dict[str, Any]:
    """Every plate_id with its measurement, shot and position counts and last activity (ISO
    8601 UTC)."""
    from solitonde.instrument.inference.estimate_rows import iso_utc

    plates = await run_in_threadpool(service(request).store.plates)
    for p in plates:
        p["last_activity"] = iso_utc(p["last_activity"])
        p["links"] = {"map": f"/v1/plates/{p['plate_id']}/map",
                      "map_png": f"/v1/plates/{p['plate_id']}/map.png"}
    return {"items": plates}


def _map(svc: Any, plate_id: str) -> dict[str, Any]:
    from solitonde.instrument.inference import plate_map

    records = svc.store.all_of_plate(plate_id, MAP_POSITIONS_MAX + 1)
    if not records:
        raise Problem(404, f"plate_id: no measurement of plate {plate_id!r}", kind="not-found",
                      field="plate_id")
    if len(records) > MAP_POSITIONS_MAX:
        raise Problem(422, f"plate_id: more than {MAP_POSITIONS_MAX:,} measurements of plate "
                      f"{plate_id!r}; a map reads at most {MAP_POSITIONS_MAX:,}", kind="limit",
                      field="plate_id")
    positions = plate_map.from_records(records, svc.estimator)
    return plate_map.build(plate_id, positions, svc.estimator.plate_size())


@router.get("/plates/{plate_id}/map", responses={**ERRORS, 404: _PROBLEM},
            operation_id="plate_map",
            summary="A plate's map: positions, estimates, the located support")
async def get_map(request: Request, plate_id: str = PlateId) -> dict[str, Any]:
    """Per position: coordinates, shot count, thickness and distance (median, intervals,
    status); then ``support`` (``normal_angle_deg``, ``offset_m``, ``ci95_offset_m``,
    ``n_positions``, ``residual_m``) or null with ``support_reason``."""

    return await run_in_threadpool(_map, service(request), plate_id)


@router.get("/plates/{plate_id}/map.png", response_class=Response,
            responses={**ERRORS, 404: _PROBLEM, 200: {"content": {"image/png": {}}}},
            operation_id="plate_map_png",
            summary="PNG of a plate's thickness and distance-to-support maps")
async def get_map_png(request: Request, plate_id: str = PlateId) -> Response:
    from solitonde.instrument.plotting import map_png

    svc = service(request)
    data = await run_in_threadpool(_map, svc, plate_id)
    png = await run_for_client(request, svc.plot_lane, map_png, data)
    return Response(png, media_type="image/png")
