"""Service settings: one frozen dataclass, filled from arguments and ``SOLITONDE_*`` variables.

The limits live here (and nowhere else) so that the OpenAPI document, the request checks and the
``serve`` command all state the same numbers.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from solitonde.instrument.errors import InstrumentError
from solitonde.instrument.tables.bundled import default_table

DEFAULT_STORE = Path(".solitonde") / "measurements.sqlite"
DEFAULT_TABLE = default_table()
"""The bundled table, found through the import system (package data of ``solitonde.data``), not
from the folder ``serve`` starts in."""

API_KEY_MIN = 16
"""Shortest API key accepted; a blank one would silently turn authentication off."""

# Environment variable -> settings field. Used by `build_app_from_env`, which is what uvicorn
# workers import: `serve` passes its options to them through these variables.
ENV_VARS: dict[str, str] = {
    "SOLITONDE_HOST": "host",
    "SOLITONDE_PORT": "port",
    "SOLITONDE_TABLE": "table_path",
    "SOLITONDE_MORE_TABLES": "table_paths",
    "SOLITONDE_STORE": "store_path",
    "SOLITONDE_API_KEY": "api_key",
    "SOLITONDE_MAX_BODY_BYTES": "max_body_bytes",
    "SOLITONDE_MAX_SHOTS": "max_shots_per_request",
    "SOLITONDE_MAX_SAMPLES": "max_samples_per_shot",
    "SOLITONDE_MAX_REQUEST_SAMPLES": "max_samples_per_request",
    "SOLITONDE_MAX_SIM_COST": "max_simulation_cost",
    "SOLITONDE_STORE_SYNC": "store_synchronous",
}


class SettingsError(InstrumentError, ValueError):
    """A setting with a value the service cannot run with; ``field`` names the setting."""


@dataclass(frozen=True)
class Settings:
    """Everything the service needs to start.

    Attributes
    ----------
    host, port:
        Where ``serve`` binds; loopback by default so nothing is exposed by accident.
    table_path:
        Model table (HDF5) for estimates; ``None`` or a missing file serves without estimates.
    table_paths:
        More tables (files or folders of ``*.h5``), one per plate family;
        ``SOLITONDE_MORE_TABLES`` lists them separated by the path separator (``:``).
    store_path:
        SQLite measurement store; its folder is created on start.
    api_key:
        When set, every ``/v1`` route needs it (``X-API-Key`` or ``Authorization: Bearer``).
    max_body_bytes:
        Largest request body accepted (413 above it).
    max_shots_per_request, max_samples_per_shot:
        Per-request limits (422 above them), stated in the OpenAPI schema.
    max_samples_per_request:
        All shots of a request together (64 MB as float64 by default); an uploaded file that
        declares more in its header is refused (413) before its data is read.
    max_simulation_cost:
        Budget for ``POST /v1/simulate`` in chain particle-steps (integration steps x particles;
        a meshed plate's dof-steps at its tier's weight: 4 for the 3-D spectral elements, 1.4
        for Mindlin, see ``Tier.dof_weight``); 5e8 is about 1.1-1.5 CPU seconds.
    store_synchronous:
        SQLite ``synchronous`` pragma. ``NORMAL`` (WAL) keeps every committed measurement when the
        process is killed; ``FULL`` also survives power loss at the cost of one fsync per write.
    """

    host: str = "127.0.0.1"
    port: int = 8000
    table_path: Path | None = None
    table_paths: tuple[Path, ...] = ()
    store_path: Path = field(default_factory=lambda: DEFAULT_STORE)
    api_key: str | None = None
    max_body_bytes: int = 64 * 1024 * 1024
    max_shots_per_request: int = 64
    max_samples_per_shot: int = 2_000_000
    max_samples_per_request: int = 8_000_000
    max_simulation_cost: float = 5e8
    store_synchronous: str = "NORMAL"
    page_size_max: int = 500
    export_rows_max: int = 200_000

    def __post_init__(self) -> None:
        positive = ("port", "max_body_bytes", "max_shots_per_request", "max_samples_per_shot",
                    "max_samples_per_request", "max_simulation_cost", "page_size_max",
                    "export_rows_max")
        for name in positive:
            if not getattr(self, name) > 0:
                raise SettingsError(name, f"must be positive, got {getattr(self, name)!r}")
        if self.port > 65535:
            raise SettingsError("port", f"must be 1..65535, got {self.port}")
        if self.store_synchronous.upper() not in ("NORMAL", "FULL"):
            raise SettingsError("store_synchronous",
                                f"must be NORMAL or FULL, got {self.store_synchronous!r}")
        if self.api_key is not None and len(self.api_key.strip()) < API_KEY_MIN:
            what = "blank" if not self.api_key.strip() else f"{len(self.api_key.strip())} " \
                "characters"
            raise SettingsError("api_key", f"SOLITONDE_API_KEY is {what}: a key of at least "
                                f"{API_KEY_MIN} characters, or unset it to serve on loopback "
                                "without one (a blank key would turn authentication off)")

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None, **overrides: Any) -> Settings:
        """Settings from ``SOLITONDE_*`` variables, then explicit ``overrides`` on top."""
        environ = os.environ if environ is None else environ
        types = {f.name: f.type for f in fields(cls)}
        values: dict[str, Any] = {}
        for var, name in ENV_VARS.items():
            raw = environ.get(var)
            # an empty key is refused, not taken as "no key": `SOLITONDE_API_KEY=$SECRET` with
            # the secret missing must not start a server without authentication
            if raw is None or (raw == "" and name != "api_key"):
                continue
            values[name] = _convert(name, str(types[name]), raw, var)
        values.update({k: v for k, v in overrides.items() if v is not None})
        for name in ("table_path", "store_path"):
            if name in values and values[name] is not None:
                values[name] = Path(values[name])
        return cls(**values)

    def to_env(self) -> dict[str, str]:
        """The inverse of :meth:`from_env`: variables that reproduce these settings."""
        env: dict[str, str] = {}
        for var, name in ENV_VARS.items():
            value = getattr(self, name)
            if isinstance(value, tuple):
                env[var] = os.pathsep.join(str(v) for v in value)
            elif value is not None:
                env[var] = str(value)
        return env

    def with_(self, **changes: Any) -> Settings:
        """A copy with some fields changed (validated again)."""
        return replace(self, **changes)

    def limits(self) -> dict[str, int | float]:
        """The request limits, as reported by ``GET /v1/table`` and the docs."""
        return {
            "max_body_bytes": self.max_body_bytes,
            "max_shots_per_request": self.max_shots_per_request,
            "max_samples_per_shot": self.max_samples_per_shot,
            "max_samples_per_request": self.max_samples_per_request,
            "max_simulation_cost": self.max_simulation_cost,
            "page_size_max": self.page_size_max,
            "export_rows_max": self.export_rows_max,
        }


def _convert(name: str, type_name: str, raw: str, var: str) -> Any:
    try:
        if "int" in type_name and "Path" not in type_name:
            return int(float(raw)) if "e" in raw.lower() else int(raw)
        if "float" in type_name:
            return float(raw)
        if "tuple" in type_name:
            return tuple(Path(p) for p in raw.split(os.pathsep) if p)
    except ValueError:
        raise SettingsError(name, f"{var}={raw!r} is not a number") from None
    return raw
