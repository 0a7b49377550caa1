"""``/v1/measurements``: post shots (JSON or an uploaded file), read them back, plot, export.

The POST route reads the raw body and validates it with pydantic's JSON parser directly (one
pass, no intermediate Python objects), which is what keeps a 10,000-sample shot in the low
milliseconds; the request schemas are added to the OpenAPI document by the app factory. A shot
can also come as its raw samples (``application/octet-stream``, float32 or float64, with ``dt``
and the metadata in the query), which skips text parsing altogether. The upload's form fields
and the raw route's query are declared in :mod:`.measurement_forms`, the export's rows in
:mod:`.export_rows`.
"""

from __future__ import annotations

import errno
import hashlib
import logging
from functools import partial
from typing import Annotated, Any

import anyio.to_thread
import numpy as np
from fastapi import APIRouter, Path, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse, Response
from pydantic import ValidationError

from solitonde.instrument.service.api_models import (
    BINARY_DTYPES,
    BINARY_MEDIA_TYPE,
    BinaryShotParams,
    MeasurementOut,
    MeasurementPage,
)
from solitonde.instrument.service.authentication import AUTH
from solitonde.instrument.service.dependencies import ServiceDep, media_type
from solitonde.instrument.service.export_rows import estimates_export, shots_export
from solitonde.instrument.service.ingest import (
    check_counts,
    measure_and_store,
    measurement_dict,
    read_file,
    waveform_error,
    waveforms_from_shots,
)
from solitonde.instrument.service.measurement_forms import (
    UploadFields,
    binary_parameters,
    material_text,
)
from solitonde.instrument.service.measurement_json import (
    MeasurementJSON,
    MeasurementLine,
    MeasurementPageJSON,
    StoredShot,
)
from solitonde.instrument.service.problems import ERRORS, PROBLEM_RESPONSE, Problem, from_pydantic
from solitonde.instrument.service.routes_setups import resolve as resolve_setup
from solitonde.instrument.service.state import Service
from solitonde.instrument.service.store import KeyTaken, SetupGone, StoreFull
from solitonde.instrument.service.uploads import (
    check_self_contained,
    declared_values,
    pick_format,
)
from solitonde.instrument.service.work_lanes import run_for_client
from solitonde.signal import channels as signal_channels
from solitonde.signal.errors import WaveformError
from solitonde.signal.formats.registry import all_reader_options
from solitonde.signal.waveform import Waveform

router = APIRouter(tags=["measurements"], dependencies=[AUTH])


log = logging.getLogger("solitonde.instrument")
IDEMPOTENCY_KEY_MAX = 200



MeasurementId = Annotated[int, Path(ge=1, le=2**62, description="measurement id")]
ShotIndex = Annotated[int, Path(ge=0, le=100_000, description="shot index, from 0")]

# the readers' options, from the format registry; group and channel select after reading
_READER_OPTIONS = tuple(k for k in all_reader_options() if k not in ("group", "channel"))


Responses = dict[int | str, dict[str, Any]]
"""OpenAPI responses by status."""
_POST_LINKS: Responses = {201: {"description": "the stored measurement", "links": {
    name: {"operationId": op, "parameters": {"measurement_id": "$response.body#/id", **extra}}
    for name, op, extra in (("GetMeasurement", "get_measurement", {}),
                            ("GetShot", "get_shot", {"shot_index": 0}),
                            ("PlotMeasurement", "plot_measurement", {}),
                            ("DeleteMeasurement", "delete_measurement", {}))}}}
_POST_LINKS[200] = {"description": "these shots' samples are a stored measurement's, in order: "
                    "that measurement, not stored again, with duplicate_of (its id) and "
                    "metadata_differences (unless allow_duplicate)",
                    "content": {"application/json": {"schema": {
                        "$ref": "#/components/schemas/MeasurementOut"}}}}
_FULL: Responses = {507: {**PROBLEM_RESPONSE, "description": "the store (or the upload's temporary "
                "folder) has no room: nothing was written; retry later (Retry-After)"}}
FULL_RETRY_AFTER_S = 60
"""What a 507 suggests to wait: room comes back when someone frees it, not in milliseconds."""
_IDEMPOTENCY_HEADER = {
    "name": "Idempotency-Key", "in": "header", "required": False,
    "schema": {"type": "string", "minLength": 1, "maxLength": IDEMPOTENCY_KEY_MAX},
    "description": "a key the client makes per measurement (a UUID): a retry with the same key "
                   "and content returns the first answer (same id, header Idempotent-Replayed) "
                   "instead of storing again; the same key with other content is a 422"}


