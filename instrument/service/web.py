"""The instrument's web page: ``GET /`` and its script and style, from this package.

No build step and nothing fetched from elsewhere: three files in ``webpage/`` beside this module
call the same REST API any client uses (plates, a plate's measurements, a shot's plot, the map).
With ``SOLITONDE_API_KEY`` set the page asks for the key once and sends it as ``X-API-Key``.
"""

from __future__ import annotations

from importlib import resources

from fastapi import APIRouter
from fastapi.responses import Response

router = APIRouter(include_in_schema=False)
_FILES = {"index.html": "text/html; charset=utf-8", "app.js": "text/javascript; charset=utf-8",
          "style.css": "text/css; charset=utf-8",
          "favicon.svg": "image/svg+xml"}
_HEADERS = {"Cache-Control": "no-cache", "X-Content-Type-Options": "nosniff",
            "Content-Security-Policy": "default-src 'self'; img-src 'self' blob:; "
                                       "style-src 'self'; script-src 'self'"}


def _read(name: str) -> bytes:
    return resources.files("solitonde.instrument.service").joinpath("webpage", name).read_bytes()


@router.get("/")
async def index() -> Response:
    return Response(_read("index.html"), media_type=_FILES["index.html"], headers=_HEADERS)


@router.get("/static/{name}")
async def static(name: str) -> Response:
    if name not in _FILES or name == "index.html":
        return Response(b"not found", status_code=404, media_type="text/plain")
    return Response(_read(name), media_type=_FILES[name], headers=_HEADERS)
