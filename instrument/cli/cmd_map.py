"""`solitonde map`: a plate's thickness and distance-to-support maps, and its located support.

From the estimates file `analyze --estimates-out` writes (one row per position) or from the
service's store (its measurements pooled per position and inverted with the model table), the
same map the service draws at ``/v1/plates/{plate_id}/map.png``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import typer

STORE_SUFFIXES = (".sqlite", ".sqlite3", ".db")
ESTIMATE_SUFFIXES = (".csv", ".parquet")


def _fail(message: str, code: int = 2) -> None:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(code)


def _from_estimates(path: Path, plate_id: str) -> list[dict[str, Any]]:
    import pandas as pd

    from solitonde.instrument.inference.plate_map import from_estimate_rows

    try:
        frame = (pd.read_parquet(path) if path.suffix.lower() == ".parquet"
                 else pd.read_csv(path, dtype={"plate_id": str, "position": str}))
    except Exception as exc:  # any unreadable file: say which and why
        _fail(f"ESTIMATES: cannot read {str(path)!r} ({type(exc).__name__}: {exc})")
    missing = [c for c in ("plate_id", "x_m", "y_m", "distance_m_status") if c not in frame]
    if missing:
        _fail(f"ESTIMATES: {path.name} lacks the column(s) {', '.join(missing)}; give the file "
              "`solitonde analyze --estimates-out` writes")
    rows = frame[frame["plate_id"].astype(str) == plate_id].to_dict("records")
    if not rows:
        plates = sorted({str(p) for p in frame["plate_id"].dropna()})
        _fail(f"--plate-id: no plate {plate_id!r} in {path.name} (plates: "
              f"{', '.join(plates) or 'none'})")
    return from_estimate_rows(rows)


def _from_store(path: Path, plate_id: str, estimator: Any) -> list[dict[str, Any]]:
    from solitonde.instrument.inference.plate_map import from_records
    from solitonde.instrument.service.store import Store, StoreError

    try:
        store = Store(path, background_checkpoint=False)
    except (StoreError, OSError) as exc:
        _fail(f"ESTIMATES: {exc}")
    try:
        records = store.all_of_plate(plate_id, 100_000)
        plates = [p["plate_id"] for p in store.plates()]
    finally:
        store.close()
    if not records:
        _fail(f"--plate-id: no plate {plate_id!r} in {path.name} (plates: "
              f"{', '.join(plates) or 'none'})")
    return from_records(records, estimator)


def map_command(
    source: Path = typer.Argument(..., metavar="ESTIMATES_FILE_OR_STORE",
                                  help="Estimates (.csv/.parquet from analyze --estimates-out) "
                                  "or the service's store (.sqlite)."),
    plate_id: str = typer.Option(..., "--plate-id", help="The plate to map."),
    out: Path | None = typer.Option(None, "--out", help="Write the map as PNG."),
    as_json: bool = typer.Option(False, "--json", help="Print the map JSON (positions, "
                                 "support)."),
    table: list[Path] = typer.Option([], "--table", help="Model table(s): the plate's size "
                                     "for the outline and, for a store, the inversion "
                                     "(default: $SOLITONDE_TABLE, else the bundled table)."),
) -> None:
    """Map a plate: thickness and distance to support at each position, the support located."""
    from solitonde.instrument.cli.cmd_invert import table_path
    from solitonde.instrument.inference.plate_map import build
    from solitonde.instrument.inference.table_set import TableSet

    suffix = source.suffix.lower()
    if not source.is_file():
        _fail(f"ESTIMATES_FILE_OR_STORE: no such file: {source}")
    if suffix not in ESTIMATE_SUFFIXES + STORE_SUFFIXES:
        _fail(f"ESTIMATES_FILE_OR_STORE: {source.name} must end in "
              f"{', '.join(ESTIMATE_SUFFIXES + STORE_SUFFIXES)}")
    if out is not None and out.suffix.lower() != ".png":
        _fail(f"--out: {out.name} must end in .png")
    if out is not None and out.is_dir():
        _fail(f"--out: {str(out)!r} is a folder; give a file")
    estimator = TableSet(table or [table_path(None)], warm_up=False)
    if suffix in STORE_SUFFIXES and not estimator.loaded:
        _fail(f"--table: {estimator.reason}")
    positions = (_from_store(source, plate_id, estimator) if suffix in STORE_SUFFIXES
                 else _from_estimates(source, plate_id))
    plate_map = build(plate_id, positions, estimator.plate_size())
    if out is not None:
        from solitonde.instrument.plotting import map_png
        from solitonde.instrument.studies.figures import write_bytes

        try:
            write_bytes(out, map_png(plate_map))
        except OSError as exc:
            _fail(f"--out: cannot write {str(out)!r}: {exc.strerror or exc}", 1)
    if as_json:
        json.dump(plate_map, sys.stdout, indent=1, default=str)
        sys.stdout.write("\n")
        return
    support = plate_map["support"]
    typer.echo(f"plate {plate_id}: {plate_map['n_positions']} positions, "
               f"{plate_map['n_scan_positions']} with coordinates")
    if support:
        lo, hi = support["ci95_offset_m"]
        typer.echo(f"support: x cos({support['normal_angle_deg']:.2f} deg) + y sin(...) = "
                   f"{support['offset_m'] * 1e3:.2f} mm (95 % {lo * 1e3:.2f}..{hi * 1e3:.2f} mm), "
                   f"{support['n_positions']} positions, rms residual "
                   f"{support['residual_m'] * 1e3:.2f} mm")
    else:
        typer.echo(f"support: not located ({plate_map['support_reason']})")
    if out is not None:
        typer.echo(f"wrote {out}")


def register(app: typer.Typer) -> None:
    """Add `map` to the CLI."""
    app.command("map")(map_command)
