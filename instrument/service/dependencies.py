"""What a route asks FastAPI for (``Depends``): the running :class:`~.state.Service`, and a JSON
body's content type.

A route declares ``svc: ServiceDep`` and gets the service the lifespan made; while the service
is starting or stopping there is none, and the request is answered 503. Kept apart from the
routers so that each of them, and :mod:`.authentication`, takes the same dependency.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Request

from solitonde.instrument.service.problems import Problem
from solitonde.instrument.service.state import Service


def current_service(request: Request) -> Service:
    """The running service (the lifespan put it on the app); 503 while there is none."""
    svc = getattr(request.app.state, "service", None)
    if svc is None:
        raise Problem(503, "the service is starting or stopping; retry shortly")
    return svc


ServiceDep = Annotated[Service, Depends(current_service)]
"""A route's parameter ``svc: ServiceDep`` is the running service."""


def media_type(request: Request) -> str:
    """The request's declared content type, without parameters, lower case."""
    return request.headers.get("content-type", "").split(";")[0].strip().lower()


def require_json(request: Request) -> None:
    """415 unless the body is declared ``application/json``."""
    media = media_type(request)
    if media != "application/json":
        raise Problem(415, f"content-type: {media or 'none'} is not accepted here "
                      "(allowed: application/json)", kind="unsupported-media-type",
                      field="content-type")
