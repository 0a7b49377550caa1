"""Features of many shots of one length at once: a 2-D array in, one array per feature out.

For an acquisition PC or a directory of files: the samples are validated in one vectorised pass,
and one numba call (:func:`solitonde.signal.kernels.analyze_batch`) runs the same per-shot kernel
as :func:`solitonde.signal.features.extract` over every row, on numba's threads. No Features
object is made per shot (only the SNR is finished in Python, to match ``extract`` bit for bit),
so the cost is the kernel's. The command line does not use it yet (``solitonde analyze`` reads
one file at a time); it is the library entry point for arrays. :meth:`FeatureTable.features`
gives one shot's :class:`~solitonde.signal.features.Features`, equal field for field to what
``extract`` returns for that shot (tests/signal/test_signal_batch.py holds them together).
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import kernels as K
from .errors import WaveformError
from .features import FIELD_KINDS, Features, window_of
from .pulses import (
    FLAGS,
    DetectOptions,
    early_pulse,
    kernel_args,
    lowpass,
    quality_flags,
    trip_s,
    unsteady,
    width_ratio,
)
from .waveform import MIN_SAMPLES, UNITS, invalid_sample

FLAG_BITS = {name: 1 << k for k, name in enumerate(FLAGS)}
"""Bit of each quality flag in :attr:`FeatureTable.flags`."""


@dataclass(frozen=True, eq=False)
class FeatureTable:
    """Per-shot features of a batch, one array per field of
    :class:`~solitonde.signal.features.Features` (``table.tof_s``), NaN where a shot has no such
    value.

    ``detected`` is false for a shot without any pulse (``extract`` raises for it); ``flags`` is a
    bit mask (:data:`FLAG_BITS`); ``secondary_times_s`` and ``secondary_ratios`` are
    ``(shots, max_secondary)``, NaN past each shot's count; ``n_pulses`` counts every pulse
    found. The columns are exactly the fields of ``Features`` (checked when the table is made),
    so a new feature is declared once, there.
    """

    detected: np.ndarray
    n_pulses: np.ndarray
    columns: dict[str, np.ndarray]

    def __post_init__(self) -> None:
        if list(self.columns) != list(FIELD_KINDS):
            missing = [k for k in FIELD_KINDS if k not in self.columns]
            extra = [k for k in self.columns if k not in FIELD_KINDS]
            raise ValueError(f"FeatureTable columns differ from Features' fields: missing "
                             f"{missing}, extra {extra} (or in another order)")

    def __getattr__(self, name: str) -> np.ndarray:
        columns = self.__dict__.get("columns")
        if columns is not None and name in columns:
            return columns[name]
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def __len__(self) -> int:
        return int(self.detected.size)

    def flag_names(self, i: int) -> list[str]:
        """Names of the flags of shot ``i``, in :data:`~solitonde.signal.pulses.FLAGS` order."""
        mask = int(self.columns["flags"][i])
        return [name for name, bit in FLAG_BITS.items() if mask & bit]

    def features(self, i: int) -> Features | None:
        """Shot ``i`` as :class:`Features` (``None`` when it holds no pulse), field by field as
        each field's kind says (a NaN of an optional field is None)."""
        if not self.detected[i]:
            return None
        count = int(np.count_nonzero(~np.isnan(self.columns["secondary_times_s"][i])))
        values: dict[str, Any] = {}
        for name, kind in FIELD_KINDS.items():
            column = self.columns[name]
            if kind == "flags":
                values[name] = self.flag_names(i)
            elif kind == "series":
                values[name] = [float(v) for v in column[i, :count]]
            elif kind == "optional":
                values[name] = None if math.isnan(column[i]) else float(column[i])
            else:
                values[name] = float(column[i])
        return Features(**values)

    def to_features(self) -> list[Features | None]:
        """Every shot as :class:`Features` (``None`` for a shot without any pulse)."""
        return [self.features(i) for i in range(len(self))]