@router.post(
    "/measurements",
    status_code=201,
    response_model=MeasurementOut,
    responses={**ERRORS, **_POST_LINKS, **_FULL},
    operation_id="post_measurement",
    summary="Post one or more shots (JSON) or a waveform file (multipart)",
    openapi_extra={"requestBody": {"required": True, "content": {
        "application/json": {"schema": {"$ref": "#/components/schemas/MeasurementIn"}},
        "multipart/form-data": {"schema": {"$ref": "#/components/schemas/MeasurementUpload"}},
    }}, "parameters": [_IDEMPOTENCY_HEADER]},
)
async def post_measurement(request: Request, svc: ServiceDep) -> JSONResponse:
    """Measure TOF and ARR on every shot, aggregate per sphere size, estimate, store.

    JSON body: ``{"shots": [{"t0", "dt", "samples", "units", "calibration", "metadata"}]}``.
    Multipart: a ``file`` field (CSV, NPY, NPZ, HDF5, TDMS, JSON) and optional metadata fields;
    the file is written to a private temporary file the server names. All shots of a request
    share ``plate_id`` and ``position``. Returns 201 with the stored measurement and its id.
    No query parameters. (A raw binary body is also taken here, as at ``/v1/measurements/raw``,
    for clients written before that route.)
    """
    media = media_type(request)
    if media in ("application/json", "multipart/form-data") and request.query_params:
        name = next(iter(request.query_params))
        raise Problem(422, f"{name}: query parameters describe a binary ({BINARY_MEDIA_TYPE}) "
                      "body only (POST /v1/measurements/raw); a JSON shot carries them in the "
                      "body, an upload in form fields", kind="invalid-input", field=name)
    if media not in ("application/json", BINARY_MEDIA_TYPE, "multipart/form-data"):
        raise Problem(415, f"content-type: {media or 'none'} is not accepted here (allowed: "
                      "application/json, multipart/form-data; a raw binary shot goes to "
                      "/v1/measurements/raw)", kind="unsupported-media-type",
                      field="content-type")
    return await _post(request, svc, media)


@router.post(
    "/measurements/raw",
    status_code=201,
    response_model=MeasurementOut,
    responses={**ERRORS, **_POST_LINKS, **_FULL},
    operation_id="post_raw_shot",
    summary="Post one shot's raw samples (binary body, what they are in the query)",
    openapi_extra={"requestBody": {"required": True, "content": {
        BINARY_MEDIA_TYPE: {"schema": {"type": "string", "format": "binary"}}}},
        "parameters": [*binary_parameters(), _IDEMPOTENCY_HEADER]},
)
async def post_raw_shot(request: Request, svc: ServiceDep) -> JSONResponse:
    """One shot's samples as little-endian float32 or float64 without a header (the acquisition
    PC's own buffer); ``dtype`` and ``dt`` (and optionally ``t0``, ``units``, ``calibration``,
    ``plate_id``, ``position``, ``sphere_diameter``, ``shot``) in the query. Returns 201 with the
    stored measurement and its id."""
    media = media_type(request)
    if media != BINARY_MEDIA_TYPE:
        raise Problem(415, f"content-type: {media or 'none'} is not accepted here (allowed: "
                      f"{BINARY_MEDIA_TYPE}; JSON shots and files go to /v1/measurements)",
                      kind="unsupported-media-type", field="content-type")
    return await _post(request, svc, media)


