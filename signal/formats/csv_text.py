"""CSV: text tables as scopes, DAQ programs, spreadsheets and this project write them.

The layouts (Tektronix, Keysight, Rigol, PicoScope, LeCroy, generic, this project's own) are
told apart by :mod:`.csv_layouts`; every value column is a channel and a shot, the time column
never is. UTF-8 (a byte-order mark is allowed) or Windows-1252.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import WaveformError
from ..waveform import Waveform, _jsonable, uniform_grid
from .base import FileFormat
from .csv_layouts import parse
from .csv_table import SCOPE_LAYOUTS
from .reading import (
    COMMON_OPTIONS,
    as_waveforms,
    decode_value,
    resolve_units,
    sample_period,
    stated_period,
)


def read_csv(
    path: Path, sample_rate: float | None = None, dt: float | None = None,
    t0: float | None = None, units: str | None = None, calibration: float | None = None,
) -> list[Waveform]:
    """Any layout :mod:`.csv_layouts` knows; one waveform per value column."""
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        try:  # Windows spreadsheets and scope software write the ANSI code page ("µs")
            text = raw.decode("cp1252")
        except UnicodeDecodeError:
            raise WaveformError("file", f"{path.name}: not text (byte "
                                f"{exc.object[exc.start]:#x} at offset {exc.start})",
                                "UTF-8 or Windows-1252 text") from None
    table = parse(text, path.name)
    meta = {k: decode_value(v, k) for k, v in table.metadata.items()}
    file_t0, file_dt, file_rate = (meta.pop(k, None) for k in ("t0", "dt", "sample_rate"))
    own: float | None
    if table.time is not None:
        own_t0, own = uniform_grid(table.time, rounding=table.time_resolution)
    else:
        own_t0 = 0.0 if file_t0 is None else file_t0
        own = stated_period(file_dt, file_rate)
    step = sample_period(own, sample_rate, dt, path.name)
    start = own_t0 if t0 is None else t0
    own_cal = meta.pop("calibration", None)
    vendor = table.layout in SCOPE_LAYOUTS or table.layout == "generic"
    parts = []
    for j, column in enumerate(table.columns):
        unit = resolve_units(column.unit, units, f"{path.name} column {column.label!r}")
        m = dict(meta)
        if len(table.columns) > 1 or vendor:
            m.setdefault("channel", column.label)
        if len(table.columns) > 1:
            m["shot"] = j
        parts.append((start, step, column.values, unit, own_cal, m))
    return as_waveforms(parts, calibration, path.name)


def write_csv(path: Path, waves: list[Waveform]) -> None:
    ref = waves[0]
    for w in waves[1:]:
        if w.n != ref.n or w.t0 != ref.t0 or w.dt != ref.dt:
            raise WaveformError("waveforms", "CSV shots must share t0, dt and length",
                                "one CSV per time axis")
    with path.open("w", encoding="utf-8", newline="\n") as fh:
        for key, value in ref.metadata.items():
            if key in ("shot", "source"):
                continue
            text = value if isinstance(value, str) else json.dumps(_jsonable(value))
            fh.write(f"# {key}: {text}\n")
        if ref.calibration is not None:
            fh.write(f"# calibration: {ref.calibration!r}\n")
        fh.write(f"# n_samples: {ref.n}\n")  # lets a reader tell a file cut short
        labels = ["time_s"] + [("force_N" if w.units == "N" else "voltage_V") for w in waves]
        fh.write(",".join(labels) + "\n")
        table = np.column_stack([ref.times] + [w.samples for w in waves])
        np.savetxt(fh, table, delimiter=",", fmt="%.9g")


FORMAT = FileFormat("csv", (".csv",), COMMON_OPTIONS, read_csv, write_csv)
