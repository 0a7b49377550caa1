"""NPZ: ``samples`` (1-D or one shot per row) with ``dt`` or ``sample_rate``, optional ``t0``,
``units``, ``calibration`` and ``metadata`` (a JSON object, or a list of one object per shot)."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import WaveformError
from ..waveform import Waveform, _jsonable
from .base import FileFormat
from .npy import npy_header_values
from .reading import (
    COMMON_OPTIONS,
    as_waveforms,
    decode_value,
    float_array,
    resolve_units,
    sample_period,
    shot_rows,
    stated_period,
)


def read_npz(
    path: Path, sample_rate: float | None = None, dt: float | None = None,
    t0: float | None = None, units: str | None = None, calibration: float | None = None,
) -> list[Waveform]:
    with np.load(path, allow_pickle=False) as data:
        if "samples" not in data:
            raise WaveformError("samples", f"{path.name}: no 'samples' array",
                                f"keys samples, dt or sample_rate; found {sorted(data.files)}")
        samples = float_array(data["samples"], "samples")
        found = {k: decode_value(data[k], k) for k in ("dt", "sample_rate", "t0", "calibration")
                 if k in data}
        stated = decode_value(data["units"]) if "units" in data else None
        meta_text = decode_value(data["metadata"]) if "metadata" in data else {}
    own = stated_period(found.get("dt"), found.get("sample_rate"))
    step = sample_period(own, sample_rate, dt, path.name)
    start = found.get("t0", 0.0) if t0 is None else t0
    unit = resolve_units(stated, units, path.name)
    try:
        meta = json.loads(meta_text) if isinstance(meta_text, str) else meta_text
    except ValueError:
        raise WaveformError("metadata", f"{path.name}: not valid JSON ({meta_text[:80]!r})",
                            "a JSON object, or a list of one object per shot") from None
    meta = {} if meta is None else meta
    rows = shot_rows(samples, "samples")
    metas = meta if isinstance(meta, list) else [meta] * len(rows)
    if len(metas) != len(rows) or not all(isinstance(m, dict) for m in metas):
        raise WaveformError("metadata", f"{path.name}: {meta_text!r} for {len(rows)} shots",
                            "a JSON object, or a list of one object per shot")
    parts = [(start, step, r, unit, found.get("calibration"), m)
             for r, m in zip(rows, metas, strict=True)]
    return as_waveforms(parts, calibration, path.name)


def write_npz(path: Path, waves: list[Waveform]) -> None:
    ref = waves[0]
    for w in waves[1:]:
        if w.n != ref.n or w.t0 != ref.t0 or w.dt != ref.dt or w.units != ref.units:
            raise WaveformError("waveforms", "NPZ shots must share t0, dt, length and units")
    extra: dict[str, Any] = ({"calibration": np.float64(ref.calibration)}
                             if ref.calibration is not None else {})
    with path.open("wb") as fh:
        np.savez_compressed(
            fh, samples=np.vstack([w.samples for w in waves]), t0=np.float64(ref.t0),
            dt=np.float64(ref.dt), units=np.str_(ref.units),
            metadata=np.str_(json.dumps([_jsonable(w.metadata) for w in waves])), **extra,
        )


def npz_values(path: Path, _dataset: str | None = None) -> int:
    """Every member of the archive, whatever its name (numpy reads ``samples`` as well as
    ``samples.npy``), sized by the larger of its .npy header's shape and its uncompressed size
    in the zip directory, so that nothing is inflated before the limit is checked."""
    total = 0
    with zipfile.ZipFile(path) as zf:
        for info in zf.infolist():
            by_size = -(-int(info.file_size) // 8)
            try:
                with zf.open(info) as member:
                    by_header = npy_header_values(member)
            except Exception:  # not an array header: its uncompressed size bounds it
                by_header = 0
            total += max(by_size, by_header)
    return total


FORMAT = FileFormat("npz", (".npz",), COMMON_OPTIONS, read_npz, write_npz,
                    declared_values=npz_values)
