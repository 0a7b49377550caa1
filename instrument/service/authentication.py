"""API-key authentication of every ``/v1`` route: :data:`AUTH`, the routers' dependency.

With ``SOLITONDE_API_KEY`` set, a request must carry the key in ``X-API-Key`` or
``Authorization: Bearer``; without it the service is open. A client that fails too often is
refused for a while (:class:`FailedKeys`), so a key is not guessed at request speed. The
OpenAPI document declares both ways (:data:`SECURITY_SCHEMES`).
"""

from __future__ import annotations

import hmac
import logging
import math
import threading
import time

from fastapi import Depends, Request

from solitonde.instrument.service.dependencies import ServiceDep
from solitonde.instrument.service.problems import Problem

log = logging.getLogger("solitonde.instrument")

SECURITY_SCHEMES = {
    "APIKeyHeader": {"type": "apiKey", "in": "header", "name": "X-API-Key",
                     "description": "the server's SOLITONDE_API_KEY (when it has one)"},
    "HTTPBearer": {"type": "http", "scheme": "bearer",
                   "description": "the server's SOLITONDE_API_KEY (when it has one)"},
}
"""Declared in the OpenAPI document by the app factory; checked by :func:`require_key`."""


class FailedKeys:
    """Failed API key attempts per client address, in this worker process: after
    :attr:`LIMIT` within :attr:`WINDOW_S` seconds a client gets 429 until the window passes
    (a key is not guessed at request speed), and a warning is logged at most once per
    :attr:`LOG_EVERY_S` per client, with the count (a flood does not flood the log)."""

    LIMIT = 10
    WINDOW_S = 60.0
    LOG_EVERY_S = 10.0
    CLIENTS_MAX = 10_000

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._seen: dict[str, list[float]] = {}
        self._logged: dict[str, float] = {}

    def _recent(self, client: str, now: float) -> list[float]:
        times = [t for t in self._seen.get(client, []) if now - t < self.WINDOW_S]
        if times:
            self._seen[client] = times
        else:
            self._seen.pop(client, None)
        return times

    def blocked_for(self, client: str) -> float:
        """Seconds until ``client`` may try again (0: now)."""
        now = time.monotonic()
        with self._lock:
            times = self._recent(client, now)
            return self.WINDOW_S - (now - times[0]) if len(times) >= self.LIMIT else 0.0

    def failed(self, client: str) -> None:
        now = time.monotonic()
        with self._lock:
            if len(self._seen) >= self.CLIENTS_MAX and client not in self._seen:
                self._seen.clear()  # bounded memory under a spray of addresses
                self._logged.clear()
            times = self._recent(client, now)
            times.append(now)
            self._seen[client] = times
            if now - self._logged.get(client, -math.inf) >= self.LOG_EVERY_S:
                self._logged[client] = now
                log.warning("api key: %d failed attempt(s) from %s in the last %.0f s",
                            len(times), client, self.WINDOW_S)


FAILED_KEYS = FailedKeys()


async def require_key(request: Request, svc: ServiceDep) -> None:
    """With SOLITONDE_API_KEY set, the request must carry it (header or bearer token); a client
    that failed too often is refused for a while (:class:`FailedKeys`).

    Reads the two headers itself (one dependency instead of FastAPI's two security classes: this
    runs on every request).
    """

    expected = svc.settings.api_key
    if expected is None:
        return
    client = request.client.host if request.client else "unknown"
    wait = FAILED_KEYS.blocked_for(client)
    if wait > 0:
        raise Problem(429, f"api_key: too many failed attempts from {client}; try again in "
                      f"{math.ceil(wait)} s", kind="too-many-requests", field="api_key",
                      headers={"Retry-After": str(math.ceil(wait))})
    given = request.headers.get("x-api-key")
    if given is None:
        scheme, _, token = request.headers.get("authorization", "").partition(" ")
        given = token.strip() if scheme.lower() == "bearer" and token.strip() else None
    if given is None:  # not counted: a client that does not know a key is needed is no guesser
        raise Problem(401, "api_key: this server needs an API key (X-API-Key header or "
                      "Authorization: Bearer)", kind="unauthorized", field="api_key",
                      headers={"WWW-Authenticate": 'Bearer realm="solitonde"'})
    if not hmac.compare_digest(given.encode(), expected.encode()):
        FAILED_KEYS.failed(client)
        raise Problem(401, "api_key: the key given is not this server's key",
                      kind="unauthorized", field="api_key",
                      headers={"WWW-Authenticate": 'Bearer realm="solitonde"'})


AUTH = Depends(require_key)
"""The dependency every ``/v1`` router declares."""
