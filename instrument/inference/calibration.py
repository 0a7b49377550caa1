"""Calibration of the model to an experiment: the chain's damping, an ARR factor and a TOF offset
per sphere size.

Real chains lose energy the elastic model does not (contact damping, friction, plasticity): the
measured ARR sits below the simulated one, and by how much depends on the plate. With
Kuwabara-Kono damping the loss is 7.7 % of ARR on a 5.5 mm aluminium plate far from the supports
but 2-5 % on 2.4-3.0 mm ones, and a thin plate's reflection moves by up to tens of microseconds
(docs/explanation/inversion.md, "Dissipation"): one factor and offset fitted on one plate do not
carry to another. So where the table has a dissipation layer (instrument.tables.dissipation:
the sweep simulated again with damping), a calibration first fits the chain's Kuwabara-Kono
time constant ``damping_s`` (with ``damping_std_s``) and the inversion reads the table at it
(:func:`calibrated_table`); the ARR factor and TOF offset then hold what damping leaves (about 1
and 0 for a chain whose losses are contact damping). Without the layer, the factor and offset are
the whole calibration, as before.

Shots on a reference plate of known thickness and position give them: with the model's (TOF,
ARR) there from the table (read at the fitted damping),

    arr_factor = ARR_measured / ARR_model,    tof_offset_s = TOF_measured - TOF_model

per sphere size (inverse-variance means when several references are given; the fit is in
:mod:`.calibration_fit`). Several references of a size also state the spread between them as a
transfer uncertainty. The inversion then compares ``arr_factor * ARR_model`` and ``TOF_model +
tof_offset_s`` with new measurements. Stored as JSON (written to a temporary name, then renamed).

Next to a clamped support the model's mismatch is not the one far away (a TOF offset of +3 to +7
us within a few centimetres of the clamp against +3.5 us far from it): references at two or more
distances give a size's factor and offset per distance (``by_distance``), and the inversion reads
them at each cell's distance (:meth:`Calibration.along`: piecewise linear in 1/L between the
references' distances, constant beyond them).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Required, TypedDict, cast

import numpy as np

from solitonde.instrument.errors import InstrumentError
from solitonde.instrument.inference.shot_scatter import ShotScatter
from solitonde.instrument.tables.dissipation import damped
from solitonde.instrument.tables.table import ModelTable
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


class DistanceRow(TypedDict, total=False):
    """A sphere size's ARR factor and TOF offset at one reference distance (``by_distance``)."""

    distance_m: Required[float]
    arr_factor: Required[float]
    tof_offset_s: Required[float]
    arr_factor_std: float
    tof_offset_std_s: float
    n_references: int


class DiameterEntry(TypedDict, total=False):
    """One sphere size's calibration: its ARR factor and TOF offset over all its references,
    their uncertainties (``*_transfer_*``: the part from the references' disagreement), the
    chain's fitted damping, and the rows per reference distance."""

    arr_factor: Required[float]
    tof_offset_s: Required[float]
    arr_factor_std: float
    arr_factor_transfer_std: float
    tof_offset_std_s: float
    tof_offset_transfer_std_s: float
    n_references: int
    damping_s: float
    damping_std_s: float
    shot_tof_rel_std: float
    shot_arr_std: float
    shot_scatter_dof: int
    """The references' per-shot scatter pooled (TOF relative, ARR absolute) and its degrees of
    freedom: the rig's repeatability, which a single shot takes (:mod:`.shot_scatter`)."""
    by_distance: list[DistanceRow]


class DiameterRecord(DiameterEntry, total=False):
    """A per-diameter entry as the calibration file lists it, its sphere size first."""

    diameter_m: Required[float]


class CalibrationDict(TypedDict):
    """A calibration as its JSON file holds it (:meth:`Calibration.to_dict`)."""

    arr_factor: float
    tof_offset_s: float
    per_diameter: list[DiameterRecord]
    reference: dict[str, Any] | None
    """Where the calibration came from, kept as the file states it (free-form)."""


DistanceKey = Literal["arr_factor", "tof_offset_s", "arr_factor_std", "tof_offset_std_s"]
"""What :func:`interpolate_by_distance` reads between a size's reference distances."""

