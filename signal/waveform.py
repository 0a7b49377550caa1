"""The waveform: one uniformly sampled sensor trace with its units, calibration and metadata.

A shot is one :class:`Waveform`; a file or REST body holding several shots yields a list of them.
Construction validates everything once, so detection code can trust what it receives.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import kernel_choice
from .errors import WaveformError
from .kernels import MAX_ABS_SAMPLE

UNITS = ("N", "V")
MIN_SAMPLES = 32
"""Fewest samples a shot may have: enough for a pre-trigger segment and one pulse."""

UNIFORM_TOLERANCE = 0.01
"""Largest allowed deviation of a time stamp from the uniform grid, as a fraction of dt.

Text files print time stamps with a limited number of digits; 1 % of a sample period absorbs that
rounding and still rejects a dropped or repeated sample.
"""


def _finite_float(name: str, value: Any) -> float:
    if isinstance(value, bool):
        raise WaveformError(name, f"expected a number, got a boolean ({value})")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise WaveformError(name, f"expected a number, got {value!r}") from None
    if not np.isfinite(number):
        raise WaveformError(name, f"must be finite, got {number}")
    return number


def check_samples(samples: Any, name: str = "samples") -> np.ndarray:
    """Return ``samples`` as a contiguous 1-D float64 array, or raise naming what is wrong."""
    try:
        array = np.ascontiguousarray(samples, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise WaveformError(name, f"not numeric data ({exc})") from None
    if array.ndim != 1:
        raise WaveformError(name, f"must be one-dimensional, got shape {array.shape}")
    if array.size == 0:
        raise WaveformError(name, "empty: no samples")
    if array.size < MIN_SAMPLES:
        raise WaveformError(
            name, f"too few samples ({array.size})", f"at least {MIN_SAMPLES} samples per shot"
        )
    checked = array.view()
    checked.setflags(write=False)  # whatever the caller's flag: one compiled first_invalid
    bad = kernel_choice.current().first_invalid(checked)
    if bad >= 0:
        raise WaveformError(name, f"{invalid_sample(array[bad])} at sample {bad}",
                            f"finite numbers of magnitude at most {MAX_ABS_SAMPLE:g}")
    return array


def invalid_sample(value: float) -> str:
    """What is wrong with a sample :func:`~solitonde.signal.kernels.first_invalid` found."""
    if not np.isfinite(value):
        return f"contains NaN or inf ({value})"
    return f"a value of magnitude beyond {MAX_ABS_SAMPLE:g} ({value:g})"


def uniform_grid(time: Any, name: str = "time", rounding: float = 0.0) -> tuple[float, float]:
    """Check that ``time`` is strictly increasing and uniform; return ``(t0, dt)``.

    ``rounding`` (s) is how far a stamp may be off the grid because the file printed it with
    few digits (half its last digit); it adds to the tolerance.

    Raises
    ------
    WaveformError
        If the stamps are not finite, go backwards or repeat, or stray from a uniform grid by more
        than :data:`UNIFORM_TOLERANCE` of a sample period.
    """
    t = np.asarray(time, dtype=np.float64)
    if t.ndim != 1 or t.size < 2:
        raise WaveformError(name, f"need a 1-D column of at least 2 time stamps, got {t.shape}")
    if not np.isfinite(t).all():
        raise WaveformError(name, "contains NaN or inf", "finite time stamps in seconds")
    steps = np.diff(t)
    if (steps <= 0).any():
        i = int(np.flatnonzero(steps <= 0)[0])
        raise WaveformError(
            name,
            f"not monotonic: stamp {i + 1} ({t[i + 1]!r} s) does not follow stamp {i} ({t[i]!r} s)",
            "strictly increasing time",
        )
    dt = (t[-1] - t[0]) / (t.size - 1)
    deviation = np.abs(t - (t[0] + dt * np.arange(t.size)))
    worst = int(np.argmax(deviation))
    if deviation[worst] > UNIFORM_TOLERANCE * dt + rounding:
        raise WaveformError(
            name,
            f"non-uniform sampling: stamp {worst} is {deviation[worst] / dt:.3g} sample periods "
            f"off the uniform grid (dt = {dt:.6g} s); steps range {steps.min():.6g} to "
            f"{steps.max():.6g} s",
            f"uniform sampling within {UNIFORM_TOLERANCE:g} dt",
        )
    return float(t[0]), float(dt)


@dataclass(frozen=True, eq=False)
class Waveform:
    """One shot: uniformly sampled sensor samples with their time axis, units and metadata.

    Parameters
    ----------
    t0:
        Time of the first sample, s.
    dt:
        Sample period, s (> 0).
    samples:
        The recorded values, 1-D, finite, at least :data:`MIN_SAMPLES` long.
    units:
        ``"N"`` (force) or ``"V"`` (raw sensor voltage).
    calibration:
        Sensor sensitivity in N/V; turns volts into newtons (``force = V * calibration``).
    metadata:
        Free-form; by convention ``shot``, ``plate_id``, ``position``, ``sphere_diameter``,
        ``source``.
    """

    t0: float
    dt: float
    samples: np.ndarray
    units: str = "N"
    calibration: float | None = None
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "t0", _finite_float("t0", self.t0))
        dt = _finite_float("dt", self.dt)
        if dt <= 0:
            raise WaveformError("dt", f"must be positive, got {dt}", "sample period > 0 s")
        set_(self, "dt", dt)
        samples = check_samples(self.samples)
        samples.setflags(write=False)
        set_(self, "samples", samples)
        if self.units not in UNITS:
            raise WaveformError("units", f"unknown units {self.units!r}", "'N' or 'V'")
        if self.calibration is not None:
            cal = _finite_float("calibration", self.calibration)
            if cal == 0:
                raise WaveformError("calibration", "must not be zero", "sensitivity in N/V, != 0")
            set_(self, "calibration", cal)
        elif self.units == "V":
            raise WaveformError(
                "calibration",
                "samples are in volts but no calibration was given",
                "sensor sensitivity in N/V",
            )
        if not isinstance(self.metadata, Mapping):
            kind = type(self.metadata).__name__
            raise WaveformError("metadata", f"must be a mapping, got {kind}")
        set_(self, "metadata", dict(self.metadata))

    @classmethod
    def from_times(cls, time: Any, samples: Any, **kwargs: Any) -> Waveform:
        """Build from explicit time stamps, checking they are monotonic and uniform."""
        values = check_samples(samples)
        t = np.asarray(time, dtype=np.float64)
        if t.shape != values.shape:
            raise WaveformError(
                "time", f"{t.size} time stamps for {values.size} samples", "one stamp per sample"
            )
        t0, dt = uniform_grid(t)
        return cls(t0=t0, dt=dt, samples=values, **kwargs)

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.samples.size)

    @property
    def times(self) -> np.ndarray:
        """Time of every sample, s."""
        return self.t0 + self.dt * np.arange(self.samples.size)

    @property
    def duration(self) -> float:
        """Span from the first to the last sample, s."""
        return self.dt * (self.samples.size - 1)

    @property
    def sample_rate(self) -> float:
        """Samples per second, Hz."""
        return 1.0 / self.dt

    @property
    def force(self) -> np.ndarray:
        """Samples in newtons (volts times calibration when the units are V)."""
        if self.units == "N":
            return self.samples
        return self.samples * self.calibration

    def to_newtons(self) -> Waveform:
        """This shot with its samples converted to N (itself when already in N)."""
        if self.units == "N":
            return self
        return Waveform(self.t0, self.dt, self.force, "N", self.calibration, self.metadata)

    def with_samples(self, samples: Any) -> Waveform:
        """A copy with other samples on the same time axis (e.g. with noise added)."""
        values = check_samples(samples)
        if values.shape != self.samples.shape:
            raise WaveformError("samples", f"{values.size} samples replace {self.n}",
                                "as many samples as the waveform has")
        return Waveform(self.t0, self.dt, values, self.units, self.calibration, self.metadata)

    def with_metadata(self, **items: Any) -> Waveform:
        """A copy with extra or replaced metadata entries."""
        meta = {**self.metadata, **items}
        return Waveform(self.t0, self.dt, self.samples, self.units, self.calibration, meta)

    def to_dict(self) -> dict[str, Any]:
        """The shot as the REST service accepts it (``POST /v1/measurements``, one of ``shots``).

        The service's metadata keys are typed as its schema types them (``plate_id`` and
        ``position`` as text, ``sphere_diameter`` as a number, ``shot`` as a whole number >= 0);
        every other entry (``channel``, ``snr_db``, ...) goes under ``metadata.extra`` as a
        scalar, with lists and mappings as JSON text. The service reserves ``source`` and
        ``shot`` there, so ``source`` travels as ``extra.source_file`` and a shot label that is
        not a whole number as ``extra.shot_label``. :func:`solitonde.signal.io.from_json` reads
        it back.
        """
        meta: dict[str, Any] = {}
        extra: dict[str, Any] = {}
        for key, value in self.metadata.items():
            value = _jsonable(value)
            if key in ("plate_id", "position"):
                if value is not None:
                    meta[key] = str(value)
            elif key == "sphere_diameter":
                if value is not None:
                    meta[key] = _finite_float("metadata.sphere_diameter", value)
            elif key == "shot" and isinstance(value, int) and not isinstance(value, bool) \
                    and 0 <= value <= MAX_SHOT:
                meta[key] = value
            elif key in EXTRA_RENAMED:
                extra.setdefault(EXTRA_RENAMED[key], _scalar(value))
            else:
                extra[str(key)] = _scalar(value)
        if len(extra) > MAX_EXTRA:
            raise WaveformError("metadata.extra", f"{len(extra)} free-form entries",
                                f"at most {MAX_EXTRA} (the service's limit)")
        meta["extra"] = extra
        return {
            "t0": self.t0,
            "dt": self.dt,
            "samples": self.samples.tolist(),
            "units": self.units,
            "calibration": self.calibration,
            "metadata": meta,
        }


MAX_SHOT = 2**31
"""Largest shot number the service's schema accepts as ``metadata.shot``."""
EXTRA_RENAMED = {"source": "source_file", "shot": "shot_label"}
"""Names under ``metadata.extra`` of the entries the service reserves there."""
MAX_EXTRA = 50
"""Most free-form metadata entries the service accepts (``metadata.extra``)."""


def _scalar(value: Any) -> Any:
    """A free-form metadata value as a JSON scalar the service keeps as given."""
    if value is None or isinstance(value, str | bool | int):
        return value
    if isinstance(value, float):
        return value if np.isfinite(value) else str(value)
    return json.dumps(value, allow_nan=True, default=str)


def _jsonable(value: Any) -> Any:
    """Metadata made JSON-safe: numpy scalars and arrays become Python numbers and lists."""
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value
