"""RFC 9457 problem details: every error the service returns is ``application/problem+json``.

A problem carries ``type``, ``title``, ``status``, ``detail`` and, for bad input, ``field`` (the
dotted path of the first failing field, e.g. ``shots.0.dt``) and ``errors`` (all of them).
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping, Sequence
from typing import Any, NotRequired, TypedDict

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel, ValidationError
from starlette.exceptions import HTTPException as StarletteHTTPException

from solitonde.instrument.errors import InstrumentError

PROBLEM_MEDIA_TYPE = "application/problem+json"
TYPE_BASE = "urn:solitonde:problem:"

log = logging.getLogger("solitonde.instrument")

_TITLES = {
    400: "Bad request",
    401: "Unauthorized",
    404: "Not found",
    405: "Method not allowed",
    409: "Conflict",
    413: "Request body too large",
    415: "Unsupported media type",
    422: "Invalid input",
    500: "Internal server error",
    503: "Service unavailable",
    507: "Insufficient storage",
}


class FieldError(TypedDict):
    """One failing field of a problem and what is wrong with it."""

    field: str
    message: str


class ProblemBody(TypedDict):
    """A problem+json body (RFC 9457) as the service sends it."""

    type: str
    title: str
    status: int
    detail: str
    instance: NotRequired[str]
    field: NotRequired[str]
    errors: NotRequired[list[FieldError]]


class Problem(InstrumentError):
    """An error to send to the client as problem+json.

    Parameters
    ----------
    status:
        HTTP status code.
    detail:
        Human-readable sentence that says what is wrong and what is allowed.
    kind:
        Short slug; the problem ``type`` is ``urn:solitonde:problem:<kind>``.
    field:
        Dotted path of the failing field, when the problem is about one.
    errors:
        Every failing field as ``{"field": ..., "message": ...}``.
    """

    field_in_text = False

    def __init__(
        self,
        status: int,
        detail: str,
        *,
        kind: str | None = None,
        field: str | None = None,
        errors: Sequence[FieldError] | None = None,
        headers: Mapping[str, str] | None = None,
        title: str | None = None,
    ) -> None:
        super().__init__(field or "", detail)
        self.status = status
        self.detail = detail
        self.kind = kind or _slug(_TITLES.get(status, "error"))
        self.field = field or ""  # "" where the problem is about no one field
        self.errors: list[FieldError] = (
            list(errors) if errors else ([{"field": field, "message": detail}] if field else []))
        self.headers = dict(headers or {})
        self.title = title or _TITLES.get(status, "Error")

    def body(self, instance: str | None = None) -> ProblemBody:
        out: ProblemBody = {
            "type": TYPE_BASE + self.kind,
            "title": self.title,
            "status": self.status,
            "detail": self.detail,
        }
        if instance:
            out["instance"] = instance
        if self.field:
            out["field"] = self.field
        if self.errors:
            out["errors"] = self.errors
        return out

    def response(self, instance: str | None = None) -> JSONResponse:
        return JSONResponse(self.body(instance), status_code=self.status,
                            media_type=PROBLEM_MEDIA_TYPE, headers=self.headers)


class FieldErrorModel(BaseModel):
    """One failing field of a 422: its dotted path and what is wrong with it."""

    field: str
    message: str


class ProblemModel(BaseModel):
    """Schema of a problem+json body (for the OpenAPI document)."""

    type: str
    title: str
    status: int
    detail: str
    instance: str | None = None
    field: str | None = None
    errors: list[FieldErrorModel] | None = None


PROBLEM_RESPONSE: dict[str, Any] = {"model": ProblemModel,
                                     "content": {PROBLEM_MEDIA_TYPE: {}}}
"""An OpenAPI response whose body is problem+json (for a route's ``responses``)."""
ERRORS: dict[int | str, dict[str, Any]] = {
    401: {**PROBLEM_RESPONSE, "description": "missing or wrong API key"},
    413: {**PROBLEM_RESPONSE, "description": "body larger than the limit"},
    415: {**PROBLEM_RESPONSE, "description": "unsupported content type"},
    422: {**PROBLEM_RESPONSE, "description": "invalid input; 'field' names it"},
}
"""The problems every ``/v1`` route may answer, for the OpenAPI document."""


def _slug(text: str) -> str:
    return "-".join(text.lower().split())


def invalid(field: str, message: str) -> Problem:
    """422 for one bad field."""
    return Problem(422, f"{field}: {message}", kind="invalid-input", field=field)


def join_loc(loc: Iterable[Any], prefix: str = "") -> str:
    """Dotted field path from a pydantic location tuple (``('shots', 0, 'dt')`` -> shots.0.dt)."""
    parts = [str(p) for p in loc if p not in ("body",) and not str(p).startswith("function-")]
    path = ".".join(parts)
    if prefix:
        return f"{prefix}.{path}" if path else prefix
    return path or "body"


def _message(error: Mapping[str, Any], model: type[BaseModel] | None) -> str:
    kind = error.get("type", "")
    loc = error.get("loc", ())
    if kind == "extra_forbidden":
        allowed = _allowed_keys(model, loc[:-1]) if model is not None else None
        msg = f"unknown field {str(loc[-1])!r}" if loc else "unknown field"
        return msg + (f" (allowed here: {', '.join(allowed)})" if allowed else "")
    if kind == "finite_number":
        return "must be a finite number (NaN and infinity are not allowed)"
    if kind == "too_long":
        ctx = error.get("ctx") or {}
        return (f"has {ctx.get('actual_length')} items; at most {ctx.get('max_length')} are "
                "allowed (a service limit, see the API docs)")
    if kind == "too_short":
        ctx = error.get("ctx") or {}
        return f"must have at least {ctx.get('min_length')} item(s), got {ctx.get('actual_length')}"
    if kind == "json_invalid":
        ctx = error.get("ctx") or {}
        return f"body is not valid JSON ({ctx.get('error', error.get('msg'))})"
    msg = str(error.get("msg", "invalid"))
    return msg.removeprefix("Value error, ")


def _allowed_keys(model: type[BaseModel] | None, loc: Sequence[Any]) -> list[str] | None:
    """Walk a model along a location to list the keys allowed where an unknown key appeared."""
    current: Any = model
    for part in loc:
        if isinstance(part, int):
            continue
        fields = getattr(current, "model_fields", None)
        if not fields or str(part) not in fields:
            return None
        annotation = fields[str(part)].annotation
        current = _model_in(annotation)
    fields = getattr(current, "model_fields", None)
    return list(fields) if fields else None


def _model_in(annotation: Any) -> Any:
    """The BaseModel inside ``list[M]``, ``M | None`` and the like, else the annotation."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in getattr(annotation, "__args__", ()) or ():
        found = _model_in(arg)
        if isinstance(found, type) and issubclass(found, BaseModel):
            return found
    return annotation


def from_validation_errors(
    errors: Sequence[Mapping[str, Any]], model: type[BaseModel] | None = None, prefix: str = ""
) -> Problem:
    """One 422 problem listing every pydantic error with its dotted field path."""
    items: list[FieldError] = [
        {"field": join_loc(e.get("loc", ()), prefix), "message": _message(e, model)}
        for e in errors]
    if not items:
        items = [{"field": prefix or "body", "message": "invalid input"}]
    first = items[0]
    detail = f"{first['field']}: {first['message']}"
    if len(items) > 1:
        detail += f" (and {len(items) - 1} more error(s), listed in 'errors')"
    return Problem(422, detail, kind="invalid-input", field=first["field"], errors=items[:50])


def from_pydantic(exc: ValidationError, model: type[BaseModel] | None = None) -> Problem:
    return from_validation_errors(exc.errors(include_url=False, include_input=False), model)


def install(app: FastAPI) -> None:
    """Route every error through problem+json."""

    @app.exception_handler(Problem)
    async def _problem(request: Request, exc: Problem) -> JSONResponse:
        return exc.response(request.url.path)

    from solitonde.instrument.service.work_lanes import ClientGone, gone_response

    @app.exception_handler(ClientGone)
    async def _gone(request: Request, exc: ClientGone) -> Response:
        return gone_response()

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = [dict(e) for e in exc.errors()]
        for e in errors:
            loc = tuple(e.get("loc", ()))
            # FastAPI prefixes parameter errors with their source ("query", "path", "header").
            if loc and loc[0] in ("query", "path", "header", "cookie", "body"):
                e["loc"] = loc[1:]
        return from_validation_errors(errors).response(request.url.path)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        detail = exc.detail if isinstance(exc.detail, str) else _TITLES.get(exc.status_code, "")
        if exc.status_code == 404 and detail == "Not Found":
            detail = f"no resource at {request.url.path}"
        if exc.status_code == 405:
            detail = f"method {request.method} is not allowed on {request.url.path}"
        return Problem(exc.status_code, detail, headers=getattr(exc, "headers", None)).response(
            request.url.path)

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return Problem(500, "the server hit an unexpected error; it has been logged").response(
            request.url.path)
