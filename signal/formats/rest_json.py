"""JSON: the REST service's shot ``{"t0", "dt", "samples", "units", "calibration", "metadata"}``
(``metadata`` holding ``plate_id``, ``position``, ``sphere_diameter``, ``shot`` and ``extra``; a
flat metadata object is read too), a list of them, or ``{"shots": [...]}``."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from ..errors import WaveformError
from ..waveform import Waveform
from .base import FileFormat
from .reading import (
    COMMON_OPTIONS,
    as_waveforms,
    decode_value,
    float_array,
    identifiers_as_text,
    prefixed,
    resolve_units,
    sample_period,
    stated_period,
)


def from_json(
    body: Any, sample_rate: float | None = None, dt: float | None = None,
    t0: float | None = None, units: str | None = None, calibration: float | None = None,
) -> list[Waveform]:
    """Shots from the REST service's JSON shape (a shot object, a list, or ``{"shots": [...]}``).

    Metadata is the service's (``plate_id``, ``position``, ``sphere_diameter``, ``shot`` and
    free-form ``extra``, merged into one mapping as the service does) or a flat mapping. The
    options mean what they mean for files (see :mod:`solitonde.signal.io`).
    """
    if isinstance(body, Mapping) and "shots" in body:
        shots = body["shots"]
        common = _flat_metadata(body.get("metadata"), "metadata")
        if not isinstance(shots, list):
            raise WaveformError("shots", "must be a list of shot objects")
    elif isinstance(body, list):
        shots, common = body, {}
    elif isinstance(body, Mapping):
        shots, common = [body], {}
    else:
        raise WaveformError("body", f"expected an object or a list, got {type(body).__name__}")
    parts = []
    for i, shot in enumerate(shots):
        where = f"shots[{i}]"
        if not isinstance(shot, Mapping):
            raise WaveformError(where, "must be an object with t0, dt, samples")
        if "samples" not in shot:
            raise WaveformError(f"{where}.samples", "missing", "a list of numbers")
        try:
            own = stated_period(shot.get("dt"), shot.get("sample_rate"))
            if own is None and sample_rate is None and dt is None:
                raise WaveformError("dt", "missing (no dt nor sample_rate)", "dt in s > 0")
            step = sample_period(own, sample_rate, dt, where)
            meta = {**common, **_flat_metadata(shot.get("metadata"), "metadata")}
            parts.append((shot.get("t0", 0.0) if t0 is None else t0, step,
                          float_array(shot["samples"], "samples"),
                          resolve_units(shot.get("units"), units, where), shot.get("calibration"),
                          identifiers_as_text(meta)))
        except WaveformError as exc:
            raise prefixed(exc, where) from None
        except (TypeError, ValueError) as exc:
            raise WaveformError(where, f"not a valid shot ({exc})") from None
    return as_waveforms(parts, calibration, "body", prefix="shots")


def _flat_metadata(metadata: Any, where: str) -> dict[str, Any]:
    """The service's metadata (schema keys plus ``extra``) or a flat mapping, as one mapping."""
    if metadata is None:
        return {}
    if not isinstance(metadata, Mapping):
        raise WaveformError(where, f"must be an object, got {type(metadata).__name__}")
    flat = {k: v for k, v in metadata.items() if k != "extra"}
    extra = metadata.get("extra") or {}
    if not isinstance(extra, Mapping):
        raise WaveformError(f"{where}.extra", "must be an object of key/value pairs")
    flat.update({str(k): decode_value(v, str(k)) for k, v in extra.items()})
    return flat


def to_json(waves: Sequence[Waveform]) -> dict[str, Any]:
    """The ``{"shots": [...]}`` JSON shape of :func:`from_json`."""
    return {"shots": [w.to_dict() for w in waves]}


def read_json(path: Path, **options: Any) -> list[Waveform]:
    try:
        body = json.loads(path.read_bytes().decode("utf-8-sig"))
    except ValueError as exc:  # UnicodeDecodeError and JSONDecodeError are ValueErrors
        raise WaveformError("file", f"{path.name}: not valid UTF-8 JSON ({exc})") from None
    return from_json(body, **options)


def write_json(path: Path, waves: list[Waveform]) -> None:
    path.write_text(json.dumps(to_json(waves)), encoding="utf-8")


FORMAT = FileFormat("json", (".json",), COMMON_OPTIONS, read_json, write_json)
