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
from typing import Any

from solitonde.instrument.reports import digest

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


def entries(records: Sequence[Any]) -> list[dict[str, Any]]:
    """Each stored measurement's digest entry (:func:`.digest.entry`) with its own digest."""
    out = []
    for r in records:
        item = digest.entry(r.id, r.position, [s.sha256 for s in r.shots], r.result)
        out.append({**item, "digest": digest.entry_digest(item)})
    return out


def _positions(plate_map: Mapping[str, Any], records: Sequence[Any]) -> list[dict[str, Any]]:
    """The map's positions, each with its shots' numbers and its measurements' warnings."""
    by_id = {r.id: r for r in records}
    out = []
    for p in plate_map["positions"]:
        members = [by_id[i] for i in p.get("measurement_ids", []) if i in by_id]
        shots = [{"measurement_id": m.id, "shot_index": s.shot_index,
                  **{k: s.features.get(k) for k in SHOT_KEYS}}
                 for m in members for s in m.shots]
        out.append({**p, "shots": shots})
    return out


def _table(records: Sequence[Any], tables: Any) -> dict[str, Any] | None:
    """The table the newest estimate used: id, SHA-256, family, extractor reading."""
    for r in reversed(records):
        table = (r.result.get("provenance") or {}).get("table")
        if table:
            loaded = tables.by_id.get(table["id"]) if tables is not None else None
            info = {"id": table["id"], "sha256": table.get("sha256"), "family": None,
                    "reading_version": None}
            if loaded is not None:
                info["family"] = loaded.model.family
                info["reading_version"] = loaded.model.reading_version
                info["loaded_sha256"] = loaded.model.content_sha256
            return info
    return None


def build(plate_id: str, records: Sequence[Any], plate_map: Mapping[str, Any], *,
          tables: Any = None, setups: Mapping[tuple[str, int], Mapping[str, Any]] | None = None,
          software_version: str, source: Mapping[str, Any],
          traces: Callable[[Any], Trace | None] | None = None,
          ) -> tuple[dict[str, Any], list[Trace]]:
    """report.json for ``plate_id`` and the traces to draw (one per position: its newest
    measurement's first shot).

    ``records``: the plate's stored measurements, oldest first, each with its shots (their
    ``sha256``, metadata and features); ``plate_map``: their map (with the joint answer and
    suggestions where asked for); ``setups``: the set-up revisions the measurements name, by
    (id, revision); ``source``: where the data came from (a service's URL, a store's path, a
    manifest), for ``report verify``; ``traces(measurement)``: its first shot, or None."""
    items = entries(records)
    setups = dict(setups or {})
    named: list[dict[str, Any]] = []
    for r in records:
        ref = (r.result.get("provenance") or {}).get("setup")
        if ref and (ref["id"], ref["revision"]) not in [(s["id"], s["revision"]) for s in named]:
            named.append(dict(setups.get((ref["id"], ref["revision"]), ref)))
    labels: dict[str, Any] = {}
    for s in named:
        labels.update(s.get("labels") or {})
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
    report = {
        "format": FORMAT,
        "plate_id": plate_id,
        "generated_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "software_version": software_version,
        "source": dict(source),
        "labels": labels,
        "setups": named,
        "chain_calibrations": _calibrations(records),
        "table": _table(records, tables),
        "map": {k: v for k, v in plate_map.items() if k != "positions"},
        "positions": positions,
        "measurements": items,
        "digest": {"algorithm": digest.ALGORITHM,
                   "value": digest.data_digest(
                       [{k: v for k, v in e.items() if k != "digest"} for e in items])},
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


def _calibrations(records: Sequence[Any]) -> list[dict[str, Any]]:
    """The distinct chain calibrations the measurements were estimated with."""
    found: list[dict[str, Any]] = []
    for r in records:
        cal = (r.result.get("provenance") or {}).get("chain_calibration")
        if cal is not None and cal not in found:
            found.append(cal)
    return found


def verify_entries(report: Mapping[str, Any]) -> str | None:
    """Why a report's own data do not match its printed digest (an edited report.json), or
    None where they do."""
    items = [{k: v for k, v in e.items() if k != "digest"} for e in report["measurements"]]
    for e, item in zip(report["measurements"], items, strict=True):
        if digest.entry_digest(item) != e["digest"]:
            return f"measurement {e['id']}'s data differ from its digest in the report"
    if digest.data_digest(items) != report["digest"]["value"]:
        return "the report's data differ from its digest"
    if content_digest(report) != (report.get("content_digest") or {}).get("value"):
        return ("the report's content (answers, map, set-up, calibration, table) differs from "
                "its content digest")
    return None
