"""Estimates as flat table rows: one row per plate and position, for CSV and Parquet.

`analyze --estimates-out` and the service's ``/v1/measurements/export?kind=estimates`` write the
same columns, so a script reads either. Every interval bound is its own column
(``thickness_m_ci95_low``); a side the data leave open is empty, and ``*_status`` says why.
``fit_chi2``, ``fit_dof``, ``fit_p_value`` are the estimate's fit; ``warnings`` its warnings,
joined by "; ". What the estimate was made from follows, so that a plate's scan can be inverted
jointly from the file (`solitonde map --joint`): ``table`` (the model table's id),
``size_summaries`` (JSON: per sphere size ``diameter_m``, ``tof_s``, ``tof_std_s``, ``arr``,
``arr_std``, ``n_shots``, ``arr_upper_bound``, ``tof_window_s``, as the inversion read them),
``calibration`` and ``material_spread`` (JSON, empty when none). ``other_reading`` (JSON,
empty when none) is a thickness the data fit as well beyond the interval, next to a support
(instrument.inference.inversion); ``readings`` (JSON, empty when none) an ``ambiguous`` answer's
readings, each ``thickness_m``, ``distance_m`` (summaries as above) and ``weight``.
"""

from __future__ import annotations

import io
import json
import math
from collections.abc import Iterable, Mapping, Sequence
from datetime import UTC, datetime
from typing import Any, TypedDict, cast

from solitonde.signal.json_ready import json_ready

PARAMETERS = ("thickness_m", "distance_m")
STATS = ("map", "median", "ci68_low", "ci68_high", "ci95_low", "ci95_high", "status")
LOCATION_COLUMNS = ("plate_id", "position", "x_m", "y_m", "sphere_diameters_m", "n_shots")
ESTIMATE_COLUMNS = (*LOCATION_COLUMNS, *(f"{p}_{s}" for p in PARAMETERS for s in STATS),
                    "reason", "fit_chi2", "fit_dof", "fit_p_value", "warnings", "table",
                    "size_summaries", "calibration", "material_spread", "other_reading",
                    "readings")
"""The columns of an estimates file, in order."""


class ParameterColumns(TypedDict):
    """One estimate's ``thickness_m_*`` and ``distance_m_*`` columns (:data:`STATS`)."""

    thickness_m_map: float | None
    thickness_m_median: float | None
    thickness_m_ci68_low: float | None
    thickness_m_ci68_high: float | None
    thickness_m_ci95_low: float | None
    thickness_m_ci95_high: float | None
    thickness_m_status: str | None
    distance_m_map: float | None
    distance_m_median: float | None
    distance_m_ci68_low: float | None
    distance_m_ci68_high: float | None
    distance_m_ci95_low: float | None
    distance_m_ci95_high: float | None
    distance_m_status: str | None


class EstimateRow(ParameterColumns):
    """A row of an estimates file (:data:`ESTIMATE_COLUMNS`, in that order): where, from
    what, the parameters' columns, then the reason, fit and warnings and, as JSON text, what
    the estimate was made from."""

    plate_id: str | None
    position: str | None
    x_m: float | None
    y_m: float | None
    sphere_diameters_m: str | None
    n_shots: int
    reason: str | None
    fit_chi2: float | None
    fit_dof: float | None
    fit_p_value: float | None
    warnings: str | None
    table: str | None
    size_summaries: str | None
    calibration: str | None
    material_spread: str | None
    other_reading: str | None
    readings: str | None


def iso_utc(epoch_s: float | None) -> str | None:
    """Seconds since the epoch as ISO 8601 UTC (``2026-11-25T02:58:41.123Z``)."""
    if epoch_s is None:
        return None
    stamp = datetime.fromtimestamp(float(epoch_s), tz=UTC)
    return stamp.isoformat(timespec="milliseconds").replace("+00:00", "Z")


def _finite(value: Any) -> float | None:
    if value is None:
        return None
    number = float(value)
    return number if math.isfinite(number) else None


