"""The software's version, looked up in one place: what provenance, the service, the command
line and the compiled kernels' cache record."""

from __future__ import annotations

from importlib import metadata

UNKNOWN = "0+unknown"
"""The version of a source tree that was never installed."""


def package_version() -> str:
    """The installed distribution's version (:data:`UNKNOWN` when not installed)."""
    try:
        return metadata.version("solitonde")
    except metadata.PackageNotFoundError:
        return UNKNOWN