async def _post(request: Request, svc: Service, media: str) -> JSONResponse:
    """Ingest a JSON, binary or multipart body (idempotent with a key) and answer 201."""

    key = idempotency_key(request)
    try:
        if media == "multipart/form-data":
            result = await _ingest_upload(svc, request, key)
            if isinstance(result, JSONResponse):  # a replayed answer
                return result
        else:
            body = await request.body()
            query = request.query_params.multi_items()
            idem = None
            if key is not None:
                idem = (key, _digest(media.encode(), str(sorted(query)).encode(), body))
                replay = await _replay(svc, *idem)
                if replay is not None:
                    return replay
            # In a worker thread: the event loop keeps reading other requests (and answering
            # /healthz) while this one is parsed, measured and waits for the store's writer lock.
            if media == "application/json":
                result = await anyio.to_thread.run_sync(_ingest_json, svc, body, idem,
                                                        limiter=svc.ingest_lane)
            else:
                result = await anyio.to_thread.run_sync(_ingest_binary, svc, body, query, idem,
                                                        limiter=svc.ingest_lane)
    except StoreFull as exc:  # the disk (or a file-size limit): the client should retry later
        log.warning("store full: %s", exc)
        raise Problem(507, f"store: {exc}", kind="insufficient-storage", field="store",
                      headers={"Retry-After": str(FULL_RETRY_AFTER_S)}) from None
    except SetupGone as exc:  # deleted between the request's check and its write
        raise Problem(409, f"setup: {exc.message}", kind="conflict", field="setup") from None
    except KeyTaken:  # the same request, retried while the first was being stored
        replay = await _replay(svc, key or "", None)
        if replay is None:
            raise Problem(409, "Idempotency-Key: the request that took this key was removed "
                          "meanwhile; retry", kind="conflict", field="Idempotency-Key") from None
        return replay
    # shots already stored: that measurement, 200 (nothing was created)
    return JSONResponse(result, status_code=200 if result.get("duplicate_of") else 201,
                        headers={"Location": f"/v1/measurements/{result['id']}"})


def idempotency_key(request: Request) -> str | None:
    """The request's ``Idempotency-Key`` header (1-200 printable characters), if any."""
    key = request.headers.get("idempotency-key")
    if key is None:
        return None
    key = key.strip()
    if not key or len(key) > IDEMPOTENCY_KEY_MAX or not key.isprintable():
        raise Problem(422, "Idempotency-Key: not a key (allowed: 1-200 printable characters, "
                      "e.g. a UUID the client makes per measurement)", kind="invalid-input",
                      field="Idempotency-Key")
    return key


def _digest(*parts: bytes) -> str:
    """SHA-256 over the parts, each length-prefixed (so no two splits hash alike)."""
    h = hashlib.sha256()
    for part in parts:
        h.update(len(part).to_bytes(8, "little"))
        h.update(part)
    return h.hexdigest()


async def _replay(svc: Service, key: str, digest: str | None) -> JSONResponse | None:
    """The measurement stored under ``key`` as the first answer gave it, or None when the key
    is new; a 422 when the key came with another request (``digest``; None skips the check)."""
    found = await run_in_threadpool(svc.store.idempotent, key)
    if found is None:
        return None
    stored_digest, measurement_id = found
    if digest is not None and stored_digest != digest:
        raise Problem(422, "Idempotency-Key: this key was used with another request body; a "
                      "new measurement needs a new key", kind="invalid-input",
                      field="Idempotency-Key")
    record = await run_in_threadpool(svc.store.get, measurement_id)
    if record is None:
        return None
    return JSONResponse(measurement_dict(record), status_code=201,
                        headers={"Location": f"/v1/measurements/{record.id}",
                                 "Idempotent-Replayed": "true"})


JSON_VALUES_SLACK = 10_000
"""Commas a JSON body may hold beyond one per allowed sample (metadata, keys)."""


def _ingest_json(svc: Service, body: bytes, idem: tuple[str, str] | None = None
                 ) -> MeasurementJSON:
    if not body:
        raise Problem(422, "body: empty; send {\"shots\": [...]}", kind="invalid-input",
                      field="body")
    # Every sample needs a comma: more commas than allowed samples is refused before parsing,
    # which would build a Python float per value (64 MiB of "0," is 3 GB of objects).
    limit = svc.settings.max_samples_per_request
    if body.count(b",") > limit + JSON_VALUES_SLACK:
        raise Problem(413, f"body: more than {limit:,} values; at most {limit:,} samples per "
                      "request", kind="content-too-large", field="body")
    try:  # a model made at start with the service's limits: its fields are the JSON shot's
        request: Any = svc.measurement_model.model_validate_json(body)
    except ValidationError as exc:
        raise from_pydantic(exc, svc.measurement_model) from None
    waveforms = waveforms_from_shots(request.shots, request.metadata)
    check_counts(waveforms, svc.settings, "shots")
    return measure_and_store(waveforms, svc.store, svc.tables, "json", "shots", idem,
                             request.allow_duplicate, resolve_setup(svc, request.setup))


