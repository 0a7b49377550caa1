"""Recompute stored measurements with the current software and tables, keeping the old results.

A table rebuild or a fix of the feature extractor should reach the measurements already taken:
:func:`reanalyze` reads each stored measurement's traces (lossless, checked against their
SHA-256), runs them through the same road as a new upload (:func:`.ingest.compute_result`:
features, aggregates, table choice, estimate, provenance) and makes that the newest result. The
result it replaces, with each shot's features, moves to the store's ``earlier_results``; the API
serves the newest and lists the others.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal, TypedDict

from solitonde.instrument.inference.setups import Setup
from solitonde.instrument.inference.table_set import TableSet
from solitonde.instrument.service.ingest import (
    apply_setup,
    compute_result,
    waveforms_from_records,
)
from solitonde.instrument.service.measurement_json import StoredResult
from solitonde.instrument.service.problems import Problem
from solitonde.instrument.service.store import Store
from solitonde.signal.errors import WaveformError


class Brief(TypedDict):
    """What a summary line shows of one result."""

    table: str | None
    table_sha256: str | None
    software_version: str | None
    thickness_m: float | None
    """The thickness's MAP, m."""
    estimate_reason: str | None


class Recomputed(TypedDict):
    """A measurement recomputed: its result before and after."""

    id: int
    plate_id: str | None
    position: str | None
    before: Brief
    after: Brief
    earlier_results: int
    """How many earlier results it keeps now."""


class Refused(TypedDict):
    """A measurement the current version refuses, and why; its result is kept."""

    id: int
    reason: str


class Reanalysis(TypedDict):
    reanalyzed: list[Recomputed]
    failed: list[Refused]


def _brief(result: StoredResult) -> Brief:
    """The parts of a result a summary line shows: table (id, hash), thickness MAP, version."""
    prov = result.get("provenance")
    table = prov.get("table") if prov else None
    est = result.get("estimate")
    thickness = est["thickness_m"].get("map") if est and est.get("thickness_m") else None
    return {"table": result.get("table"), "table_sha256": table.get("sha256") if table else None,
            "software_version": prov.get("software_version") if prov else None,
            "thickness_m": thickness,
            "estimate_reason": result.get("estimate_reason")}


def setup_of(store: Store, measurement_id: int) -> Setup | None:
    """The set-up revision a measurement was estimated with, or None."""
    from solitonde.instrument.service import setup_book

    rows = store.rows("SELECT setup_id, revision FROM setup_uses WHERE measurement_id = ?",
                      (measurement_id,))
    return setup_book.revision(store, rows[0][0], rows[0][1]) if rows else None


def recompute(store: Store, tables: TableSet, measurement_id: int,
              setup: Setup | Literal["recorded"] | None = "recorded") -> Recomputed | None:
    """Recompute one measurement through the upload's road and make that its newest result,
    keeping the earlier one; the summary line, or None when it was deleted meanwhile.

    ``setup``: the set-up revision to estimate with; ``"recorded"`` (the default) the one the
    measurement names, if any. Problem or WaveformError where the current version refuses it
    (nothing is changed then)."""
    record = store.get(measurement_id, with_samples=True)
    if record is None:
        return None
    if setup == "recorded":
        setup = setup_of(store, measurement_id)
    waveforms = apply_setup(waveforms_from_records(record.shots), setup, "shots")
    shots, result = compute_result(waveforms, tables, "shots", setup=setup)
    if "location" in record.result and "location" not in result:
        result["location"] = record.result["location"]
    store.replace_result(record.id, result, [s["features"] for s in shots],
                         None if setup is None else (setup.id, setup.revision))
    return {"id": record.id, "plate_id": record.plate_id, "position": record.position,
            "before": _brief(record.result), "after": _brief(result),
            "earlier_results": len(record.earlier) + 1}


def reanalyze(store: Store, tables: TableSet, plate_id: str | None = None,
              progress: Callable[[Recomputed], None] | None = None) -> Reanalysis:
    """Recompute every measurement (of ``plate_id``, or all) and keep the earlier results; each
    with the set-up revision it names.

    A measurement the current version refuses (its metadata no longer accepted, no table that
    fits) keeps its result untouched and is listed under ``failed`` with the reason."""
    done: list[Recomputed] = []
    failed: list[Refused] = []
    after = 0
    while True:
        page = store.list(plate_id=plate_id, after_id=after, limit=200)
        if not page:
            break
        for summary in page:
            after = summary.id
            try:
                line = recompute(store, tables, summary.id)
            except Problem as exc:
                failed.append({"id": summary.id, "reason": exc.detail})
                continue
            except WaveformError as exc:
                failed.append({"id": summary.id, "reason": str(exc)})
                continue
            if line is None:  # deleted meanwhile
                continue
            done.append(line)
            if progress is not None:
                progress(line.copy())
    return {"reanalyzed": done, "failed": failed}
