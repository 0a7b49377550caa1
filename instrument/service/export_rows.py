"""The measurements export: the store's shots as flat rows, one per shot with its features
spread into columns (``GET /v1/measurements/export?kind=shots``), or one row per measurement
with its estimate (``kind=estimates``), as CSV or Parquet."""

from __future__ import annotations

import dataclasses
import io
import json
from collections.abc import Iterator
from typing import Any

from solitonde.instrument.inference.estimate_rows import EstimateRow
from solitonde.instrument.service.measurement_json import StoredResult
from solitonde.instrument.service.problems import Problem
from solitonde.instrument.service.state import Service
from solitonde.instrument.service.store import Store
from solitonde.signal.features import FeatureDict

EXPORT_COLUMNS = ("measurement_id", "created_at", "plate_id", "position", "shot_index",
                  "shot", "sphere_diameter", "t0_s", "dt_s", "units", "calibration",
                  "n_samples")
"""The columns :func:`shot_rows` puts before each shot's features."""

Cell = str | float | int | None
"""One value of an export row: CSV and Parquet hold one scalar per cell."""


def shot_rows(store: Store, plate_id: str | None = None,
              limit: int = 200_000) -> Iterator[dict[str, Cell]]:
    """Flat rows (one per shot, features spread into columns) for export."""
    sql = ("SELECT m.id, m.created_at, m.plate_id, m.position, s.shot_index, s.t0, s.dt, "
           "s.units, s.calibration, s.n_samples, s.metadata, s.features "
           "FROM shots s JOIN measurements m ON m.id = s.measurement_id")
    args: list[Any] = []
    if plate_id is not None:
        sql += " WHERE m.plate_id = ?"
        args.append(plate_id)
    sql += " ORDER BY m.id, s.shot_index LIMIT ?"
    args.append(limit)
    for r in store.rows(sql, args):
        meta = json.loads(r[10])
        feats = json.loads(r[11])
        yield {
            "measurement_id": r[0], "created_at": r[1], "plate_id": r[2], "position": r[3],
            "shot_index": r[4], "shot": meta.get("shot"),
            "sphere_diameter": meta.get("sphere_diameter"), "t0_s": r[5], "dt_s": r[6],
            "units": r[7], "calibration": r[8], "n_samples": r[9], **_flat(feats),
        }


def _flat(features: FeatureDict) -> dict[str, Cell]:
    """Scalar features as columns; lists joined so CSV and Parquet hold one value per cell."""
    out: dict[str, Cell] = {}
    for key, value in features.items():
        raw: object = value  # a row stored by an older version may hold a mapping
        if isinstance(raw, list | tuple):
            out[key] = ";".join(str(v) for v in raw)
        elif isinstance(raw, dict):
            out[key] = json.dumps(raw)
        else:
            out[key] = value  # type: ignore[assignment]
    return out


class MeasurementEstimateRow(EstimateRow):
    """A row of the estimates export: the measurement's id and time, then its estimate's
    columns."""

    measurement_id: int
    created_at: str | None


MEDIA = {"csv": "text/csv", "parquet": "application/vnd.apache.parquet"}
"""The export formats and their media types."""


def shots_export(svc: Service, fmt: str, plate_id: str | None) -> tuple[bytes, str]:
    """One row per stored shot (:func:`shot_rows`) as CSV or Parquet bytes, with the media type;
    a 422 rather than a silently cut export above the service's row limit."""
    import pandas as pd

    from solitonde.instrument.inference.estimate_rows import iso_utc, neutralised

    limit = svc.settings.export_rows_max
    rows = list(shot_rows(svc.store, plate_id, limit + 1))
    if len(rows) > limit:  # never a silently cut export
        raise Problem(422, f"export: more than {limit:,} shots match; export at most {limit:,} "
                      "rows at a time (ask for one plate_id)", kind="limit", field="plate_id")
    frame = pd.DataFrame(rows)
    if not rows:  # still the columns, so a script reading an empty export finds them
        from solitonde.signal.features import Features

        frame = pd.DataFrame(columns=[*EXPORT_COLUMNS,
                                      *(f.name for f in dataclasses.fields(Features)),
                                      "baseline"])
    frame["created_at"] = frame["created_at"].map(iso_utc).astype("string")
    for col in ("measurement_id", "shot_index", "shot", "n_samples"):
        numbers = pd.to_numeric(frame[col], errors="coerce")
        if numbers.notna().sum() == frame[col].notna().sum():  # a file's text shot labels stay
            frame[col] = numbers.astype("Int64")
    if fmt == "parquet":
        buf = io.BytesIO()
        frame.to_parquet(buf, index=False)
        return buf.getvalue(), MEDIA[fmt]
    return neutralised(frame).to_csv(index=False).encode(), MEDIA[fmt]


def estimates_export(svc: Service, fmt: str, plate_id: str | None) -> tuple[bytes, str]:
    """One row per stored measurement: where, from what, and its estimate's columns."""
    from solitonde.instrument.inference.estimate_rows import (
        ESTIMATE_COLUMNS,
        estimate_row,
        iso_utc,
        to_bytes,
    )

    limit = svc.settings.export_rows_max
    rows: list[MeasurementEstimateRow] = []
    after = 0
    while True:
        page = svc.store.list(plate_id, after, 1000)
        for r in page:
            diameters = _estimated_sizes(r.result)
            location = {"plate_id": r.plate_id, "position": r.position,
                        **(r.result.get("location") or {})}
            rows.append({"measurement_id": r.id, "created_at": iso_utc(r.created_at),
                         **estimate_row(location, diameters, r.n_shots, r.result.get("estimate"),
                                        r.result.get("estimate_reason"))})
        if len(rows) > limit:
            raise Problem(422, f"export: more than {limit:,} measurements match; export at most "
                          f"{limit:,} rows at a time (ask for one plate_id)", kind="limit",
                          field="plate_id")
        if len(page) < 1000:
            break
        after = page[-1].id
    columns = ("measurement_id", "created_at", *ESTIMATE_COLUMNS)
    return to_bytes(rows, fmt, columns), MEDIA[fmt]


def _estimated_sizes(result: StoredResult) -> list[float]:
    """The sphere sizes an estimate was made from (the inversion's inputs, less any it left
    out); without an estimate, every size measured."""
    estimate = result.get("estimate")
    if estimate and estimate.get("inputs"):
        excluded = set(estimate.get("excluded_diameters_m") or [])
        return [i["diameter_m"] for i in estimate["inputs"] if i["diameter_m"] not in excluded]
    return [d for a in result.get("aggregates", [])
            if (d := a.get("sphere_diameter")) is not None]