def parameter_columns(estimate: Mapping[str, Any] | None) -> ParameterColumns:
    """The ``thickness_m_*`` and ``distance_m_*`` columns of one estimate (its ``to_dict``)."""
    out: dict[str, float | str | None] = {}
    for name in PARAMETERS:
        p = (estimate or {}).get(name) or {}
        ci68, ci95 = p.get("ci68") or (None, None), p.get("ci95") or (None, None)
        status = p.get("status")
        values = {"map": p.get("map"), "median": p.get("median"), "ci68_low": ci68[0],
                  "ci68_high": ci68[1], "ci95_low": ci95[0], "ci95_high": ci95[1]}
        if status == "lower_bound_only":  # the inversion reports the open side as the grid's
            values.update(ci68_high=None, ci95_high=None)  # edge; the file leaves it empty
        elif status == "upper_bound_only":
            values.update(ci68_low=None, ci95_low=None)
        for stat, value in values.items():
            out[f"{name}_{stat}"] = _finite(value)
        out[f"{name}_status"] = status
    return cast(ParameterColumns, out)


def estimate_row(location: Mapping[str, Any], diameters: Sequence[float], n_shots: int,
                 estimate: Mapping[str, Any] | None, reason: str | None) -> EstimateRow:
    """One row: where (plate, position, coordinates), from what (sphere sizes, shots), the
    estimate's columns, and ``reason`` when there is no estimate or it comes with one."""
    given: Mapping[str, Any] = estimate or {}
    fit = given.get("fit") or {}
    return {
        "plate_id": location.get("plate_id"), "position": location.get("position"),
        "x_m": _finite(location.get("x_m")), "y_m": _finite(location.get("y_m")),
        "sphere_diameters_m": ";".join(f"{d:.6g}" for d in sorted(set(diameters))) or None,
        "n_shots": int(n_shots),
        **parameter_columns(estimate),
        "reason": reason if reason else given.get("reason"),
        "fit_chi2": _finite(fit.get("chi2")), "fit_dof": _finite(fit.get("dof")),
        "fit_p_value": _finite(fit.get("p_value")),
        "warnings": "; ".join(given.get("warnings") or []) or None,
        "table": given.get("table"),
        "size_summaries": _json_text(given.get("inputs")),
        "calibration": _json_text(given.get("calibration")),
        "material_spread": _json_text(given.get("material_spread")),
        "other_reading": _json_text(given.get("other_reading")),
        "readings": _json_text(given.get("readings")),
    }


def _json_text(value: Any) -> str | None:
    """A part of the estimate as one cell of JSON text, or None where it is empty."""
    return json.dumps(json_ready(value), allow_nan=False) if value else None


FORMULA_STARTS = ("=", "+", "-", "@", "\t", "\r")
"""A CSV cell starting with one of these is a formula to a spreadsheet (OWASP CSV injection)."""


def neutralised(frame: Any) -> Any:
    """``frame`` with every text cell that a spreadsheet would run as a formula prefixed by a
    single quote (OWASP); numbers, also negative ones, are left as they are. For CSV only:
    Parquet keeps values as they are."""
    from pandas.api.types import is_numeric_dtype

    out = frame.copy()
    for col in out.columns:
        if not is_numeric_dtype(out[col]):
            out[col] = out[col].map(lambda v: "'" + v if isinstance(v, str) and v.startswith(
                FORMULA_STARTS) else v)
    return out


def to_bytes(rows: Iterable[Mapping[str, Any]], fmt: str,
             columns: Sequence[str] = ESTIMATE_COLUMNS) -> bytes:
    """Rows as CSV or Parquet bytes with ``columns`` in order (also when there are no rows);
    ``n_shots`` and ``measurement_id`` stay integers."""
    import pandas as pd

    frame = pd.DataFrame(list(rows), columns=list(columns))
    for col in ("n_shots", "measurement_id"):
        if col in frame:
            frame[col] = frame[col].astype("Int64")
    for col in ("plate_id", "position", "sphere_diameters_m", "reason", "warnings", "created_at",
                "table", "size_summaries", "calibration", "material_spread", "other_reading",
                "readings", *(f"{p}_status" for p in PARAMETERS)):
        if col in frame:
            frame[col] = frame[col].astype("string")
    if fmt == "parquet":
        buf = io.BytesIO()
        frame.to_parquet(buf, index=False)
        return buf.getvalue()
    return neutralised(frame).to_csv(index=False).encode()
