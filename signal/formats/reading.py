"""What every waveform reader shares: metadata decoding, units, the sample period, and the
step from ``(t0, dt, samples, units, calibration, metadata)`` parts to :class:`Waveform` shots.

The rules are the ones :mod:`solitonde.signal.io` documents for every format: a file's own time
axis wins and an option must agree with it, a file's stated units win and an option must not
contradict them, ``calibration=`` converts volts only, identifiers stay text.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

import numpy as np

from ..errors import OptionNeeded, WaveformError
from ..waveform import UNIFORM_TOLERANCE, UNITS, Waveform, uniform_grid

COMMON_OPTIONS = ("sample_rate", "dt", "t0", "units", "calibration")
"""The options every reader takes (see :mod:`solitonde.signal.io`)."""
Part = tuple[float, float, Any, str, Any, dict[str, Any]]
"""One shot before it is a Waveform: (t0, dt, samples, units, own calibration, metadata)."""

IDENTIFIERS = ("plate_id", "position")
"""Metadata that label things: kept as text, never read as numbers (``007`` is not 7)."""
NUMERIC_METADATA = ("t0", "dt", "sample_rate", "calibration", "wf_increment", "wf_start_offset")
"""Metadata the reader needs as numbers; a file holding anything else there is refused."""
UNIT_NAMES = {"n": "N", "newton": "N", "newtons": "N", "v": "V", "volt": "V", "volts": "V"}
"""Unit spellings found in files (TDMS ``unit_string``, attributes), case-insensitive."""


def identifiers_as_text(meta: Mapping[str, Any]) -> dict[str, Any]:
    """``plate_id`` and ``position`` as text (a file may store them as numbers)."""
    out = dict(meta)
    for key in IDENTIFIERS:
        if out.get(key) is not None and not isinstance(out[key], str):
            out[key] = str(out[key])
    return out


def decode_value(value: Any, key: str | None = None) -> Any:
    """Metadata value ``key`` from a file as Python: bytes to str, numpy to Python.

    Identifiers stay text; the keys the reader needs as numbers must be one number;
    ``sphere_diameter`` text becomes a number when it is one; other text is decoded only when it
    is a JSON object, list, boolean or null (``# scene: {...}``), so labels keep their digits.
    """
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, bytes):
        value = value.decode("utf-8", "replace")
    if key in IDENTIFIERS or key == "shot":
        return value.strip() if isinstance(value, str) else value
    if key in ("sphere_diameter", "x_m", "y_m") and isinstance(value, str):
        try:  # a number when it is one; anything else is left for the consumer to name
            return float(value)
        except ValueError:
            return value
    if key in NUMERIC_METADATA:
        if isinstance(value, bool) or not isinstance(value, str | int | float):
            raise WaveformError(key, f"expected one number, got {value!r}")
        try:
            return float(value)
        except ValueError:
            raise WaveformError(key, f"expected a number, got {value!r}") from None
    if isinstance(value, str):
        text = value.strip()
        if text[:1] in "{[" or text in ("true", "false", "null"):
            try:
                return json.loads(text)
            except ValueError:
                return value
    return value


def resolve_units(stated: Any, option: str | None, where: str) -> str:
    """Units of the data: the file's (``stated``, any spelling in :data:`UNIT_NAMES`), else the
    ``units=`` option, else N; an option contradicting the file is an error."""
    if option is not None and option not in UNITS:
        raise WaveformError("units", f"unknown units {option!r}", "'N' or 'V'")
    if stated is None or (isinstance(stated, str) and not stated.strip()):
        return option or "N"
    unit = UNIT_NAMES.get(str(stated).strip().lower())
    if unit is None:
        raise WaveformError("units", f"{where}: unknown units {stated!r}",
                            "N (Newtons) or V (Volts)")
    if option is not None and option != unit:
        raise WaveformError("units", f"{where}: the file says its data are in {unit}, not "
                            f"{option}", f"units='{unit}' or no units= option")
    return unit


def positive(name: str, value: Any) -> float:
    number = float(value)
    if not np.isfinite(number) or number <= 0:
        raise WaveformError(name, f"must be positive and finite, got {value!r}",
                            "Hz > 0" if name == "sample_rate" else "s > 0")
    return number


def stated_period(dt: Any, sample_rate: Any) -> float | None:
    """The sample period a file states (``dt`` or ``sample_rate``), or None."""
    if dt is not None:
        return positive("dt", dt)
    if sample_rate is not None:
        return 1.0 / positive("sample_rate", sample_rate)
    return None


def sample_period(own: float | None, sample_rate: float | None, dt: float | None, where: str,
          hint: str = "sample_rate= in Hz (or dt= in s)") -> float:
    """The sample period: the file's own (an option must agree with it), else the option's."""
    given = stated_period(dt, sample_rate)
    if own is None:
        if given is None:
            raise OptionNeeded("sample_rate", f"{where} has no time axis; give the sample rate",
                               hint)
        return given
    if given is not None and abs(given - own) > UNIFORM_TOLERANCE * own:
        name = "dt" if dt is not None else "sample_rate"
        raise WaveformError(
            name, f"{where} has its own time axis (dt = {own:.6g} s, {1 / own:.6g} Hz); "
            f"{name}= says dt = {given:.6g} s ({1 / given:.6g} Hz)",
            "the file's own rate, or no option",
        )
    return own


def as_waveforms(parts: list[Part],
           calibration: float | None, where: str, prefix: str | None = None) -> list[Waveform]:
    """Waveforms from ``(t0, dt, samples, units, own calibration, metadata)`` tuples.

    ``calibration=`` applies to the shots in volts (over their own); a file with none in volts
    refuses it, and a shot in volts with no calibration at all raises :class:`OptionNeeded`.
    With ``prefix``, a shot's error names ``prefix[i].field``.
    """
    if calibration is not None and not any(p[3] == "V" for p in parts):
        raise WaveformError("calibration", f"{where}: the data are in newtons; a calibration "
                            "(N/V) converts volts only", "no calibration for data in N")
    out = []
    for i, (t0, dt, samples, units, own_cal, meta) in enumerate(parts):
        cal = calibration if calibration is not None and units == "V" else own_cal
        try:
            if units == "V" and cal is None:
                raise OptionNeeded("calibration", f"{where}: samples are in volts but no "
                                   "calibration was given", "calibration= sensor sensitivity "
                                   "in N/V")
            out.append(Waveform(t0, dt, samples, units, cal, meta))
        except WaveformError as exc:
            if prefix is None:
                raise
            raise prefixed(exc, f"{prefix}[{i}]") from None
    return out


def float_array(data: Any, name: str) -> np.ndarray:
    """Real numeric data as float64; text, objects and complex numbers are refused."""
    array = np.asarray(data)
    if array.dtype.kind not in "biuf":
        raise WaveformError(name, f"not real numbers (dtype {array.dtype})", "integer or float")
    return array.astype(np.float64)


def is_time_axis(column: np.ndarray) -> bool:
    try:
        uniform_grid(column)
    except WaveformError:
        return False
    return True


def shot_rows(array: np.ndarray, name: str) -> list[np.ndarray]:
    if array.ndim == 1:
        return [array]
    if array.ndim == 2:
        return list(array)
    raise WaveformError(name, f"expected 1-D or 2-D data, got shape {array.shape}")


def prefixed(exc: WaveformError, where: str) -> WaveformError:
    field = f"{where}.{exc.field}"
    if isinstance(exc, OptionNeeded):
        return OptionNeeded(exc.option, exc.message, exc.allowed, field=field)
    return WaveformError(field, exc.message, exc.allowed)