def _ingest_binary(svc: Service, body: bytes, query: list[tuple[str, str]],
                   idem: tuple[str, str] | None = None) -> MeasurementJSON:
    """One shot from its raw little-endian samples; what they are comes from the query."""
    seen: set[str] = set()
    for name, _ in query:
        if name in seen:
            raise Problem(422, f"{name}: given more than once", kind="invalid-input", field=name)
        seen.add(name)
    try:
        params: Any = BinaryShotParams.model_validate(dict(query))
    except ValidationError as exc:
        raise from_pydantic(exc, BinaryShotParams) from None
    dtype = np.dtype(BINARY_DTYPES[params.dtype])
    if not body:
        raise Problem(422, f"body: empty; send the samples as little-endian {params.dtype}",
                      kind="invalid-input", field="body")
    if len(body) % dtype.itemsize:
        raise Problem(422, f"body: {len(body):,} bytes is not a whole number of {params.dtype} "
                      f"samples ({dtype.itemsize} bytes each)", kind="invalid-input",
                      field="body")
    n = len(body) // dtype.itemsize
    limit = min(svc.settings.max_samples_per_shot, svc.settings.max_samples_per_request)
    if n > limit:
        raise Problem(422, f"samples: {n:,} samples; at most {limit:,} per shot", kind="limit",
                      field="samples")
    meta = {k: getattr(params, k) for k in ("plate_id", "position", "sphere_diameter", "shot",
                                            "table")
            if getattr(params, k) is not None}
    if params.plate_material is not None:
        meta["plate_material"] = material_text(params.plate_material)
    setup = resolve_setup(svc, params.setup)
    try:
        waveform = Waveform(t0=params.t0, dt=params.dt, samples=np.frombuffer(body, dtype),
                            units=params.units, calibration=params.calibration, metadata=meta)
    except WaveformError as exc:
        raise waveform_error(exc, "") from None
    return measure_and_store([waveform], svc.store, svc.tables, "binary", "", idem,
                             params.allow_duplicate, setup)


async def _ingest_upload(svc: Service, request: Request, key: str | None = None) -> Any:
    try:
        form = await request.form(max_files=1, max_fields=len(UploadFields.model_fields) + 1)
    except Problem:
        raise
    except OSError as exc:  # spooling the upload to a temporary file: no room
        if exc.errno not in (errno.ENOSPC, errno.EFBIG, errno.EDQUOT):
            raise
        raise Problem(507, f"file: no room to receive the upload ({exc.strerror}); nothing was "
                      "stored, retry later", kind="insufficient-storage", field="file",
                      headers={"Retry-After": str(FULL_RETRY_AFTER_S)}) from None
    except Exception as exc:  # malformed multipart, too many parts
        raise Problem(422, f"body: not a valid multipart form ({exc})", kind="invalid-input",
                      field="body") from None
    try:
        upload = form.get("file")
        if upload is None or isinstance(upload, str):
            raise Problem(422, "file: missing; send the waveform file in a 'file' field",
                          kind="invalid-input", field="file")
        fields = {k: v for k, v in form.multi_items() if k != "file"}
        if any(not isinstance(v, str) for v in fields.values()):
            raise Problem(422, "file: only one file per request", kind="invalid-input",
                          field="file")
        try:
            opts: Any = UploadFields.model_validate(
                {k: v for k, v in fields.items() if v != ""})
        except ValidationError as exc:
            raise from_pydantic(exc, UploadFields) from None
        fmt = pick_format(opts.format, upload.filename)
        idem = None
        if key is not None:  # the content, not the bytes: a retry has a new multipart boundary
            content = await anyio.to_thread.run_sync(_file_bytes, upload.file)
            idem = (key, _digest(b"multipart", str(sorted(fields.items())).encode(),
                                 (upload.filename or "").encode(), content))
            replay = await _replay(svc, *idem)
            if replay is not None:
                return replay
        return await run_for_client(request, svc.lane_for(upload.size), _ingest_file, svc,
                                    upload.file, fmt, opts, client_name(upload.filename), idem)
    finally:
        await form.close()


