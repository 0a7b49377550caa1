"""Heavy work (plots, file parsing, simulations) in lanes that skip clients who have gone.

A request for a plot or an upload can wait in its lane behind others. When a client gives up
meanwhile (a time-out, a closed browser tab), the work it asked for is of no use to anyone: the
answer has nowhere to go. :func:`run_for_client` checks, when the job's turn comes, whether the
client is still connected, and drops the job if not, so abandoned requests do not pile up CPU
time in front of live ones. A job that has started runs to its end (a worker thread cannot be
stopped from outside); each one is bounded in size (plots are decimated to a fixed number of
points, metadata is limited, files are checked against the size limits before they are read).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any, TypeVar

import anyio
from starlette.requests import Request
from starlette.responses import Response

from solitonde.instrument.errors import MessageError

log = logging.getLogger("solitonde.instrument")

T = TypeVar("T")

CLIENT_CLOSED = 499
"""Status logged for a request whose client left before its turn (nginx's convention); the
client never sees it."""


class ClientGone(MessageError):
    """The client disconnected before its job started; nothing was done."""

    subject = "request"

    def __init__(self, message: str = "the client disconnected before its job started") -> None:
        super().__init__(message)


async def run_for_client(request: Request, limiter: anyio.CapacityLimiter,
                         fn: Callable[..., T], *args: Any) -> T:
    """``fn(*args)`` in a worker thread once ``limiter`` has room, unless the client has gone
    by then (raises :class:`ClientGone`)."""
    async with limiter:
        if await request.is_disconnected():
            log.info("%s %s: the client left before its turn; skipped", request.method,
                     request.url.path)
            raise ClientGone
        return await anyio.to_thread.run_sync(fn, *args)


def gone_response() -> Response:
    """What a route returns for a gone client (never read by it)."""
    return Response(status_code=CLIENT_CLOSED)
