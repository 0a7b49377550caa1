"""The service's own routes: liveness (``/healthz``), readiness (``/readyz``) and the loaded
model tables (``/v1/tables``, ``/v1/table``, behind the API key as every ``/v1`` route)."""

from __future__ import annotations

from typing import Literal, TypedDict

from fastapi import APIRouter

from solitonde.instrument.inference.table_set import TableListing
from solitonde.instrument.service.api_models import Health, Ready, TableOut
from solitonde.instrument.service.authentication import AUTH
from solitonde.instrument.service.dependencies import ServiceDep
from solitonde.instrument.service.problems import PROBLEM_RESPONSE, Problem
from solitonde.instrument.tables.table import TableSummary
from solitonde.model.version import package_version

__version__ = package_version()

router = APIRouter(tags=["service"])


class HealthJSON(TypedDict):
    """:class:`Health`'s keys."""

    status: Literal["ok"]
    version: str


class ReadyJSON(TypedDict):
    """:class:`Ready`'s keys."""

    ready: bool
    store: str
    table_loaded: bool
    estimates: bool
    reason: str | None


class TableJSON(TypedDict):
    """:class:`TableOut`'s keys."""

    loaded: bool
    path: str | None
    reason: str | None
    summary: TableSummary | None
    """The table's axes and provenance (the table's own JSON)."""
    limits: dict[str, int | float]


@router.get("/healthz", response_model=Health)
async def healthz() -> HealthJSON:
    """Liveness: the process answers."""
    return {"status": "ok", "version": __version__}


@router.get("/readyz", response_model=Ready, responses={503: PROBLEM_RESPONSE})
async def readyz(svc: ServiceDep) -> ReadyJSON:
    """Readiness: the store answers; says whether estimates are available (a table loaded)."""
    try:
        svc.store.count()
    except Exception as exc:
        raise Problem(503, f"store: not usable ({exc})", field="store") from None
    loaded = svc.tables.loaded
    return {"ready": True, "store": svc.settings.store_path.name, "table_loaded": loaded,
            "estimates": loaded, "reason": None if loaded else svc.tables.reason}


class TablesJSON(TypedDict):
    """``GET /v1/tables``: every loaded table, and why any configured one is not."""

    items: list[TableListing]
    problems: list[str]


@router.get("/v1/tables", dependencies=[AUTH], response_model=dict)
async def tables(svc: ServiceDep) -> TablesJSON:
    """Every loaded model table: id, plate family (materials with their properties, plate
    size, supports, gravity, chain, striker), sphere sizes and axes' ranges."""
    return {"items": svc.tables.listing(), "problems": svc.tables.problems}


@router.get("/v1/table", response_model=TableOut, dependencies=[AUTH])
async def table(svc: ServiceDep) -> TableJSON:
    """The loaded model table: axes, provenance; and the service's request limits."""
    tables = svc.tables
    return {"loaded": tables.loaded, "path": str(tables.path) if tables.path else None,
            "reason": tables.reason, "summary": tables.summary(),
            "limits": svc.settings.limits()}
