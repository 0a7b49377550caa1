"""NPY: a 2-D ``(n_samples, 1 + shots)`` array with a uniform time axis in column 0, or
samples only (1-D, or one shot per row), which need ``sample_rate=``. Its header states shape
and dtype, so its size is known before it is read."""

from __future__ import annotations

from pathlib import Path
from typing import IO

import numpy as np

from ..errors import WaveformError
from ..waveform import MIN_SAMPLES, Waveform, uniform_grid
from .base import FileFormat
from .reading import (
    COMMON_OPTIONS,
    as_waveforms,
    float_array,
    is_time_axis,
    resolve_units,
    sample_period,
    shot_rows,
)


def read_npy(
    path: Path, sample_rate: float | None = None, dt: float | None = None,
    t0: float | None = None, units: str | None = None, calibration: float | None = None,
) -> list[Waveform]:
    array = float_array(np.load(path, allow_pickle=False), "samples")
    unit = resolve_units(None, units, path.name)
    if array.ndim == 2 and array.shape[0] >= MIN_SAMPLES and array.shape[1] >= 2 \
            and is_time_axis(array[:, 0]):
        own_t0, own = uniform_grid(array[:, 0])
        step = sample_period(own, sample_rate, dt, path.name)
        start = own_t0 if t0 is None else t0
        parts = [(start, step, array[:, j], unit, None, {"shot": j - 1})
                 for j in range(1, array.shape[1])]
        return as_waveforms(parts, calibration, path.name)
    if sample_rate is None and dt is None and array.ndim == 2 and array.shape[1] >= 2 \
            and array.shape[0] >= MIN_SAMPLES:
        uniform_grid(array[:, 0])  # raises, naming what is wrong with the would-be time column
    step = sample_period(None, sample_rate, dt, f"{path.name} (shape {array.shape})",
                 "a 2-D array (n_samples, 1 + shots) with time in column 0, or sample_rate=")
    start = 0.0 if t0 is None else t0
    parts = [(start, step, r, unit, None, {}) for r in shot_rows(array, "samples")]
    return as_waveforms(parts, calibration, path.name)


def write_npy(path: Path, waves: list[Waveform]) -> None:
    ref = waves[0]
    for w in waves[1:]:
        if w.n != ref.n or w.t0 != ref.t0 or w.dt != ref.dt:
            raise WaveformError("waveforms", "NPY shots must share t0, dt and length")
    table = np.column_stack([ref.times] + [w.force for w in waves])
    with path.open("wb") as fh:
        np.save(fh, table)


def array_values(shape: tuple[int, ...] | None, dtype: np.dtype) -> int:
    """Values of an array of ``shape`` and ``dtype``, one per 8 bytes of each element."""
    count = int(np.prod(shape, dtype=np.int64)) if shape else 1
    return count * max(1, -(-int(dtype.itemsize) // 8))


def npy_header_values(fh: IO[bytes]) -> int:
    """Values an .npy header declares (``fh`` at its start); reads the header only."""
    version = np.lib.format.read_magic(fh)
    if version == (1, 0):
        shape, _, dtype = np.lib.format.read_array_header_1_0(fh)
    else:
        shape, _, dtype = np.lib.format.read_array_header_2_0(fh)
    return array_values(shape, np.dtype(dtype))


def npy_values(path: Path, _dataset: str | None = None) -> int:
    """Values the array's header declares."""
    with open(path, "rb") as fh:
        return npy_header_values(fh)


FORMAT = FileFormat("npy", (".npy",), COMMON_OPTIONS, read_npy, write_npy,
                    declared_values=npy_values)
