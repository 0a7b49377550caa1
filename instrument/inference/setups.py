"""An instrument set-up: the chain's sphere sizes, the table of the plate family it measures,
its chain calibration and labels, as one record every door applies the same way.

A lab configures its instrument once: the spheres it mounts, the table its plates are read
against, a calibration fitted on a reference plate. A :class:`Setup` holds one *revision* of that
(revisions are immutable; a new calibration or a new size is a new revision) and
:meth:`Setup.apply` turns a shot's metadata into what the measured-shot road reads: the sphere
size filled in where the shot has none (a set-up of one size), the set-up's table named, and a
shot whose own size or table contradicts the set-up refused with both named.

The service keeps set-ups (``/v1/setups``, :mod:`solitonde.instrument.service.setup_book`);
``GET /v1/setups/{id}`` saved as a file is one revision, which ``analyze --setup FILE`` reads
offline with :meth:`Setup.load`.

"Chain calibration" is the chain's damping, ARR factor and TOF offset
(:class:`~.calibration.Calibration`), never a sensor's N/V factor (a shot's ``calibration``).
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NotRequired, TypedDict, cast

from solitonde.instrument.errors import InstrumentError
from solitonde.instrument.inference.calibration import (
    Calibration,
    CalibrationDict,
    CalibrationError,
)
from solitonde.instrument.inference.sizes import size_problem

SETUP_ID_MAX = 128
"""Longest set-up id."""
SAME_SIZE_REL = 0.01
"""Two sphere sizes within 1 % are the same size (as a table's and a calibration's are)."""

FIELDS = ("id", "revision", "created_at", "sphere_diameters_m", "table", "plate_material",
          "chain", "striker", "labels", "chain_calibration", "calibration_source")
"""The keys of a set-up revision, in the order it is written."""
INPUT_FIELDS = ("id", "sphere_diameters_m", "table", "plate_material", "chain", "striker",
                "labels")
"""What a client states when it creates or revises a set-up (the rest the service sets)."""


class SetupReference(TypedDict):
    """What a measurement's provenance names of its set-up."""

    id: str
    revision: int


class ReferenceRow(TypedDict):
    """Stored measurements on a reference plate, its thickness and the chain's distance to the
    support there (as a calibration fitted on them records them)."""

    measurement_ids: list[int]
    thickness_m: float
    distance_m: float


class CalibrationSource(TypedDict):
    """Where a set-up's chain calibration came from: a calibration file (``file``, with the
    file's own ``reference``) or a fit on stored reference measurements (``references``)."""

    kind: str
    reference: NotRequired[dict[str, Any] | None]
    """The file's ``reference``, kept as the file states it."""
    references: NotRequired[list[ReferenceRow]]


class SetupDict(TypedDict):
    """A set-up revision's JSON form (:meth:`Setup.to_dict`), the keys of :data:`FIELDS`."""

    id: str
    revision: int
    created_at: float | None
    sphere_diameters_m: list[float]
    table: str
    plate_material: Any  # a library name or a property mapping, as stated
    chain: dict[str, Any] | None  # kept as the client states it
    striker: dict[str, Any] | None  # likewise
    labels: dict[str, str | float] | None
    chain_calibration: CalibrationDict | None
    calibration_source: CalibrationSource | None


class SetupError(InstrumentError):
    """A set-up that cannot be used, or a shot that contradicts its set-up; ``field`` names
    what is wrong (the set-up's field, or the shot's)."""


