"""Calibration of the model to an experiment: an ARR factor and a TOF offset per sphere size.

Real chains lose energy the elastic model does not (contact damping, friction, plasticity): the
measured ARR sits below the simulated one, by a factor that depends on the sphere size and, less,
on the plate, and the reflection arrives a little late. One factor and offset per size is a first
order: the map study's dissipation lowers ARR by 7.7 % on a 5.5 mm plate and by 2-4 % where the
reflection is weak (ARR 0.15-0.23), and moves a thin plate's TOF by tens of microseconds
(docs/joint-map.md). Several references of a size state that spread as a transfer uncertainty,
two only part of it. Shots on a reference plate of known
thickness and position give both: with the model's (TOF, ARR) there from the table,

    arr_factor = ARR_measured / ARR_model,    tof_offset_s = TOF_measured - TOF_model

per sphere size (inverse-variance means when several references are given; the fit is in
:mod:`.calibration_fit`). The inversion then
compares ``arr_factor * ARR_model`` and ``TOF_model + tof_offset_s`` with new measurements. Stored
as JSON (written to a temporary name, then renamed).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from solitonde.instrument.errors import InstrumentError
from solitonde.signal.atomic import write_text


class CalibrationError(InstrumentError, ValueError):
    """A calibration that cannot be used; ``field`` names what is wrong."""



def _positive(name: str, value: Any) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise CalibrationError(name, f"expected a number, got {value!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise CalibrationError(name, f"must be a positive finite number, got {value!r}")
    return v


def _finite(name: str, value: Any) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise CalibrationError(name, f"expected a number, got {value!r}") from None
    if not math.isfinite(v):
        raise CalibrationError(name, f"must be finite, got {value!r}")
    return v


def _nonnegative(name: str, value: Any) -> float:
    v = _finite(name, value)
    if v < 0:
        raise CalibrationError(name, f"must be >= 0, got {value!r}")
    return v


def _count(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int | float) or not (
            math.isfinite(value) and float(value).is_integer() and value >= 1):
        raise CalibrationError(name, f"must be an integer >= 1, got {value!r}")
    return int(value)


# what a per-diameter entry may hold (as fit_calibration writes it), each with its check
_PER_DIAMETER_KEYS: dict[str, Any] = {
    "arr_factor": _positive,
    "arr_factor_std": _nonnegative,
    "arr_factor_transfer_std": _nonnegative,
    "tof_offset_s": _finite,
    "tof_offset_std_s": _nonnegative,
    "tof_offset_transfer_std_s": _nonnegative,
    "n_references": _count,
}


@dataclass(frozen=True)
class Calibration:
    """ARR factor and TOF offset: global, and optionally per sphere diameter.

    ``per_diameter`` maps a diameter in m to ``{"arr_factor": .., "tof_offset_s": ..}`` (plus
    optional uncertainties); a sphere size not listed uses the global values.
    """

    arr_factor: float = 1.0
    tof_offset_s: float = 0.0
    per_diameter: dict[float, dict[str, float]] = field(default_factory=dict)
    reference: dict[str, Any] | None = None

    def for_diameter(self, diameter_m: float) -> tuple[float, float]:
        """(arr_factor, tof_offset_s) for a sphere size."""
        for d, entry in self.per_diameter.items():
            if abs(d - diameter_m) <= 0.01 * d:
                return float(entry["arr_factor"]), float(entry["tof_offset_s"])
        return self.arr_factor, self.tof_offset_s

    def uncertainty_for(self, diameter_m: float) -> tuple[float, float]:
        """(arr_factor_std, tof_offset_std_s) for a sphere size; 0 when not stated."""
        for d, entry in self.per_diameter.items():
            if abs(d - diameter_m) <= 0.01 * d:
                return (float(entry.get("arr_factor_std", 0.0)),
                        float(entry.get("tof_offset_std_s", 0.0)))
        return 0.0, 0.0

    def to_dict(self) -> dict[str, Any]:
        return {
            "arr_factor": self.arr_factor,
            "tof_offset_s": self.tof_offset_s,
            "per_diameter": [{"diameter_m": d, **e} for d, e in sorted(self.per_diameter.items())],
            "reference": self.reference,
        }

    @classmethod
    def from_any(cls, data: Calibration | Mapping[str, Any] | None) -> Calibration | None:
        """From a Calibration, its dict (as :meth:`to_dict` writes, or just the two globals), or
        None."""
        if data is None or isinstance(data, Calibration):
            return data
        if not isinstance(data, Mapping):
            raise CalibrationError("calibration", f"expected a mapping, got {type(data).__name__}")
        known = {"arr_factor", "tof_offset_s", "per_diameter", "reference"}
        extra = set(data) - known
        if extra:
            raise CalibrationError(sorted(extra)[0], f"unknown key (allowed: {sorted(known)})")
        per: dict[float, dict[str, float]] = {}
        entries = data.get("per_diameter") or []
        if not isinstance(entries, Sequence) or isinstance(entries, str):
            raise CalibrationError("per_diameter", f"expected a list of entries, got "
                                   f"{type(entries).__name__}")
        for i, entry in enumerate(entries):
            where = f"per_diameter[{i}]"
            if not isinstance(entry, Mapping) or "diameter_m" not in entry:
                raise CalibrationError(where, "needs diameter_m, arr_factor, tof_offset_s")
            d = _positive(f"{where}.diameter_m", entry["diameter_m"])
            for key in entry:
                if key != "diameter_m" and key not in _PER_DIAMETER_KEYS:
                    raise CalibrationError(f"{where}.{key}", "unknown key (allowed: "
                                           f"{['diameter_m', *_PER_DIAMETER_KEYS]})")
            rest: dict[str, float] = {
                key: check(f"{where}.{key}", entry[key])
                for key, check in _PER_DIAMETER_KEYS.items() if entry.get(key) is not None}
            rest.setdefault("arr_factor", 1.0)
            rest.setdefault("tof_offset_s", 0.0)
            for other in per:
                if abs(other - d) <= 0.01 * other:
                    raise CalibrationError(f"{where}.diameter_m", f"{d!r} m is listed twice "
                                           f"(within 1 % of {other!r} m)")
            per[d] = rest
        return cls(_positive("arr_factor", data.get("arr_factor", 1.0)),
                   _finite("tof_offset_s", data.get("tof_offset_s", 0.0)), per,
                   data.get("reference"))

    def save(self, path: str | Path) -> Path:
        """Write as JSON through a temporary file that is renamed over ``path``.

        Raises
        ------
        CalibrationError
            (field ``path``) When ``path`` is a directory or cannot be written; the temporary
            file is removed again.
        """
        path = Path(path)
        if path.is_dir():
            raise CalibrationError("path", f"{str(path)!r} is a directory; give the name of "
                                   "the JSON file to write")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except (FileExistsError, NotADirectoryError):
            raise CalibrationError("path", f"cannot write {str(path)!r}: "
                                   f"{str(path.parent)!r} is not a folder") from None
        except OSError as exc:
            raise CalibrationError("path", f"cannot write {str(path)!r}: "
                                   f"{exc.strerror or exc}") from None
        try:
            write_text(path, json.dumps(self.to_dict(), indent=2) + "\n")
        except OSError as exc:
            raise CalibrationError("path", f"cannot write {str(path)!r}: "
                                   f"{exc.strerror or exc}") from None
        return path

    @classmethod
    def load(cls, path: str | Path) -> Calibration:
        path = Path(path)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except OSError as exc:
            raise CalibrationError("calibration",
                                   f"cannot read {str(path)!r}: {exc.strerror}") from None
        except json.JSONDecodeError as exc:
            raise CalibrationError("calibration", f"{path.name} is not JSON: {exc}") from None
        cal = cls.from_any(data)
        assert cal is not None
        return cal
