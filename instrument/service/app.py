"""The REST service: ``build_app(settings)`` returns the FastAPI application.

The lifespan opens the measurement store and loads the model table (when there is one); routes
live in ``routes_*.py`` (the service's own in :mod:`.routes_service`), each taking the running
service as a dependency (:mod:`.dependencies`) behind the API key (:mod:`.authentication`);
errors are RFC 9457 problem+json (:mod:`.problems`). uvicorn workers import
:func:`build_app_from_env`, which reads the same settings from ``SOLITONDE_*`` variables.
"""

from __future__ import annotations

import contextlib
import gc
import logging
from collections.abc import AsyncIterator

import anyio
from fastapi import FastAPI
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from solitonde.instrument.inference.table_set import TableSet
from solitonde.instrument.service import openapi_doc, problems
from solitonde.instrument.service.api_models import request_models
from solitonde.instrument.service.ingest import warm_up
from solitonde.instrument.service.problems import Problem
from solitonde.instrument.service.routes_service import __version__
from solitonde.instrument.service.settings import Settings
from solitonde.instrument.service.state import INGEST_THREADS, PLOT_THREADS, Service
from solitonde.instrument.service.store import Store
from solitonde.instrument.service.uploads import UploadDir

log = logging.getLogger("solitonde.instrument")


class Options:
    """ASGI middleware: ``OPTIONS`` on any route answers 204 with ``Allow`` listing the methods
    its path takes (``GET``, ``POST``, ``DELETE`` ...), 404 on a path no route has."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["method"] != "OPTIONS":
            await self.app(scope, receive, send)
            return
        from starlette.routing import Match

        routes = scope["app"].routes
        methods = {m for m in ("GET", "HEAD", "POST", "PUT", "PATCH", "DELETE")
                   if any(r.matches({**scope, "method": m})[0] == Match.FULL for r in routes)}
        if not methods:
            await self.app(scope, receive, send)  # the usual 404
            return
        allow = ", ".join(sorted(methods | {"OPTIONS"}))
        await send({"type": "http.response.start", "status": 204,
                    "headers": [(b"allow", allow.encode())]})
        await send({"type": "http.response.body", "body": b""})


class BodyLimit:
    """ASGI middleware: 413 for bodies larger than ``max_bytes``, declared or streamed."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        declared = dict(scope.get("headers") or []).get(b"content-length")
        if declared is not None:
            try:
                too_big = int(declared) > self.max_bytes
            except ValueError:
                too_big = False
            if too_big:
                await self._reject(scope, send, int(declared))
                return
        seen = 0

        async def limited() -> Message:
            nonlocal seen
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > self.max_bytes:
                    raise Problem(413, self._detail(seen, streamed=True), kind="body-too-large",
                                  field="body")
            return message

        await self.app(scope, limited, send)

    def _detail(self, size: int, streamed: bool = False) -> str:
        what = f"more than {size:,}" if streamed else f"{size:,}"
        return (f"body: {what} bytes; at most {self.max_bytes:,} bytes per request "
                "(split the shots over several requests)")

    async def _reject(self, scope: Scope, send: Send, size: int) -> None:
        problem = Problem(413, self._detail(size), kind="body-too-large", field="body")
        response = problem.response(scope.get("path"))
        response.headers["Connection"] = "close"
        await response(scope, _no_body, send)


async def _no_body() -> Message:
    return {"type": "http.disconnect"}


def build_app(settings: Settings | None = None) -> FastAPI:
    """The application for ``settings`` (default: from the environment)."""
    settings = settings or Settings.from_env()
    shot_model, measurement_model = request_models(settings.max_shots_per_request,
                                                   settings.max_samples_per_shot)

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        store = Store(settings.store_path, settings.store_synchronous)
        log.info("feature extractor ready in %.2f s", warm_up())
        tables = TableSet([settings.table_path, *settings.table_paths])
        if not tables.loaded:
            log.warning("serving without estimates: %s", tables.reason)
        else:
            log.info("model tables: %s", ", ".join(tables.by_id))
        svc = Service(settings, store, tables, UploadDir(), shot_model, measurement_model,
                      anyio.CapacityLimiter(INGEST_THREADS), anyio.CapacityLimiter(INGEST_THREADS),
                      anyio.CapacityLimiter(1), anyio.CapacityLimiter(PLOT_THREADS))
        app.state.service = svc
        # Everything loaded so far (numpy, pandas, matplotlib, the table: ~170k objects) lives
        # as long as the process; a full collection walks all of it (50-150 ms measured), a
        # pause that lands in some request's latency. Freezing moves it out of the collector's
        # reach; objects made by requests are still collected.
        gc.collect()
        gc.freeze()
        try:
            yield
        finally:
            app.state.service = None
            svc.close()

    app = FastAPI(
        title="solitonde instrument service",
        version=__version__,
        description=_description(settings),
        lifespan=lifespan,
        openapi_tags=[
            {"name": "measurements", "description": "post shots, read them back, export"},
            {"name": "plates", "description": "plates, their maps and located supports"},
            {"name": "compute", "description": "inversion and simulation"},
            {"name": "service", "description": "table, health and readiness"},
        ],
    )
    app.state.settings = settings
    app.state.service = None
    problems.install(app)
    app.add_middleware(BodyLimit, max_bytes=settings.max_body_bytes)
    app.add_middleware(Options)

    from solitonde.instrument.service import (
        routes_compute,
        routes_measurements,
        routes_plates,
        routes_service,
        routes_setups,
        web,
    )

    app.include_router(routes_measurements.router, prefix="/v1")
    app.include_router(routes_plates.router, prefix="/v1")
    app.include_router(routes_compute.router, prefix="/v1")
    app.include_router(routes_setups.router, prefix="/v1")
    app.include_router(web.router)
    app.include_router(routes_service.router)

    from solitonde.instrument.service.api_models import InvertIn, SimulateIn

    openapi_doc.install(app, (shot_model, measurement_model, InvertIn, SimulateIn))
    return app


def build_app_from_env() -> FastAPI:
    """Factory for uvicorn (``--factory``): settings from ``SOLITONDE_*`` variables."""
    logging.basicConfig(level=logging.INFO)
    return build_app(Settings.from_env())


def _description(s: Settings) -> str:
    return (
        "Measure time of flight (TOF) and amplitude ratio (ARR) of solitary-wave shots, store "
        "them, and estimate plate thickness and distance to the nearest support.\n\n"
        "**Limits** (413 or 422 above them): "
        f"request body at most {s.max_body_bytes:,} bytes; "
        f"at most {s.max_shots_per_request} shots per request; "
        f"at most {s.max_samples_per_shot:,} samples per shot and "
        f"{s.max_samples_per_request:,} per request (an uploaded file declaring more is "
        "refused with 413 before it is read); "
        f"simulation cost at most {s.max_simulation_cost:.3g} particle-steps; "
        f"page size at most {s.page_size_max}; export at most {s.export_rows_max:,} rows.\n\n"
        "**Authentication**: when the server runs with `SOLITONDE_API_KEY` set, every `/v1` "
        "route needs the key in `X-API-Key: <key>` or `Authorization: Bearer <key>`.\n\n"
        "**Errors** are RFC 9457 `application/problem+json` with `field` naming the first "
        "failing field (dotted path, e.g. `shots.0.dt`) and `errors` listing all of them."
    )