Check = Callable[[str, Any], float]
"""A value's check: its field name and the value in, the number out (CalibrationError)."""

# what a per-diameter entry may hold (as fit_calibration writes it), each with its check;
# "by_distance" besides, checked by _by_distance
_PER_DIAMETER_KEYS: dict[str, Check] = {
    "arr_factor": _positive,
    "arr_factor_std": _nonnegative,
    "arr_factor_transfer_std": _nonnegative,
    "tof_offset_s": _finite,
    "tof_offset_std_s": _nonnegative,
    "tof_offset_transfer_std_s": _nonnegative,
    "n_references": _count,
    "damping_s": _nonnegative,
    "damping_std_s": _nonnegative,
    "shot_tof_rel_std": _nonnegative,
    "shot_arr_std": _nonnegative,
    "shot_scatter_dof": _count,
}

# what a by_distance row may hold; distance_m, arr_factor and tof_offset_s are required
_BY_DISTANCE_KEYS: dict[str, Check] = {
    "distance_m": _nonnegative,
    "arr_factor": _positive,
    "tof_offset_s": _finite,
    "arr_factor_std": _nonnegative,
    "tof_offset_std_s": _nonnegative,
    "n_references": _count,
}
_BY_DISTANCE_REQUIRED = ("distance_m", "arr_factor", "tof_offset_s")

MIN_DISTANCE_M = 1e-3
"""Distances below this (the clamp itself, 0, or a negative one) are read at it: the rule is
linear in 1/L, which must stay finite; a chain of spheres a few millimetres across stands no
closer to the clamp than about this in any sense the table resolves."""


def _by_distance(where: str, rows: Any) -> list[DistanceRow]:
    """A per-diameter entry's ``by_distance`` rows, checked: a list of at least two mappings,
    each with ``distance_m``, ``arr_factor``, ``tof_offset_s`` (stds and ``n_references``
    optional), sorted by distance, no two at the same distance once read at
    :data:`MIN_DISTANCE_M` or more."""
    if not isinstance(rows, Sequence) or isinstance(rows, str):
        raise CalibrationError(where, f"expected a list of rows, got {type(rows).__name__}")
    if len(rows) < 2:
        raise CalibrationError(where, f"needs at least two rows (one per reference distance), "
                               f"got {len(rows)}; leave by_distance out for one distance")
    out: list[DistanceRow] = []
    for j, row in enumerate(rows):
        at = f"{where}[{j}]"
        if not isinstance(row, Mapping):
            raise CalibrationError(at, f"expected a mapping, got {type(row).__name__}")
        for key in row:
            if key not in _BY_DISTANCE_KEYS:
                raise CalibrationError(f"{at}.{key}", "unknown key (allowed: "
                                       f"{list(_BY_DISTANCE_KEYS)})")
        for key in _BY_DISTANCE_REQUIRED:
            if row.get(key) is None:
                raise CalibrationError(f"{at}.{key}", "missing")
        # every key checked against _BY_DISTANCE_KEYS above, the required ones present
        checked = cast(DistanceRow, {key: check(f"{at}.{key}", row[key])
                                     for key, check in _BY_DISTANCE_KEYS.items()
                                     if row.get(key) is not None})
        if out and max(checked["distance_m"], MIN_DISTANCE_M) <= max(out[-1]["distance_m"],
                                                                      MIN_DISTANCE_M):
            raise CalibrationError(f"{at}.distance_m", f"{checked['distance_m']!r} m does not "
                                   f"exceed the previous row's {out[-1]['distance_m']!r} m (rows "
                                   f"sorted by distance, each distance once, at most one at "
                                   f"{MIN_DISTANCE_M:g} m or less)")
        out.append(checked)
    return out


def interpolate_by_distance(rows: Sequence[DistanceRow], key: DistanceKey,
                            distance_m: Any) -> np.ndarray:
    """``rows[*][key]`` (0 where a row does not state it) at ``distance_m``: piecewise linear in
    1/L between the rows' distances, constant below the first and beyond the last.

    Why 1/L: the near-field mismatch a clamp adds fades with the distance to it, fastest next to
    the clamp; linear in 1/L follows ``a + b / L`` exactly between two references and changes
    little between two far ones. Distances below :data:`MIN_DISTANCE_M` are read at it."""
    inv = 1.0 / np.maximum(np.asarray(distance_m, dtype=float), MIN_DISTANCE_M)
    # 1/L falls with L: the rows reversed give np.interp the rising abscissa it needs
    nodes = np.array([1.0 / max(r["distance_m"], MIN_DISTANCE_M) for r in reversed(rows)])
    values = np.array([float(r.get(key, 0.0)) for r in reversed(rows)])
    return np.interp(inv, nodes, values)


