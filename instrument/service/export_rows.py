"""The store's shots as flat rows, one per shot with its features spread into columns: what
``GET /v1/measurements/export?kind=shots`` writes as CSV or Parquet."""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any

from solitonde.instrument.service.store import Store

EXPORT_COLUMNS = ("measurement_id", "created_at", "plate_id", "position", "shot_index",
                  "shot", "sphere_diameter", "t0_s", "dt_s", "units", "calibration",
                  "n_samples")
"""The columns :func:`shot_rows` puts before each shot's features."""


def shot_rows(store: Store, plate_id: str | None = None,
              limit: int = 200_000) -> Iterator[dict[str, Any]]:
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


def _flat(features: dict[str, Any]) -> dict[str, Any]:
    """Scalar features as columns; lists joined so CSV and Parquet hold one value per cell."""
    out: dict[str, Any] = {}
    for key, value in features.items():
        if isinstance(value, list | tuple):
            out[key] = ";".join(str(v) for v in value)
        elif isinstance(value, dict):
            out[key] = json.dumps(value)
        else:
            out[key] = value
    return out