def check_batch(samples: Any) -> np.ndarray:
    """``samples`` as a C-contiguous ``(shots, n)`` float64 array (no copy when it already is
    one), checked in one pass: at least one shot, :data:`MIN_SAMPLES` per shot, all finite."""
    try:
        x = np.ascontiguousarray(samples, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise WaveformError("samples", f"not numeric data ({exc})") from None
    if x.ndim != 2 or x.shape[0] == 0:
        raise WaveformError("samples", f"got shape {x.shape}", "a 2-D array, one shot per row")
    if x.shape[1] < MIN_SAMPLES:
        raise WaveformError("samples", f"too few samples per shot ({x.shape[1]})",
                            f"at least {MIN_SAMPLES} samples per shot")
    bad = K.first_invalid(x)
    if bad >= 0:
        shot, sample = divmod(bad, x.shape[1])
        raise WaveformError("samples", f"{invalid_sample(x[shot, sample])} at shot {shot}, "
                            f"sample {sample}",
                            f"finite numbers of magnitude at most {K.MAX_ABS_SAMPLE:g}")
    return x


def _number(name: str, value: Any, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise WaveformError(name, f"expected a number, got {value!r}")
    number = float(value)
    if not math.isfinite(number) or (positive and number <= 0):
        raise WaveformError(name, f"got {number}", "a positive finite number" if positive
                            else "a finite number")
    return number


def extract_batch(
    samples: Any,
    dt: float,
    t0: float = 0.0,
    units: str = "N",
    calibration: float | None = None,
    threads: int = 1,
    **options: Any,
) -> FeatureTable:
    """TOF, ARR, SNR and flags of every shot in ``samples`` (one shot per row, all of period
    ``dt`` s, starting at ``t0`` s); ``options`` are :class:`DetectOptions` fields.

    Volts (``units="V"``) are turned into newtons with ``calibration`` (N/V), as a
    :class:`~solitonde.signal.waveform.Waveform` does. ``threads`` > 1 splits the shots into
    that many blocks run side by side (the kernel runs without the GIL); the features do not
    depend on it.
    """
    x = check_batch(samples)
    dt = _number("dt", dt, positive=True)
    t0 = _number("t0", t0)
    if units not in UNITS:
        raise WaveformError("units", f"unknown units {units!r}", "'N' or 'V'")
    if units == "V":
        if calibration is None:
            raise WaveformError("calibration", "samples are in volts but no calibration was given",
                                "sensor sensitivity in N/V")
        cal = _number("calibration", calibration)
        if cal == 0:
            raise WaveformError("calibration", "must not be zero", "sensitivity in N/V, != 0")
        x = x * cal
    opts = DetectOptions.from_kwargs(options)
    if opts.lowpass_hz is not None:
        x = np.stack([lowpass(row, dt, opts.lowpass_hz) for row in x])
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        raise WaveformError("threads", f"got {threads!r}", "a positive integer")
    args = (*kernel_args(opts, x.shape[1], dt), 2 + opts.max_secondary)
    x = x.view()
    x.setflags(write=False)  # rows then have the type of a Waveform's samples: one compiled kernel
    if threads == 1 or x.shape[0] == 1:
        parts = [K.analyze_batch(x, *args)]
    else:
        blocks = np.array_split(x, min(threads, x.shape[0]))
        with ThreadPoolExecutor(len(blocks)) as pool:
            parts = list(pool.map(lambda block: K.analyze_batch(block, *args), blocks))
    heads, rows, counts = (np.concatenate(arrays) for arrays in zip(*parts, strict=True))
    return _table(heads, rows, counts, t0, dt, opts, x.shape[1])


def _table(heads: np.ndarray, rows: np.ndarray, counts: np.ndarray, t0: float, dt: float,
           opts: DetectOptions, n_samples: int) -> FeatureTable:
    """The arrays of :func:`analyze_batch` as features, with the flag logic of
    :func:`solitonde.signal.pulses.detect` done on whole columns."""
    nan = np.nan
    sign = heads[:, K.H_SIGN]
    noise = heads[:, K.H_SIGMA]
    detected = counts > 0
    has_ref = (counts > 1) & (heads[:, K.H_NOREF] == 0)
    times = t0 + rows[:, :, K.P_TIME] * dt
    amps = rows[:, :, K.P_AMP]
    rise = rows[:, :, K.P_RISE]
    inc_t, inc_a = times[:, 0], amps[:, 0]
    inc_w = rows[:, 0, K.P_WIDTH] * dt
    ref_t = np.where(has_ref, times[:, 1], nan)
    ref_a = np.where(has_ref, amps[:, 1], nan)
    snr = np.array([20.0 * math.log10(max(a, 1e-300) / s) for a, s in zip(amps[:, 0], noise,
                                                                         strict=True)])
    ref_snr = np.array([20.0 * math.log10(max(a, 1e-300) / s) for a, s in zip(amps[:, 1], noise,
                                                                             strict=True)])
    # The secondary pulses follow the reflection's row, or the incident's where the travel gate
    # held no reflection.
    start = np.where(has_ref, 2, 1)
    n_sec = np.clip(counts - start, 0, opts.max_secondary)
    sec = np.arange(opts.max_secondary)[None, :] < n_sec[:, None]
    cols = np.minimum(start[:, None] + np.arange(opts.max_secondary)[None, :], times.shape[1] - 1)
    sec_t = np.where(sec, np.take_along_axis(times, cols, axis=1), nan)
    sec_r = np.where(sec, np.take_along_axis(amps, cols, axis=1)
                     / np.where(detected, inc_a, 1.0)[:, None], nan)

    merged = rows[:, :, K.P_MERGED] != 0
    cut = rows[:, :, K.P_TRUNC] != 0  # only the incident and the reflection count
    ratio = np.array([width_ratio(w, a, opts.pulse_width_1n_s)
                      for w, a in zip(inc_w, inc_a, strict=True)], dtype=np.float64)
    # the rows past a shot's count are zeros: a negative delay and a zero ratio, no pulse
    early_one = early_pulse(times[:, 1:] - inc_t[:, None],
                            amps[:, 1:] / np.where(detected, inc_a, 1.0)[:, None],
                            trip_s(opts.travel_time_1n_s, inc_a))
    raised = quality_flags(
        detected=detected, has_reflection=has_ref, early=heads[:, K.H_EARLY] != 0,
        saturated=heads[:, K.H_SATURATED] != 0, sign=sign, incident_merged=merged[:, 0],
        reflection_merged=merged[:, 1], more_than_two=counts > 2, incident_cut=cut[:, 0],
        reflection_cut=cut[:, 1], train=heads[:, K.H_TRAIN] != 0,
        check_snr_db=np.where(has_ref, ref_snr, snr), low_snr_db=opts.low_snr_db,
        width_ratio=ratio, early_pulse=early_one,
        unsteady=unsteady(heads[:, K.H_MISFIT], heads[:, K.H_MISFIT_N], noise, rows[:, 0, K.P_AMP]))
    flags = np.zeros(sign.size, dtype=np.uint16)
    for name, where in raised.items():
        flags |= np.where(where, FLAG_BITS[name], 0).astype(np.uint16)
    return FeatureTable(detected=detected, n_pulses=counts, columns={
        "tof_s": np.where(has_ref, ref_t - inc_t, nan),
        "arr": np.where(has_ref, ref_a / np.where(detected, inc_a, 1.0), nan),
        "incident_time_s": np.where(detected, inc_t, nan),
        "reflected_time_s": ref_t,
        "incident_peak_N": np.where(detected, inc_a, nan),
        "reflected_peak_N": ref_a,
        "snr_db": np.where(detected, snr, nan),
        "flags": flags,
        "arr_upper_bound": np.where(detected & ~has_ref, heads[:, K.H_UPPER], nan),
        "secondary_times_s": sec_t,
        "secondary_ratios": sec_r,
        "baseline_N": np.where(detected, sign * rows[:, 0, K.P_BASE], nan),
        "noise_N": noise,
        "arr_local": np.where(has_ref, rise[:, 1] / np.where(detected, rise[:, 0], 1.0), nan),
        "incident_rise_N": np.where(detected, rise[:, 0], nan),
        "reflected_rise_N": np.where(has_ref, rise[:, 1], nan),
        "tof_peak_s": np.where(has_ref, (t0 + rows[:, 1, K.P_PEAK_TIME] * dt)
                               - (t0 + rows[:, 0, K.P_PEAK_TIME] * dt), nan),
        "arr_peak": np.where(has_ref, rows[:, 1, K.P_PEAK_AMP]
                             / np.where(detected, rows[:, 0, K.P_PEAK_AMP], 1.0), nan),
        "incident_width_s": np.where(detected, inc_w, nan),
        "reflection_window_s": np.where(
            detected, window_of(t0 + (n_samples - 1) * dt, inc_t, inc_w), nan),
    })