@dataclass(frozen=True)
class Calibration:
    """ARR factor and TOF offset: global, and optionally per sphere diameter.

    ``per_diameter`` maps a diameter in m to ``{"arr_factor": .., "tof_offset_s": ..}`` (plus
    optional uncertainties, the fitted damping, and ``by_distance``: the factor and offset at
    two or more reference distances, which :meth:`along` reads between); a sphere size not
    listed uses the global values. An entry's own ``arr_factor`` and ``tof_offset_s`` hold over
    all its references, for readers that know no distance.
    """

    arr_factor: float = 1.0
    tof_offset_s: float = 0.0
    per_diameter: dict[float, DiameterEntry] = field(default_factory=dict)
    reference: dict[str, Any] | None = None
    """Where the calibration came from (the references fitted, the table), kept as stated."""

    def _entry(self, diameter_m: float) -> DiameterEntry | None:
        for d, entry in self.per_diameter.items():
            if abs(d - diameter_m) <= 0.01 * d:
                return entry
        return None

    def by_distance(self, diameter_m: float) -> list[DistanceRow] | None:
        """A sphere size's rows per reference distance, or None where it has one set of values
        for every distance."""
        entry = self._entry(diameter_m)
        return None if entry is None else entry.get("by_distance")

    @property
    def has_by_distance(self) -> bool:
        return any("by_distance" in e for e in self.per_diameter.values())

    def along(self, diameter_m: float, distance_m: Any) -> tuple[Any, Any, Any, Any]:
        """(arr_factor, tof_offset_s, arr_factor_std, tof_offset_std_s) for a sphere size at the
        distances ``distance_m`` (m; a number or an array).

        With ``by_distance`` each is an array of ``distance_m``'s shape (broadcasting with it as
        the distance did): piecewise linear in 1/L between the rows' distances, constant beyond
        the first and the last (:func:`interpolate_by_distance`; a near-field mismatch that
        fades with the distance to the clamp). Without it, the size's plain numbers (those of
        :meth:`for_diameter` and :meth:`uncertainty_for`, floats) for every distance."""
        rows = self.by_distance(diameter_m)
        if rows is None:
            return (*self.for_diameter(diameter_m), *self.uncertainty_for(diameter_m))
        keys: tuple[DistanceKey, ...] = ("arr_factor", "tof_offset_s", "arr_factor_std",
                                         "tof_offset_std_s")
        f, o, f_sd, o_sd = (interpolate_by_distance(rows, key, distance_m) for key in keys)
        return f, o, f_sd, o_sd

    def for_diameter(self, diameter_m: float) -> tuple[float, float]:
        """(arr_factor, tof_offset_s) for a sphere size (over all its reference distances; see
        :meth:`along` for the values at a distance)."""
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

    def damping_for(self, diameter_m: float) -> tuple[float, float] | None:
        """(Kuwabara-Kono time constant s, its sd) fitted for a sphere size, or None where the
        calibration has none (fitted against a table without a dissipation layer)."""
        for d, entry in self.per_diameter.items():
            if abs(d - diameter_m) <= 0.01 * d:
                if "damping_s" not in entry:
                    return None
                return float(entry["damping_s"]), float(entry.get("damping_std_s", 0.0))
        return None

    def shot_scatter(self, diameter_m: float) -> ShotScatter | None:
        """The per-shot scatter measured on a sphere size's reference shots, or None where the
        calibration does not state it (all three keys)."""
        e = self._entry(diameter_m)
        if e is None or not all(k in e for k in ("shot_tof_rel_std", "shot_arr_std",
                                                 "shot_scatter_dof")):
            return None
        return {"shot_tof_rel_std": float(e["shot_tof_rel_std"]),
                "shot_arr_std": float(e["shot_arr_std"]),
                "shot_scatter_dof": int(e["shot_scatter_dof"])}

    def shot_scatter_by_size(self) -> dict[float, ShotScatter]:
        """:meth:`shot_scatter` of every sphere size that states it."""
        return {d: rig for d in self.per_diameter if (rig := self.shot_scatter(d)) is not None}

    @property
    def has_damping(self) -> bool:
        return any("damping_s" in e for e in self.per_diameter.values())

    def to_dict(self) -> CalibrationDict:
        return {
            "arr_factor": self.arr_factor,
            "tof_offset_s": self.tof_offset_s,
            "per_diameter": [_record(d, e) for d, e in sorted(self.per_diameter.items())],
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
        per: dict[float, DiameterEntry] = {}
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
                if key not in ("diameter_m", "by_distance") and key not in _PER_DIAMETER_KEYS:
                    allowed = ["diameter_m", *_PER_DIAMETER_KEYS, "by_distance"]
                    raise CalibrationError(f"{where}.{key}", f"unknown key (allowed: {allowed})")
            # every key checked against _PER_DIAMETER_KEYS above; the two required ones below
            rest = cast(DiameterEntry, {
                key: check(f"{where}.{key}", entry[key])
                for key, check in _PER_DIAMETER_KEYS.items() if entry.get(key) is not None})
            rest.setdefault("arr_factor", 1.0)
            rest.setdefault("tof_offset_s", 0.0)
            if entry.get("by_distance") is not None:
                rest["by_distance"] = _by_distance(f"{where}.by_distance", entry["by_distance"])
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


def _record(diameter_m: float, entry: DiameterEntry) -> DiameterRecord:
    """``entry`` as the file lists it: its size first, its rows per distance copied."""
    record: DiameterRecord = {"diameter_m": diameter_m, **entry}
    if "by_distance" in entry:
        record["by_distance"] = [row.copy() for row in entry["by_distance"]]
    return record


def calibration_along(calibration: Calibration | None, diameter_m: float, distance_m: Any
                      ) -> tuple[Any, Any, Any, Any]:
    """(arr_factor, tof_offset_s, arr_factor_std, tof_offset_std_s) of a sphere size at the
    distances ``distance_m``, as :meth:`Calibration.along` gives them; without a calibration
    ``(1.0, 0.0, 0.0, 0.0)``. The inversion reads a size's calibration over its fine grid with
    ``distance_m`` the grid's distance axis as a row, ``grid.distance_m[None, :]``, so that the
    arrays broadcast over the (thickness, distance) cells."""
    if calibration is None:
        return 1.0, 0.0, 0.0, 0.0
    return calibration.along(diameter_m, distance_m)


def answer_distance(distance: Any) -> float | None:
    """Where an answer puts the chain (its distance estimate's median, else its MAP, else an
    end of its 95 % interval), to read a distance-dependent calibration at; None when it gives
    no number."""
    ci = getattr(distance, "ci95", None) or (None, None)
    for value in (getattr(distance, "median", None), getattr(distance, "map", None), *ci):
        if value is not None:
            return float(value)
    return None


def calibrated_table(table: ModelTable, calibration: Calibration | None) -> ModelTable:
    """The table as the calibration reads it: at the chain's fitted damping (per sphere size,
    :func:`~solitonde.instrument.tables.dissipation.damped`) when the calibration has one, else
    the table itself. A size the calibration does not list is read undamped.

    Raises
    ------
    CalibrationError
        (field ``damping_s``) When the calibration states a damping and the table has no
        dissipation layer to read it with.
    """
    if calibration is None or not calibration.has_damping:
        return table
    if table.dissipation is None:
        raise CalibrationError("damping_s", f"the calibration states the chain's damping, but "
                               f"table {table.table_id!r} has no dissipation layer to read it "
                               "with: calibrate against this table, or add the layer with "
                               "`solitonde table dissipation FILE`")
    taus, sds = [], []
    for d in table.axes["diameter_m"]:
        fitted = calibration.damping_for(float(d))
        taus.append(0.0 if fitted is None else fitted[0])
        sds.append(0.0 if fitted is None else fitted[1])
    return damped(table, taus, sds)