def _identifier(value: Any, name: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise SetupError(name, f"{value!r} is not an id", "printable text, not blank, at most "
                         f"{SETUP_ID_MAX} characters")
    if len(value) > SETUP_ID_MAX or not value.isprintable():
        raise SetupError(name, f"{value[:40]!r}... is not an id" if len(value) > 40 else
                         f"{value!r} holds a control character" if not value.isprintable()
                         else f"{value!r} is not an id",
                         f"printable text, not blank, at most {SETUP_ID_MAX} characters")
    return value


ROUTE_SUFFIXES = re.compile(r"(^|/)(calibration|revisions/\d+|revisions)$")
"""The ends of a set-up id that its routes would read as a route (``/calibration``,
``/revisions/2``): refused, since a ``/`` in a URL cannot be told from one in the id."""


def _setup_id(value: Any) -> str:
    text = _identifier(value, "id")
    if ROUTE_SUFFIXES.search(text):
        raise SetupError("id", f"{text!r} ends as a route of the set-up API does",
                         "an id not ending in /calibration, /revisions or /revisions/N")
    return text


def _sizes(value: Any, name: str) -> tuple[float, ...]:
    if not isinstance(value, Sequence) or isinstance(value, str) or not value:
        raise SetupError(name, f"{value!r} is not a list of sizes",
                         "a list of sphere diameters in metres, e.g. [9.53e-3]")
    sizes: list[float] = []
    for i, d in enumerate(value):
        problem = size_problem(d)
        if problem is not None:
            raise SetupError(f"{name}[{i}]", problem)
        if any(abs(float(d) - s) <= SAME_SIZE_REL * s for s in sizes):
            raise SetupError(f"{name}[{i}]", f"{d!r} m is listed twice")
        sizes.append(float(d))
    return tuple(sizes)


def _mapping(value: Any, name: str) -> dict[str, Any] | None:
    """A free-form JSON object a set-up keeps as stated (``chain``, ``striker``, ...)."""
    if value is None:
        return None
    if not isinstance(value, Mapping):
        raise SetupError(name, f"expected a mapping, got {type(value).__name__}")
    try:
        json.dumps(value, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise SetupError(name, f"not JSON: {exc}") from None
    return dict(value)


def _labels(value: Any) -> dict[str, str | float] | None:
    """``labels``: a JSON object whose values are text or numbers."""
    labels = _mapping(value, "labels")
    if labels is not None:
        for key, label in labels.items():
            if not isinstance(label, str | int | float) or isinstance(label, bool):
                raise SetupError(f"labels.{key}", f"{label!r} is not a label",
                                 "text or a number")
    return labels


def _chain_calibration(value: Any) -> CalibrationDict | None:
    """``chain_calibration`` checked and written back in the calibration file's form."""
    try:
        calibration = Calibration.from_any(value)
    except CalibrationError as exc:
        raise SetupError(f"chain_calibration.{exc.field}", exc.full_message) from None
    return None if calibration is None else calibration.to_dict()


@dataclass(frozen=True)
class Setup:
    """One revision of an instrument set-up (see the module docstring)."""

    id: str
    sphere_diameters_m: tuple[float, ...]
    table: str
    revision: int = 0
    """0 for a set-up not yet stored (the service numbers revisions from 1)."""
    created_at: float | None = None
    plate_material: Any = None
    """The plate family's material (a library name or its properties), for the material
    spread; None: the table's."""
    chain: dict[str, Any] | None = None
    """The chain as mounted (material, n_particles, sensor_index ...), kept as stated."""
    striker: dict[str, Any] | None = None
    """The striker (drop_height ...), kept as stated."""
    labels: dict[str, str | float] | None = None
    """Operator, instrument serial, lab: what a report's title block names."""
    chain_calibration: CalibrationDict | None = None
    """The chain calibration (:class:`~.calibration.Calibration`'s dict), or None."""
    calibration_source: CalibrationSource | None = None
    """Where the calibration came from: the reference measurements, or an uploaded file (its
    own provenance), kept as stored."""

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], *, inputs_only: bool = False) -> Setup:
        """A set-up from its JSON form (a client's request, a stored revision, or a saved
        ``GET /v1/setups/{id}``, whose ``revisions`` and ``links`` are ignored).

        ``inputs_only``: a client's request, which may state only :data:`INPUT_FIELDS`.
        SetupError naming the field for anything else."""
        if not isinstance(data, Mapping):
            raise SetupError("setup", f"expected a JSON object, got {type(data).__name__}")
        allowed = INPUT_FIELDS if inputs_only else (*FIELDS, "revisions", "links")
        for key in data:
            if key not in allowed:
                raise SetupError(str(key), "unknown field" if key not in FIELDS else
                                 "is set by the service", f"one of {', '.join(allowed)}")
        for key in ("id", "sphere_diameters_m", "table"):
            if data.get(key) is None:
                raise SetupError(key, "missing", {
                    "id": "the set-up's name, e.g. \"lab-a-chain-1\"",
                    "sphere_diameters_m": "the sphere diameters in metres, e.g. [9.53e-3]",
                    "table": "the id of the table its plates are read against"}[key])
        calibration = _chain_calibration(data.get("chain_calibration"))
        revision = data.get("revision", 0)
        if isinstance(revision, bool) or not isinstance(revision, int) or revision < 0:
            raise SetupError("revision", f"{revision!r} is not a revision number")
        created = data.get("created_at")
        if created is not None and not (isinstance(created, int | float)
                                        and math.isfinite(created)):
            raise SetupError("created_at", f"{created!r} is not a time (Unix seconds)")
        labels = _labels(data.get("labels"))
        return cls(
            id=_setup_id(data["id"]),
            sphere_diameters_m=_sizes(data["sphere_diameters_m"], "sphere_diameters_m"),
            table=_identifier(data["table"], "table"),
            revision=revision,
            created_at=None if created is None else float(created),
            plate_material=data.get("plate_material"),
            chain=_mapping(data.get("chain"), "chain"),
            striker=_mapping(data.get("striker"), "striker"),
            labels=labels,
            chain_calibration=calibration,
            calibration_source=cast(CalibrationSource | None, _mapping(
                data.get("calibration_source"), "calibration_source")),
        )

    @classmethod
    def load(cls, path: str | Path) -> Setup:
        """A set-up saved as a file (``GET /v1/setups/{id}``'s answer, one revision)."""
        path = Path(path)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except OSError as exc:
            raise SetupError("setup", f"cannot read {str(path)!r}: {exc.strerror}") from None
        except json.JSONDecodeError as exc:
            raise SetupError("setup", f"{path.name} is not JSON: {exc}") from None
        try:
            return cls.from_dict(data)
        except SetupError as exc:
            raise SetupError(f"setup.{exc.field}", f"{exc.full_message} (in {path.name})") \
                from None

    def to_dict(self) -> SetupDict:
        """The JSON form, every field of :data:`FIELDS` in order."""
        return {"id": self.id, "revision": self.revision, "created_at": self.created_at,
                "sphere_diameters_m": list(self.sphere_diameters_m), "table": self.table,
                "plate_material": self.plate_material, "chain": self.chain,
                "striker": self.striker, "labels": self.labels,
                "chain_calibration": self.chain_calibration,
                "calibration_source": self.calibration_source}

    def reference(self) -> SetupReference:
        """What a measurement's provenance names: ``{"id", "revision"}``."""
        return {"id": self.id, "revision": self.revision}

    def calibration(self) -> Calibration | None:
        """The chain calibration the inversion applies, or None."""
        return Calibration.from_any(self.chain_calibration)

    def size_of(self, diameter_m: float) -> float | None:
        """The set-up's size within 1 % of ``diameter_m``, or None."""
        return next((s for s in self.sphere_diameters_m
                     if abs(s - diameter_m) <= SAME_SIZE_REL * s), None)

    def apply(self, metadata: Sequence[Mapping[str, Any]],
              field_of: Callable[[int, str], str]) -> list[dict[str, Any]]:
        """Each shot's metadata as the set-up completes it: its sphere size where it states
        none (a set-up of one size), the set-up's table, its plate material where none is
        stated. A shot whose size is not one of the set-up's, or whose table is another, is a
        SetupError naming the shot's field and the set-up's."""
        where = f"setup {self.id!r} (revision {self.revision})"
        out = []
        for i, meta in enumerate(metadata):
            meta = dict(meta)
            d = meta.get("sphere_diameter")
            if d is None:
                if len(self.sphere_diameters_m) != 1:
                    sizes = ", ".join(f"{s:g}" for s in self.sphere_diameters_m)
                    raise SetupError(field_of(i, "sphere_diameter"), f"missing, and {where} "
                                     f"mounts several sizes (sphere_diameters_m {sizes} m)",
                                     "the shot's sphere size, one of the set-up's")
                meta["sphere_diameter"] = self.sphere_diameters_m[0]
            elif self.size_of(float(d)) is None:
                sizes = ", ".join(f"{s:g}" for s in self.sphere_diameters_m)
                raise SetupError(field_of(i, "sphere_diameter"), f"{float(d):g} m contradicts "
                                 f"{where}: its sphere_diameters_m are {sizes} m",
                                 "one of the set-up's sizes, or no setup")
            stated = meta.get("table")
            if stated is not None and stated != self.table:
                raise SetupError(field_of(i, "table"), f"{stated!r} contradicts {where}, whose "
                                 f"table is {self.table!r}", "the set-up's table, or no setup")
            meta["table"] = self.table
            if self.plate_material is not None and meta.get("plate_material") is None:
                meta["plate_material"] = self.plate_material
            out.append(meta)
        return out
