"""Several model tables, one per plate family, and the rule that picks one for a measurement.

The service and the command line may hold tables for several families (the paper's aluminium
plate, a steel plate ...). A measurement names its table (``table``, an id) or its plate material
(``plate_material``, a library name); otherwise the tables that cover its sphere sizes are the
candidates, and more than one is an error listing them, never a guess. A measurement whose stated
plate material differs from the named table's is refused, naming the key.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, TypedDict

from solitonde.instrument.errors import InstrumentError
from solitonde.instrument.inference.loaded_table import LoadedTable
from solitonde.instrument.tables.family import Family, describe, differences
from solitonde.instrument.tables.table import TableSummary

log = logging.getLogger("solitonde.instrument")


class TableChoiceError(InstrumentError, ValueError):
    """No table, or more than one, fits a measurement; ``field`` names the metadata key."""


def table_files(paths: Iterable[Path]) -> list[Path]:
    """The table files given: files as they are, a folder's ``*.h5`` files in name order."""
    out: list[Path] = []
    for p in paths:
        out.extend(sorted(p.glob("*.h5")) if p.is_dir() else [p])
    return out


class TableListing(TypedDict):
    """One loaded table as ``GET /v1/tables`` lists it."""

    id: str
    path: str
    family: Family | None
    diameters_m: list[float]
    thickness_range_m: list[float]
    distance_range_m: list[float]
    complete: bool


class TableSet:
    """The loaded tables by id; with one table it behaves as that table's LoadedTable."""

    def __init__(self, paths: Sequence[str | Path | None], warm_up: bool = True) -> None:
        files = table_files(Path(p) for p in paths if p is not None)
        self.by_id: dict[str, LoadedTable] = {}
        self.problems: list[str] = []
        for f in files:
            est = LoadedTable(f, warm_up)
            if not est.loaded:
                self.problems.append(est.reason or f"model table {str(f)!r} not loaded")
                continue
            tid = est.model.table_id
            if tid in self.by_id:
                self.problems.append(f"model table {str(f)!r} has the id {tid!r} of "
                                     f"{str(self.by_id[tid].path)!r}; give it another "
                                     "(table build --id) or file name")
                continue
            self.by_id[tid] = est
        for p in self.problems:
            log.warning(p)
        if not files:
            self.problems.append("no model table configured (start with --table FILE)")

    # --- what the routes ask of "the estimator" ------------------------------------------------
    @property
    def loaded(self) -> bool:
        return bool(self.by_id)

    @property
    def reason(self) -> str | None:
        return None if self.loaded else "; ".join(self.problems)

    @property
    def default(self) -> LoadedTable | None:
        return next(iter(self.by_id.values()), None)

    @property
    def path(self) -> Path | None:
        return self.default.path if self.default else None

    def summary(self) -> TableSummary | None:
        return self.default.summary() if self.default else None

    def plate_size(self) -> list[float] | None:
        """The plate size the tables share, or None when they differ or there is none."""
        sizes = {tuple(e.plate_size() or ()) for e in self.by_id.values()}
        return list(sizes.pop()) if len(sizes) == 1 and () not in sizes else None

    def listing(self) -> list[TableListing]:
        """Every table's id, family, sphere sizes and axes' ranges (``GET /v1/tables``)."""
        out: list[TableListing] = []
        for tid, est in self.by_id.items():
            t = est.model
            out.append({"id": tid, "path": str(est.path), "family": t.family,
                        "diameters_m": t.axes["diameter_m"].tolist(),
                        "thickness_range_m": [float(t.axes["thickness_m"][0]),
                                              float(t.axes["thickness_m"][-1])],
                        "distance_range_m": [float(t.axes["distance_m"][0]),
                                             float(t.axes["distance_m"][-1])],
                        "complete": t.complete})
        return out

    # --- choosing -------------------------------------------------------------------------------
    def choose(self, diameters: Iterable[float], table: str | None = None,
               plate_material: Any = None) -> LoadedTable:
        """The table for a measurement with these sphere sizes and what it says of itself.

        Raises TableChoiceError (field ``table`` or ``plate_material``) for an unknown id or
        material, a family mismatch, no table covering the sizes, or several that could serve.
        """
        from solitonde.model.materials import properties_from

        if not self.loaded:
            raise TableChoiceError("table", self.reason or "no model table loaded")
        stated: dict[str, dict[str, object]] = {}  # what the measurement says of its family
        if plate_material is not None:
            try:
                stated["plate_material"] = properties_from(plate_material)
            except ValueError as exc:
                raise TableChoiceError("plate_material", str(exc)) from None
        ids = ", ".join(self.by_id)
        if table is not None:
            est = self.by_id.get(str(table))
            if est is None:
                raise TableChoiceError("table", f"no table {table!r} (tables: {ids})")
            self._check_family(est, stated)
            return est
        sizes = [float(d) for d in diameters]
        candidates = [e for e in self.by_id.values() if _covers(e, sizes)
                      and not (stated and e.model.family and differences(stated, e.model.family))]
        if len(candidates) == 1:
            return candidates[0]
        if not candidates and not stated and len(self.by_id) == 1:
            return self.default  # type: ignore[return-value]  # its inversion names the size
        if not candidates:
            what = f"plate_material {describe(stated['plate_material'])}" if stated else \
                f"sphere sizes {', '.join(f'{d:g} m' for d in sizes)}"
            raise TableChoiceError("plate_material" if stated else "table",
                                   f"no table serves {what} (tables: {ids})")
        raise TableChoiceError("table", "more than one table could serve this measurement: "
                               f"{', '.join(e.model.table_id for e in candidates)}; name one "
                               "as table (a shot's metadata.table, an upload's or the raw "
                               "route's table field, post's --table), or give plate_material")

    @staticmethod
    def _check_family(est: LoadedTable, stated: Mapping[str, Any]) -> None:
        family = est.model.family
        if not stated or family is None:
            return
        keys = differences(stated, family)
        if keys:
            detail = "; ".join(f"{k}: measurement {describe(stated[k])}, table "
                               f"{describe(family.get(k))}" for k in keys)
            raise TableChoiceError(keys[0], f"table {est.model.table_id!r} was built for "
                                   f"another plate family ({detail}); it is not inverted")


def _covers(est: LoadedTable, diameters: Sequence[float]) -> bool:
    """Whether the table has every sphere size (within 1 % of its own size, the rule of
    :meth:`ModelTable.diameter_index`), or any when none is known."""
    have = est.model.axes["diameter_m"]
    return all(any(abs(h - d) <= 0.01 * h for h in have) for d in diameters)
