"""A plate's inspection report from a measurement store: its data (report.json), HTML and PDF.

The service's routes (``GET /v1/plates/{id}/report.pdf`` ...) and ``solitonde report build``
(from a store, or from recordings through a temporary store filled by the upload's own road) all
come here, so every report of the same stored data holds the same numbers and digest.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping

from solitonde.instrument.errors import MessageError
from solitonde.instrument.inference.table_set import TableSet
from solitonde.instrument.reports import content, render
from solitonde.instrument.reports.content import DigestEntry, Report, Trace
from solitonde.instrument.service import setup_book
from solitonde.instrument.service.store import MeasurementRecord, Store

log = logging.getLogger("solitonde.instrument")

POSITIONS_MAX = 5_000
"""Measurements one report reads (as a map does)."""
SUGGEST_UP_TO = 50
"""Suggestions are added to a report of at most this many scan positions by default (a
suggestion's search grows with the scan; a long plate's report leaves them out)."""
SUGGESTIONS = 3


class NoSuchPlate(MessageError, LookupError):
    """The store holds no measurement of the plate."""

    subject = "plate_id"


def version() -> str:
    """This software's version."""
    from solitonde.model.version import package_version

    return package_version()


def entries(store: Store, plate_id: str) -> list[DigestEntry]:
    """The plate's digest entries as the store holds them now (what ``report verify``
    compares a report's with)."""
    return content.entries(store.all_of_plate(plate_id, POSITIONS_MAX + 1))


def build(store: Store, tables: TableSet, plate_id: str, source: Mapping[str, str], *,
          joint: bool = True, suggest: int | None = None,
          progress: Callable[[str], None] | None = None) -> tuple[Report, list[Trace]]:
    """report.json of ``plate_id`` and the traces to draw; ``suggest`` None: three suggestions
    up to :data:`SUGGEST_UP_TO` scan positions, none beyond. NoSuchPlate for a plate without
    measurements."""
    records, traces = _records_and_traces(store, plate_id)
    return _build(store, tables, plate_id, source, records, traces, joint, suggest,
                  progress or (lambda _: None))


def report_bytes(store: Store, tables: TableSet, plate_id: str, source: Mapping[str, str],
                 fmt: str, *, joint: bool = True, suggest: int | None = None,
                 progress: Callable[[str], None] | None = None) -> bytes:
    """The report as ``pdf``, ``html`` or ``json``. NoSuchPlate for a plate without
    measurements.

    The steps run one after the other: drawing the traces beside the joint inversion (a thread,
    or a process on the second core) measured slower on 2 cores than in turn, both contending
    for the interpreter and the cores."""
    say = progress or (lambda _: None)
    started = time.perf_counter()
    records, traces = _records_and_traces(store, plate_id)
    report, shown = _build(store, tables, plate_id, source, records, traces, joint, suggest,
                           say)
    if fmt != "json":
        say(f"drawing the maps and {len(shown)} traces")
    out = render_report(report, shown, fmt, progress=say)
    log.info("report of plate %s: %d positions, %s, %.1f s", plate_id,
             len(report["positions"]), fmt, time.perf_counter() - started)
    return out


def _records_and_traces(store: Store, plate_id: str
                        ) -> tuple[list[MeasurementRecord], dict[int, Trace]]:
    """The plate's measurements (with their shots) and, per position, its newest
    measurement's first shot with its samples."""
    from solitonde.instrument.inference import plate_map

    records = store.all_of_plate(plate_id, POSITIONS_MAX + 1)
    if not records:
        raise NoSuchPlate(f"no measurement of plate {plate_id!r}")
    if len(records) > POSITIONS_MAX:
        raise ValueError(f"more than {POSITIONS_MAX:,} measurements of plate {plate_id!r}")
    traces = {}
    for members in plate_map.by_position(records).values():
        newest = members[-1]
        if not newest.shots:
            continue
        shot = store.get_shot(newest.id, newest.shots[0].shot_index)
        if shot is not None:
            traces[newest.id] = Trace(newest.id, shot.shot_index, shot.t0, shot.dt,
                                      shot.samples, shot.features)
    return records, traces


def _build(store: Store, tables: TableSet, plate_id: str, source: Mapping[str, str],
           records: list[MeasurementRecord], traces: dict[int, Trace], joint: bool,
           suggest: int | None,
           say: Callable[[str], None]) -> tuple[Report, list[Trace]]:
    from solitonde.instrument.inference import plate_map
    from solitonde.instrument.inference.joint_map import DEFAULT_SPREAD, JointMapError
    from solitonde.instrument.inference.table_set import TableChoiceError

    say(f"{len(records)} measurements: estimating each position")
    result = plate_map.of_records(plate_id, records, tables)
    n_scan = result["n_scan_positions"]
    wanted = (SUGGESTIONS if n_scan <= SUGGEST_UP_TO else 0) if suggest is None else suggest
    if (joint or wanted) and n_scan >= 3:
        say(f"inverting the scan of {n_scan} positions jointly"
            + (f", {wanted} suggestions" if wanted else ""))
        scan, table_ids = plate_map.scan_from_records(records)
        try:
            result = plate_map.with_joint(result, scan, table_ids, tables, plate_map.JointOptions(
                joint, wanted, "edge", "free", DEFAULT_SPREAD))
        except (JointMapError, TableChoiceError) as exc:
            result["joint_reason"] = str(exc)
    setups = {}
    for r in records:
        provenance = r.result.get("provenance")
        ref = provenance.get("setup") if provenance else None
        if ref and (ref["id"], ref["revision"]) not in setups:
            found = setup_book.revision(store, ref["id"], ref["revision"])
            if found is not None:
                setups[(ref["id"], ref["revision"])] = found.to_dict()
    return content.build(plate_id, records, result, tables=tables, setups=setups,
                         software_version=version(), source=source,
                         traces=lambda record: traces.get(record.id))


def render_report(report: Report, traces: list[Trace], fmt: str,
                  strips: list[bytes] | None = None,
                  progress: Callable[[str], None] | None = None) -> bytes:
    """The report as ``html`` or ``pdf`` bytes (``json``: report.json); ``strips``: the traces
    already drawn (else drawn here)."""
    from solitonde.instrument.plotting import map_png, trace_strips

    if fmt == "json":
        return render.report_json(report).encode()
    picture = map_png({**report["map"], "positions": report["positions"]})
    if strips is None:
        strips = trace_strips([(t.t0, t.dt, t.samples, t.features) for t in traces])
    document = render.html(report, picture, traces, strips)
    if fmt == "html":
        return document.encode()
    if progress is not None:
        progress("laying out the PDF")
    return render.pdf(document, report)