def client_name(filename: str | None) -> str | None:
    """The upload's file name as a label (never used as a path): last component, printable."""
    if not filename:
        return None
    name = filename.replace("\\", "/").rsplit("/", 1)[-1]
    name = "".join(ch for ch in name if ch.isprintable())[:200]
    return name or None


def _file_bytes(stream: Any) -> bytes:
    """An upload's content (the body limit bounds it), the stream rewound for the reader."""
    stream.seek(0)
    data = stream.read()
    stream.seek(0)
    return bytes(data)


def _ingest_file(svc: Service, stream: Any, fmt: str, opts: Any,
                 filename: str | None = None,
                 idem: tuple[str, str] | None = None) -> MeasurementJSON:
    settings = svc.settings
    path = svc.uploads.write(stream, fmt)
    try:
        check_self_contained(path, fmt)
        declared = declared_values(path, fmt, opts.dataset)
        limit = settings.max_samples_per_request
        if declared is not None and declared > limit:
            raise Problem(413, f"file: declares {declared:,} samples; at most {limit:,} per "
                          f"request ({settings.max_samples_per_shot:,} per shot)",
                          kind="content-too-large", field="file")
        options = {k: getattr(opts, k) for k in _READER_OPTIONS if getattr(opts, k) is not None}
        waveforms = read_file(path, fmt, options, filename)
    finally:
        path.unlink(missing_ok=True)
    try:
        waveforms, skipped = signal_channels.select(
            waveforms, [opts.channel] if opts.channel else None, opts.group,
            filename or "the upload")
    except WaveformError as exc:
        raise waveform_error(exc, "") from None
    meta = {k: getattr(opts, k) for k in ("plate_id", "position", "sphere_diameter", "x_m",
                                          "y_m", "table")
            if getattr(opts, k) is not None}
    if opts.plate_material is not None:
        meta["plate_material"] = material_text(opts.plate_material)
    setup = resolve_setup(svc, opts.setup)
    if filename:
        meta["source"] = filename  # the reader named it after the server's temporary file
    if meta:
        waveforms = [wf.with_metadata(**meta) for wf in waveforms]
    check_counts(waveforms, settings, "file.shots")
    stored = measure_and_store(waveforms, svc.store, svc.tables, f"upload:{fmt}", "file.shots",
                               idem, opts.allow_duplicate, setup)
    return {**stored, "skipped_channels": skipped}


@router.get("/measurements", response_model=MeasurementPage, responses=ERRORS,
            summary="List measurements, optionally of one plate (paged)")
async def list_measurements(
    svc: ServiceDep,
    plate_id: str | None = Query(None, max_length=200, description="only this plate"),
    after: int = Query(0, ge=0, le=2**62, description="return ids greater than this"),
    limit: int = Query(50, ge=1, le=500, description="page size"),
) -> MeasurementPageJSON:
    """Measurements in id order; ``next`` gives the following page."""

    limit = min(limit, svc.settings.page_size_max)
    records = await run_in_threadpool(svc.store.list, plate_id, after, limit + 1)
    more = len(records) > limit
    records = records[:limit]
    items: list[MeasurementLine] = [{"id": r.id, "created_at": r.created_at, "plate_id": r.plate_id,
              "position": r.position, "n_shots": r.n_shots, "source": r.source,
              "aggregates": r.result.get("aggregates", []),
              "estimate": r.result.get("estimate"), "table": r.result.get("table"),
              "location": r.result.get("location")} for r in records]
    next_url = None
    if more and records:
        from urllib.parse import urlencode

        query: dict[str, int | str] = {"after": records[-1].id, "limit": limit}
        if plate_id is not None:
            query["plate_id"] = plate_id
        next_url = f"/v1/measurements?{urlencode(query)}"
    return {"items": items, "next": next_url}


@router.get(
    "/measurements/export",
    responses={**ERRORS, 200: {"content": {"text/csv": {}, "application/vnd.apache.parquet": {}},
                               "description": "one row per shot, or per measurement"}},
    response_class=Response,
    summary="Export measured features (one row per shot) or estimates (one row per measurement)",
)
async def export_measurements(
    svc: ServiceDep,
    format: str = Query("csv", pattern="^(csv|parquet)$", description="csv or parquet"),
    plate_id: str | None = Query(None, max_length=200, description="only this plate"),
    kind: str = Query("shots", pattern="^(shots|estimates)$",
                      description="shots: features per shot; estimates: thickness and distance "
                      "per measurement (one position), bounds and status in flat columns"),
) -> Response:
    """Stored measurements, oldest first; timestamps in ISO 8601 UTC."""

    exporter = shots_export if kind == "shots" else estimates_export
    data, media = await run_in_threadpool(exporter, svc, format, plate_id)
    suffix = "parquet" if format == "parquet" else "csv"
    name = f"{'measurements' if kind == 'shots' else 'estimates'}.{suffix}"
    return Response(data, media_type=media,
                    headers={"Content-Disposition": f'attachment; filename="{name}"'})


