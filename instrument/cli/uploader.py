"""The acquisition PC's side of the REST service: upload waveform files, idempotently.

`solitonde post` and `solitonde watch` send each file as the web page and ``curl -F`` do: a
multipart ``POST /v1/measurements`` with the file and its metadata fields. Every request carries
an ``Idempotency-Key`` made from the file's content, its name and the fields sent with it, so the
same file with the same metadata always has the same key: a retry after a lost answer, a second
``post``, or ``watch`` restarted after a crash gets the stored measurement back (the server's
``Idempotent-Replayed`` answer) and never stores it twice.

Only httpx and the standard library are used here: this module is what runs beside the scope.
"""

from __future__ import annotations

import fnmatch
import hashlib
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

import httpx

from solitonde.instrument.errors import MessageError

if TYPE_CHECKING:
    from solitonde.instrument.inference.pipeline import TableEstimateDict
    from solitonde.instrument.service.measurement_json import (
        MeasurementJSON,
        MetadataDifference,
    )

FIELD_FLAGS: dict[str, str] = {
    "plate_id": "--plate-id", "position": "--position", "x_m": "--x", "y_m": "--y",
    "sphere_diameter": "--sphere-diameter", "calibration": "--calibration", "units": "--units",
    "sample_rate": "--sample-rate", "format": "--format", "channel": "--channel",
    "group": "--group", "plate_material": "--plate-material", "table": "--table",
    "setup": "--setup",
}
"""The upload's form fields (the service's names) and the command-line flag that sets each."""

KEY_PREFIX = "solitonde-file-"
TRANSIENT_STATUS = frozenset({408, 425, 429, 500, 502, 503, 504, 507})
"""Answers that say "not now" (overload, a restart, a full disk): the same request is retried;
any other 4xx is the request's own fault and retrying it cannot help."""


def field_text(value: Any) -> str:
    """A form field's text: numbers in Python's shortest round-trip form, so a key made from
    ``--x 0.1`` is the same on every machine."""
    if isinstance(value, float):
        return repr(value)
    return str(value)


def idempotency_key(content: bytes, filename: str, fields: Mapping[str, Any]) -> str:
    """The key of one upload: SHA-256 over the file's bytes, its name and the sorted fields,
    each part length-prefixed (no two splits hash alike)."""
    h = hashlib.sha256()
    parts = [content, filename.encode()]
    parts += [f"{k}={field_text(v)}".encode() for k, v in sorted(fields.items())]
    for part in parts:
        h.update(len(part).to_bytes(8, "little"))
        h.update(part)
    return KEY_PREFIX + h.hexdigest()


class UploadLine(TypedDict):
    """One upload as ``post --json`` prints it (the stored measurement's parts, None where the
    server answered none)."""

    source: str
    state: str
    id: int | None
    status_code: int | None
    idempotency_key: str
    plate_id: str | None
    position: str | None
    n_shots: int | None
    estimate: TableEstimateDict | None
    estimate_reason: str | None
    error: str | None
    duplicate_of: int | None
    metadata_differences: list[MetadataDifference] | None


@dataclass
class Outcome:
    """What became of one upload.

    ``state`` is ``stored`` (201, new), ``replayed`` (201, the server had it: the same id as the
    first time), ``duplicate`` (200: the server holds these shots' samples already, as the
    measurement it names; what the metadata says otherwise is listed), ``refused`` (a 4xx the
    request itself caused: not retried) or ``unreachable`` (no answer, or a transient status:
    try again later).
    """

    source: str
    state: str
    key: str
    status_code: int | None = None
    measurement: MeasurementJSON | None = None
    """The server's answer: the measurement stored (or the one it duplicates)."""
    error: str | None = None

    @property
    def ok(self) -> bool:
        return self.state in ("stored", "replayed", "duplicate")

    @property
    def transient(self) -> bool:
        return self.state == "unreachable"

    def to_dict(self) -> UploadLine:
        m: Mapping[str, Any] = self.measurement or {}
        return {"source": self.source, "state": self.state, "id": m.get("id"),
                "status_code": self.status_code, "idempotency_key": self.key,
                "plate_id": m.get("plate_id"), "position": m.get("position"),
                "n_shots": m.get("n_shots"), "estimate": m.get("estimate"),
                "estimate_reason": m.get("estimate_reason"), "error": self.error,
                "duplicate_of": m.get("duplicate_of"),
                "metadata_differences": m.get("metadata_differences")}


@dataclass
class Client:
    """Uploads files to one server; ``api_key`` goes out as ``X-API-Key``."""

    server: str
    api_key: str | None = None
    timeout_s: float = 120.0
    _http: httpx.Client | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self.server = self.server.rstrip("/")
        headers = {"X-API-Key": self.api_key} if self.api_key else {}
        self._http = httpx.Client(base_url=self.server, headers=headers,
                                  timeout=httpx.Timeout(self.timeout_s, connect=10.0))

    def close(self) -> None:
        if self._http is not None:
            self._http.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def upload(self, path: Path, fields: Mapping[str, Any],
               key: str | None = None, content: bytes | None = None) -> Outcome:
        """POST ``path`` with ``fields``; never raises for what the network or server does."""
        assert self._http is not None
        try:
            data = path.read_bytes() if content is None else content
        except OSError as exc:
            return Outcome(str(path), "refused", key or "", error=f"cannot read {path}: "
                           f"{exc.strerror or exc}")
        key = key or idempotency_key(data, path.name, fields)
        form = {k: field_text(v) for k, v in fields.items()}
        try:
            r = self._http.post("/v1/measurements", data=form,
                                files={"file": (path.name, data, "application/octet-stream")},
                                headers={"Idempotency-Key": key})
        except httpx.HTTPError as exc:
            return Outcome(str(path), "unreachable", key,
                           error=f"{self.server}: {type(exc).__name__}: {exc}")
        if r.status_code == 201:
            replayed = r.headers.get("idempotent-replayed", "").lower() == "true"
            return Outcome(str(path), "replayed" if replayed else "stored", key, 201, r.json())
        if r.status_code == 200 and r.json().get("duplicate_of") is not None:
            return Outcome(str(path), "duplicate", key, 200, r.json())
        return Outcome(str(path), "unreachable" if r.status_code in TRANSIENT_STATUS
                       else "refused", key, r.status_code, error=_problem_text(r))


