"""What an inspection report holds (``report.json``): one plate's measurements, their map, the
instrument and model they were computed with, and the digest a reviewer checks later.

Built from stored measurements (the service's store, or a temporary one that ``report build
--manifest`` fills through the upload's own road), so a report made from a service and one made
offline from the same recordings hold the same numbers. Rendering (HTML, PDF) is
:mod:`.render`'s; this module only gathers and arranges.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NotRequired, TypedDict, cast

from solitonde.instrument.inference.calibration import CalibrationDict
from solitonde.instrument.inference.plate_map import MapOverview, MapPosition, PlateMap
from solitonde.instrument.inference.setups import SetupDict, SetupReference
from solitonde.instrument.reports import digest
from solitonde.instrument.reports.digest import DigestItem
from solitonde.instrument.tables.family import Family

FORMAT = "solitonde-report/1"
"""The version of report.json's layout."""

SHOT_KEYS = ("tof_s", "arr", "tof_peak_s", "arr_peak", "snr_db", "flags")
"""A shot's numbers the report lists."""


@dataclass(frozen=True)
class Trace:
    """One recorded shot to draw, with its measured features."""

    measurement_id: Any
    shot_index: int
    t0: float
    dt: float
    samples: Any
    features: Mapping[str, Any]


class DigestEntry(DigestItem):
    """A measurement's digest entry (:class:`.digest.DigestItem`) with its own digest."""

    digest: str


class DataDigest(TypedDict):
    algorithm: str
    value: str


class ReportShot(TypedDict):
    """A shot's numbers as a report lists them (:data:`SHOT_KEYS`), each None if not read."""

    measurement_id: int
    shot_index: int
    tof_s: float | None
    arr: float | None
    tof_peak_s: float | None
    arr_peak: float | None
    snr_db: float | None
    flags: list[str] | None


class TraceRef(TypedDict):
    measurement_id: int
    shot_index: int


class ReportPosition(MapPosition, total=False):
    """A map position with its shots' numbers and the shot drawn for it (None if none)."""

    shots: list[ReportShot]
    trace: TraceRef | None


class ReportTable(TypedDict):
    """The table the newest estimate used, and (where it is loaded) what it holds."""

    id: str
    sha256: str | None
    family: Family | None
    reading_version: int | None
    loaded_sha256: NotRequired[str | None]


class Report(TypedDict):
    """report.json, in the order it is written (``content_digest`` last)."""

    format: str
    plate_id: str
    generated_at: str
    software_version: str
    source: dict[str, str]
    labels: dict[str, str | float]
    setups: list[SetupDict | SetupReference]
    chain_calibrations: list[CalibrationDict]
    table: ReportTable | None
    map: MapOverview
    positions: list[ReportPosition]
    measurements: list[DigestEntry]
    digest: DataDigest
    content_digest: NotRequired[DataDigest]


def entries(records: Sequence[Any]) -> list[DigestEntry]:
    """Each stored measurement's digest entry (:func:`.digest.entry`) with its own digest."""
    out: list[DigestEntry] = []
    for r in records:
        item = digest.entry(r.id, r.position, [s.sha256 for s in r.shots], r.result)
        out.append({**item, "digest": digest.entry_digest(item)})
    return out


def without_digest(entry: Mapping[str, Any]) -> DigestItem:
    """A digest entry less its own digest (every other key it holds, as read)."""
    return cast(DigestItem, {k: v for k, v in entry.items() if k != "digest"})


def _positions(plate_map: PlateMap, records: Sequence[Any]) -> list[ReportPosition]:
    """The map's positions, each with its shots' numbers and its measurements' warnings."""
    by_id = {r.id: r for r in records}
    out: list[ReportPosition] = []
    for p in plate_map["positions"]:
        members = [by_id[i] for i in p.get("measurement_ids", []) if i in by_id]
        shots = [cast(ReportShot, {"measurement_id": m.id, "shot_index": s.shot_index,
                                   **{k: s.features.get(k) for k in SHOT_KEYS}})
                 for m in members for s in m.shots]
        out.append({**p, "shots": shots})
    return out