def _missing(measurement_id: int) -> Problem:
    return Problem(404, f"id: no measurement {measurement_id}", kind="not-found", field="id")


@router.get("/measurements/{measurement_id:int}", response_model=MeasurementOut,
            responses={**ERRORS, 404: PROBLEM_RESPONSE}, summary="One stored measurement",
            operation_id="get_measurement")
async def get_measurement(svc: ServiceDep, measurement_id: MeasurementId) -> MeasurementJSON:
    """Features per shot, aggregates and estimate as stored."""

    record = await run_in_threadpool(svc.store.get, measurement_id)
    if record is None:
        raise _missing(measurement_id)
    return measurement_dict(record)


@router.delete("/measurements/{measurement_id:int}", status_code=204, response_class=Response,
               responses={**ERRORS, 404: PROBLEM_RESPONSE},
               summary="Remove a measurement and its shots",
               operation_id="delete_measurement")
async def delete_measurement(svc: ServiceDep, measurement_id: MeasurementId) -> Response:
    """Removes the measurement and every shot of it in one transaction; 404 when there is none
    (also the second time). The plate's map follows."""

    if not await run_in_threadpool(svc.store.delete, measurement_id):
        raise _missing(measurement_id)
    return Response(status_code=204)


@router.get("/measurements/{measurement_id:int}/shots/{shot_index:int}",
            responses={**ERRORS, 404: PROBLEM_RESPONSE}, operation_id="get_shot",
            response_model=dict,
            summary="One stored shot with its samples (as stored, bit for bit)")
async def get_shot(svc: ServiceDep, measurement_id: MeasurementId,
                   shot_index: ShotIndex) -> StoredShot:
    """The trace of one shot: t0, dt, samples, units, calibration, metadata, features."""

    shot = await run_in_threadpool(svc.store.get_shot, measurement_id, shot_index)
    if shot is None:
        raise Problem(404, f"shot_index: measurement {measurement_id} has no shot {shot_index}",
                      kind="not-found", field="shot_index")
    return {"t0": shot.t0, "dt": shot.dt, "samples": shot.samples.tolist(), "units": shot.units,
            "calibration": shot.calibration, "metadata": shot.metadata,
            "features": shot.features}


@router.get("/measurements/{measurement_id:int}/plot.png", response_class=Response,
            operation_id="plot_measurement",
            responses={**ERRORS, 404: PROBLEM_RESPONSE, 200: {"content": {"image/png": {}}}},
            summary="PNG of a shot's trace with the incident and reflected pulses marked")
async def plot_measurement(
    request: Request, svc: ServiceDep, measurement_id: MeasurementId,
    shot: int = Query(0, ge=0, le=100_000, description="shot index within the measurement"),
) -> Response:

    record = await run_in_threadpool(svc.store.get_shot, measurement_id, shot)
    if record is None:
        if await run_in_threadpool(svc.store.get, measurement_id) is None:
            raise _missing(measurement_id)
        raise Problem(404, f"shot: measurement {measurement_id} has no shot {shot}",
                      kind="not-found", field="shot")
    from solitonde.instrument.plotting import trace_png

    title = f"measurement {measurement_id}, shot {shot}"
    meta = record.metadata
    if meta.get("plate_id") is not None:
        title += f" - plate {meta['plate_id']}"
    if meta.get("position") is not None:
        title += f", position {meta['position']}"
    # features are in newtons: draw the force (volts times the calibration, as Waveform does)
    samples = Waveform(record.t0, record.dt, record.samples, record.units,
                       record.calibration).force
    png = await run_for_client(request, svc.plot_lane, partial(
        trace_png, record.t0, record.dt, samples, record.features, units="N", title=title))
    return Response(png, media_type="image/png")