def _problem_text(r: httpx.Response) -> str:
    """The server's problem+json ``detail`` (or the body's start), with the status."""
    try:
        body = r.json()
        detail = body.get("detail") if isinstance(body, dict) else None
    except ValueError:
        detail = None
    if not isinstance(detail, str):
        detail = r.text[:300].strip() or r.reason_phrase
    return f"{r.status_code}: {detail}"


class ServerError(MessageError):
    """A server that cannot be reached, or that refused a request; the message says which
    (the server's problem detail with its status)."""

    subject = "--server"


def call(server: str, api_key_env: str, method: str, path: str, body: Any = None,
         timeout_s: float = 300.0) -> httpx.Response:
    """One request to ``server`` with the key in ``$api_key_env`` (a JSON ``body`` if given);
    ServerError for an unreachable server or a status of 400 and up."""
    key = api_key_from(api_key_env)
    try:
        r = httpx.request(method, server.rstrip("/") + path, json=body, timeout=timeout_s,
                          headers={"X-API-Key": key} if key else {})
    except httpx.HTTPError as exc:
        raise ServerError(f"{server}: {type(exc).__name__}: {exc}") from None
    if r.status_code >= 400:
        raise ServerError(_problem_text(r))
    return r


def api_key_from(env_var: str) -> str | None:
    """The key in ``$env_var`` (blank counts as none)."""
    value = os.environ.get(env_var, "").strip()
    return value or None


def manifest_row_for(rows: list[Any], base: Path, path: Path) -> Any | None:
    """The manifest row whose file name or glob (relative to ``base``) matches ``path``, else
    None; for files that appear after the manifest was read (``watch``)."""
    target = path.resolve()
    for row in rows:
        pattern = Path(row.pattern)
        full = pattern if pattern.is_absolute() else base.resolve() / pattern
        if fnmatch.fnmatchcase(str(target), str(full)):
            return row
    return None


def fields_for(given: Mapping[str, Any], row: Any | None) -> dict[str, Any]:
    """The form fields of one file: the command line's, and its manifest row's metadata and
    calibration; a value both state differently is a ValueError naming the flag and the row."""
    out = {k: v for k, v in given.items() if v is not None}
    if row is None:
        return out
    stated = dict(row.metadata)
    if row.calibration is not None:
        stated["calibration"] = row.calibration
    for key, value in stated.items():
        if key in out and not _same(out[key], value):
            raise ValueError(f"{FIELD_FLAGS.get(key, key)} says {out[key]!r}, --manifest "
                             f"{row.where} says {value!r}; give one, or make them agree")
        out[key] = value
    return out


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, int | float) and isinstance(b, int | float):
        return math.isclose(float(a), float(b), rel_tol=1e-9, abs_tol=1e-12)
    return str(a).strip() == str(b).strip()


def _mm(value: Any) -> str:
    return "?" if not isinstance(value, int | float) else f"{value * 1e3:.3g}"


def estimate_text(measurement: Mapping[str, Any] | None) -> str:
    """The stored estimate in a few words (thickness and distance, 95 % intervals)."""
    if not measurement:
        return ""
    est = measurement.get("estimate")
    if not est:
        reason = measurement.get("estimate_reason")
        return f"no estimate ({reason})" if reason else "no estimate"
    parts = []
    for key, name in (("thickness_m", "thickness"), ("distance_m", "distance")):
        p = est.get(key)
        if not isinstance(p, Mapping):
            continue
        status, ci = p.get("status"), p.get("ci95") or [None, None]
        if status == "constrained":
            parts.append(f"{name} {_mm(p.get('median'))} mm (95 % {_mm(ci[0])}..{_mm(ci[1])})")
        elif status == "lower_bound_only":
            parts.append(f"{name} >= {_mm(ci[0])} mm")
        elif status == "upper_bound_only":
            parts.append(f"{name} <= {_mm(ci[1])} mm")
        else:
            parts.append(f"{name} {status}")
    return ", ".join(parts)


def status_line(outcome: Outcome) -> str:
    """One line per file for the console and the log."""
    m: Mapping[str, Any] = outcome.measurement or {}
    if outcome.ok:
        where = "/".join(str(m[k]) for k in ("plate_id", "position") if m.get(k) is not None)
        text = (f"{outcome.state}: {outcome.source} -> measurement {m.get('id')}"
                f" ({m.get('n_shots')} shot{'s' if m.get('n_shots') != 1 else ''}"
                f"{', ' + where if where else ''})")
        if outcome.state == "duplicate":
            text += " (these shots were stored already; not stored again" + "".join(
                f"; shot {d['shot']} {d['key']}: stored {d['stored']!r}, sent {d['sent']!r}"
                for d in m.get("metadata_differences") or []) + ")"
        est = estimate_text(m)
        return f"{text}: {est}" if est else text
    return f"{'failed' if outcome.state == 'refused' else 'not sent'}: {outcome.source}: " \
           f"{outcome.error}"