def _table(records: Sequence[Any], tables: Any) -> ReportTable | None:
    """The table the newest estimate used: id, SHA-256, family, extractor reading."""
    for r in reversed(records):
        table = (r.result.get("provenance") or {}).get("table")
        if table:
            loaded = tables.by_id.get(table["id"]) if tables is not None else None
            info: ReportTable = {"id": table["id"], "sha256": table.get("sha256"),
                                 "family": None, "reading_version": None}
            if loaded is not None:
                info["family"] = loaded.model.family
                info["reading_version"] = loaded.model.reading_version
                info["loaded_sha256"] = loaded.model.content_sha256
            return info
    return None


def build(plate_id: str, records: Sequence[Any], plate_map: PlateMap, *,
          tables: Any = None, setups: Mapping[tuple[str, int], SetupDict] | None = None,
          software_version: str, source: Mapping[str, str],
          traces: Callable[[Any], Trace | None] | None = None,
          ) -> tuple[Report, list[Trace]]:
    """report.json for ``plate_id`` and the traces to draw (one per position: its newest
    measurement's first shot).

    ``records``: the plate's stored measurements, oldest first, each with its shots (their
    ``sha256``, metadata and features); ``plate_map``: their map (with the joint answer and
    suggestions where asked for); ``setups``: the set-up revisions the measurements name, by
    (id, revision); ``source``: where the data came from (a service's URL, a store's path, a
    manifest), for ``report verify``; ``traces(measurement)``: its first shot, or None."""
    items = entries(records)
    setups = dict(setups or {})
    named: list[SetupDict | SetupReference] = []
    labels: dict[str, str | float] = {}  # the named set-ups' labels, a later one's winning
    for r in records:
        ref: SetupReference | None = (r.result.get("provenance") or {}).get("setup")
        if ref and (ref["id"], ref["revision"]) not in [(s["id"], s["revision"]) for s in named]:
            found = setups.get((ref["id"], ref["revision"]))
            named.append(ref.copy() if found is None else found.copy())
            if found is not None:
                labels.update(found["labels"] or {})
    positions = _positions(plate_map, records)
    drawn: list[Trace] = []
    if traces is not None:
        by_id = {r.id: r for r in records}
        for p in positions:
            ids = p.get("measurement_ids") or []
            trace = traces(by_id[ids[-1]]) if ids and ids[-1] in by_id else None
            p["trace"] = None if trace is None else {"measurement_id": trace.measurement_id,
                                                     "shot_index": trace.shot_index}
            if trace is not None:
                drawn.append(trace)
    report: Report = {
        "format": FORMAT,
        "plate_id": plate_id,
        "generated_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "software_version": software_version,
        "source": dict(source),
        "labels": labels,
        "setups": named,
        "chain_calibrations": _calibrations(records),
        "table": _table(records, tables),
        "map": cast(MapOverview, {k: v for k, v in plate_map.items() if k != "positions"}),
        "positions": positions,
        "measurements": items,
        "digest": {"algorithm": digest.ALGORITHM,
                   "value": digest.data_digest(
                       [without_digest(e) for e in items])},
    }
    report["content_digest"] = {"algorithm": digest.ALGORITHM, "value": content_digest(report)}
    return report, drawn


def content_digest(report: Mapping[str, Any]) -> str:
    """The SHA-256 of everything report.json holds but this digest itself (the positions'
    answers, the map, the set-ups, the calibrations, the table, the date): an edited report
    no longer matches it. Unlike the data digest, it is the report's own, not the store's."""
    import hashlib

    body = {k: v for k, v in report.items() if k != "content_digest"}
    return hashlib.sha256(digest.canonical(body)).hexdigest()


def _calibrations(records: Sequence[Any]) -> list[CalibrationDict]:
    """The distinct chain calibrations the measurements were estimated with."""
    found: list[CalibrationDict] = []
    for r in records:
        cal = (r.result.get("provenance") or {}).get("chain_calibration")
        if cal is not None and cal not in found:
            found.append(cal)
    return found


def verify_entries(report: Mapping[str, Any]) -> str | None:
    """Why a report's own data do not match its printed digest (an edited report.json), or
    None where they do."""
    items = [without_digest(e) for e in report["measurements"]]
    for e, item in zip(report["measurements"], items, strict=True):
        if digest.entry_digest(item) != e["digest"]:
            return f"measurement {e['id']}'s data differ from its digest in the report"
    if digest.data_digest(items) != report["digest"]["value"]:
        return "the report's data differ from its digest"
    if content_digest(report) != (report.get("content_digest") or {}).get("value"):
        return ("the report's content (answers, map, set-up, calibration, table) differs from "
                "its content digest")
    return None
