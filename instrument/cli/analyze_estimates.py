"""`analyze --invert`: an estimate per plate and position from `analyze`'s summaries.

Sphere sizes are combined per (plate_id, position, x, y) and estimated through the one estimate
path (instrument.inference.pipeline), against the table a manifest row, ``--setup`` or the plate
material names; the rows written by ``--estimates-out`` and the estimates that count as failures
of the run are read from the same rows.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, NotRequired, TypedDict

from solitonde.instrument.inference import measured_shots
from solitonde.instrument.inference.measured_shots import PositionShots

if TYPE_CHECKING:
    from solitonde.instrument.inference.pipeline import TableEstimateDict
    from solitonde.instrument.inference.setups import Setup

MISSING_SIZE_FLAG = ("--sphere-diameter: --invert needs the sphere size, and these shots state "
                     "none (give --sphere-diameter M, or a manifest's sphere_diameter_m)")


class SkippedSize(TypedDict):
    """A sphere size of a position that was not estimated, and why."""

    sphere_diameter: float | None
    reason: str | None


class PositionEstimate(TypedDict):
    """One plate and position as `analyze --invert` reports it (JSON keys in this order)."""

    plate_id: str | None
    position: str | None
    x_m: float | None
    y_m: float | None
    skipped: list[SkippedSize]
    diameters_m: list[float]
    n_shots: int
    estimate: TableEstimateDict | None
    error: NotRequired[str]


@dataclass(frozen=True)
class Chosen:
    """The table and plate material a position is estimated with, or why it cannot be."""

    table: str | None = None
    plate_material: Any = None
    error: str | None = None


def estimates_for_locations(groups: Sequence[PositionShots], table_files: Sequence[Path] | None,
                            calibration_file: Path | None,
                            plate_material: Any = None,
                            setup: Setup | None = None) -> list[PositionEstimate]:
    """Estimates per (plate_id, position) from `analyze`'s summaries, sphere sizes combined,
    each against the table of its family (instrument.table_set's rule) or the one its manifest
    row or ``setup`` names, through the one estimate path (instrument.inference.pipeline).

    With ``setup`` its table is found by id among ``table_files``, the bundled tables and
    ``$SOLITONDE_TABLE``, and its chain calibration is applied, as the service does.

    Raises TableError/CalibrationError when a table or the calibration cannot be read.
    """
    from solitonde.instrument.cli.common import setup_tables, table_set
    from solitonde.instrument.inference.calibration import Calibration

    tables = table_set(table_files) if setup is None else setup_tables(setup, table_files)
    cal = Calibration.load(calibration_file) if calibration_file else None
    if setup is not None and setup.chain_calibration is not None:
        cal = setup.calibration()
    by_location = measured_shots.by_position(
        groups, lambda g: tuple(g.location.get(k) for k in measured_shots.POSITION_KEYS))
    return [_estimate_position(location, sizes, tables, cal, setup, plate_material)
            for location, sizes in by_location.items()]


def _estimate_position(location: tuple[Any, ...], sizes: Sequence[PositionShots], tables: Any,
                       cal: Any, setup: Setup | None, plate_material: Any) -> PositionEstimate:
    """The estimate of one position from the summaries of its sphere sizes."""
    from solitonde.instrument.cli.common import choice_error
    from solitonde.instrument.inference.inversion_inputs import InversionError
    from solitonde.instrument.inference.pipeline import MISSING_SIZE, estimate
    from solitonde.instrument.inference.table_set import TableChoiceError
    from solitonde.instrument.tables.table import TableError

    plate, position, x_m, y_m = location
    usable = [g.summary for g in sizes if g.summary.skip_reason() is None]
    row: PositionEstimate = {
        "plate_id": plate, "position": position, "x_m": x_m, "y_m": y_m,
        # the command line names its flag, not the metadata key the inversion reads
        "skipped": [{"sphere_diameter": g.location["sphere_diameter"],
                     "reason": MISSING_SIZE_FLAG if g.summary.skip_reason() == MISSING_SIZE
                     else g.summary.skip_reason()} for g in sizes if g.summary.skip_reason()],
        "diameters_m": [s.diameter_m for s in usable if s.diameter_m is not None],
        "n_shots": sum(s.inputs().n_shots for s in usable),
        "estimate": None,
    }
    if not usable:
        return row
    chosen = _chosen_for(sizes, setup, plate_material)
    if chosen.error is not None:
        row["error"] = chosen.error
        return row
    try:
        found = estimate(tables, usable, cal, table=chosen.table,
                         plate_material=chosen.plate_material, skipped=row["skipped"])
        row["estimate"] = found.to_dict()
    except TableChoiceError as exc:
        row["error"] = choice_error(exc)
    except (InversionError, TableError) as exc:
        row["error"] = str(exc)
    return row


def _chosen_for(sizes: Sequence[PositionShots], setup: Setup | None,
                plate_material: Any) -> Chosen:
    """The table and plate material a position is estimated with: its manifest row's, else the
    set-up's, else the command line's material; an error where a row names another set-up
    than ``--setup``, or a table that contradicts it."""
    from solitonde.instrument.cli.common import parse_material

    loc = sizes[0].location
    contradiction = _setup_contradiction(sizes, setup)
    if contradiction is not None:
        return Chosen(error=contradiction)
    table = loc.get("table")
    material = loc.get("plate_material")
    try:
        material = plate_material if material is None else parse_material(str(material))
    except ValueError as exc:
        return Chosen(error=f"--manifest: plate_material: {exc}")
    if material is None and setup is not None:
        material = setup.plate_material
    return Chosen(table=table if table is not None else None if setup is None else setup.table,
                  plate_material=material)


def _setup_contradiction(sizes: Sequence[PositionShots], setup: Setup | None) -> str | None:
    """Why a position's manifest row or sphere sizes cannot be read with ``--setup``, or
    None."""
    loc = sizes[0].location
    named = loc.get("setup")
    if named is not None and (setup is None or named != setup.id):
        return (f"--manifest: setup {named!r}: give that set-up's file with --setup"
                + ("" if setup is None else f" (--setup is {setup.id!r})"))
    if setup is None:
        return None
    for g in sizes:
        d = g.location.get("sphere_diameter")
        if d is not None and setup.size_of(float(d)) is None:
            return (f"sphere_diameter {float(d):g} m contradicts --setup {setup.id!r}, whose "
                    f"sphere_diameters_m are "
                    f"{', '.join(f'{s:g}' for s in setup.sphere_diameters_m)} m")
    table = loc.get("table")
    if table is not None and table != setup.table:
        return (f"--manifest: table {table!r} contradicts --setup {setup.id!r}, whose table is "
                f"{setup.table!r}")
    return None


def estimate_failures(estimates: Sequence[PositionEstimate]) -> Iterator[tuple[str, str | None]]:
    """(where, why) for each position whose estimate makes the run fail: an inversion that
    failed, a sphere size missing, records no answer can be read from, or an answer the table's
    family does not explain."""
    from solitonde.instrument.cli.estimate_text import where_estimated
    from solitonde.instrument.inference.pipeline import (
        ALL_EARLY,
        ALL_REJECTED,
        ALL_SATURATED,
        ALL_TRUNCATED,
        ALL_UNSTEADY,
    )

    every_unreadable = (ALL_TRUNCATED, ALL_SATURATED, ALL_EARLY, ALL_UNSTEADY, ALL_REJECTED)
    for est in estimates:
        where = where_estimated(est)
        result = est.get("estimate")
        skipped = est.get("skipped", [])
        if est.get("error"):  # an inversion that failed (e.g. a size the table lacks)
            yield where, est["error"]
        elif result is None and any(s.get("reason") == MISSING_SIZE_FLAG for s in skipped):
            yield where, MISSING_SIZE_FLAG
        elif result is None and (unreadable := [
                s["reason"] for s in skipped
                if any(every in str(s["reason"]) for every in every_unreadable)]):
            # records too short, or clipped: no answer can be read from them
            yield where, unreadable[0]
        elif result is not None and result["thickness_m"].get("status") in (
                "inconsistent", "out_of_range"):
            # an answer the table's family does not explain is no answer to act on
            yield where, (result["warnings"][0] if result.get("warnings")
                          else result.get("reason"))


def write_estimates(out: Path, estimates: Sequence[PositionEstimate]) -> None:
    """One row per plate and position (instrument.estimate_rows' columns)."""
    from solitonde.instrument.inference.estimate_rows import estimate_row, to_bytes
    from solitonde.instrument.studies.figures import write_bytes

    table = []
    for est in estimates:
        result = est.get("estimate")
        reason = est.get("error") or ("; ".join(str(s["reason"]) for s in est.get("skipped", []))
                                      if result is None else None)
        table.append(estimate_row(est, est.get("diameters_m", []), est.get("n_shots", 0),
                                  result, reason))
    write_bytes(out, to_bytes(table, "parquet" if out.suffix.lower() == ".parquet" else "csv"))
