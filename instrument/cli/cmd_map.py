"""`solitonde map`: a plate's thickness and distance-to-support maps, and its located support.

From the estimates file `analyze --estimates-out` writes (one row per position) or from the
service's store (its measurements pooled per position and inverted with the model table), the
same map the service draws at ``/v1/plates/{plate_id}/map.png``. With ``--joint`` the scan is
inverted as one unknown (the plate's edges and every position's thickness, from the positions'
per-size summaries: the estimates file's ``size_summaries`` or the store's shots); with
``--suggest N`` the N positions to measure next are added (instrument.inference.plate_map).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

import typer

if TYPE_CHECKING:
    from solitonde.instrument.inference.joint_map import ScanPosition
    from solitonde.instrument.inference.marginals import ParameterDict
    from solitonde.instrument.inference.plate_map import JointOptions, MapPosition, PlateMap
    from solitonde.instrument.inference.table_set import TableSet

    ScanReader = Callable[[], tuple[list[ScanPosition], list[str | None]]]
    """Reads a plate's positions as a scan, for the joint map (only when it is asked for)."""

STORE_SUFFIXES = (".sqlite", ".sqlite3", ".db")
ESTIMATE_SUFFIXES = (".csv", ".parquet")


def _fail(message: str, code: int = 2) -> NoReturn:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(code)


def _from_estimates(path: Path, plate_id: str) -> tuple[list[MapPosition], ScanReader]:
    import pandas as pd

    from solitonde.instrument.inference.plate_map import from_estimate_rows, scan_from_rows

    try:
        frame = (pd.read_parquet(path) if path.suffix.lower() == ".parquet"
                 else pd.read_csv(path, dtype={"plate_id": str, "position": str}))
    except Exception as exc:  # any unreadable file: say which and why
        _fail(f"ESTIMATES: cannot read {str(path)!r} ({type(exc).__name__}: {exc})")
    missing = [c for c in ("plate_id", "x_m", "y_m", "distance_m_status") if c not in frame]
    if missing:
        _fail(f"ESTIMATES: {path.name} lacks the column(s) {', '.join(missing)}; give the file "
              "`solitonde analyze --estimates-out` writes")
    rows = [{str(k): v for k, v in r.items()}
            for r in frame[frame["plate_id"].astype(str) == plate_id].to_dict("records")]
    if not rows:
        plates = sorted({str(p) for p in frame["plate_id"].dropna()})
        _fail(f"--plate-id: no plate {plate_id!r} in {path.name} (plates: "
              f"{', '.join(plates) or 'none'})")
    return from_estimate_rows(rows), lambda: scan_from_rows(rows)


def _from_store(path: Path, plate_id: str, estimator: TableSet
                ) -> tuple[list[MapPosition], ScanReader]:
    from solitonde.instrument.inference.plate_map import from_records, scan_from_records
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
    return from_records(records, estimator), lambda: scan_from_records(records)


def _mm(value: Any) -> str:
    """A length in mm, or "-" where there is none."""
    return "-" if value is None else f"{float(value) * 1e3:.2f}"


FLAG_OF = {"suggest": "--suggest", "suggest_for": "--suggest-for",
           "thickness_prior": "--thickness-prior", "thickness_spread": "--thickness-spread",
           "table": "--table", "size_summaries": "ESTIMATES_FILE_OR_STORE",
           "positions": "--joint", "joint": "--joint", "x_m": "ESTIMATES_FILE_OR_STORE",
           "y_m": "ESTIMATES_FILE_OR_STORE"}
"""The flag each field of a joint-map error stands for on the command line."""


def _options(joint: bool, suggest: str | None, suggest_for: str, thickness_prior: str,
             thickness_spread: str | None) -> JointOptions:
    """The joint map's options from the flags, each checked (exit 1 naming the flag)."""
    from solitonde.instrument.inference.joint_map import DEFAULT_SPREAD, JointMapError
    from solitonde.instrument.inference.plate_map import JointOptions
    from solitonde.instrument.inference.suggest import MAX_SUGGEST

    n: Any = 0
    if suggest is not None:
        try:
            n = int(suggest)
        except ValueError:
            _fail(f"--suggest: {suggest!r} is not a whole number (allowed: 0..{MAX_SUGGEST})", 1)
    spread: Any = DEFAULT_SPREAD
    if thickness_spread is not None:
        try:
            spread = float(thickness_spread)
        except ValueError:
            _fail(f"--thickness-spread: {thickness_spread!r} is not a number (allowed: a "
                  "relative standard deviation, e.g. 0.05)", 1)
        if thickness_prior != "common":
            _fail("--thickness-spread: only with --thickness-prior common (the positions' "
                  "spread around their common mean)", 1)
    try:
        return JointOptions(joint, n, suggest_for, thickness_prior, spread)
    except JointMapError as exc:
        _fail(f"{FLAG_OF.get(exc.field, exc.field)}: {exc.message}", 1)


def map_command(
    source: Path = typer.Argument(..., metavar="ESTIMATES_FILE_OR_STORE",
                                  help="Estimates (.csv/.parquet from analyze --estimates-out) "
                                  "or the service's store (.sqlite)."),
    plate_id: str = typer.Option(..., "--plate-id", help="The plate to map."),
    out: Path | None = typer.Option(None, "--out", help="Write the map as PNG."),
    as_json: bool = typer.Option(False, "--json", help="Print the map JSON (positions, "
                                 "support)."),
    table: list[Path] = typer.Option([], "--table", help="Model table(s): the plate's size "
                                     "for the outline and, for a store or --joint, the "
                                     "inversion (default: $SOLITONDE_TABLE, else the bundled "
                                     "table)."),
    joint: bool = typer.Option(False, "--joint", help="Invert the scan as one unknown: the "
                               "plate's edges and every position's thickness, with the joint "
                               "fit and warnings."),
    suggest: str | None = typer.Option(None, "--suggest", metavar="N", help="Add the N "
                                       "positions where a measurement would shrink the edge's "
                                       "interval most (0..20)."),
    suggest_for: str = typer.Option("edge", "--suggest-for", help="What the suggestions "
                                    "shrink: edge (the located edge's interval) or thickness "
                                    "(the thickness map's)."),
    thickness_prior: str = typer.Option("free", "--thickness-prior", help="free (each "
                                        "position's thickness its own, the default) or common "
                                        "(tied to the plate's mean with --thickness-spread)."),
    thickness_spread: str | None = typer.Option(None, "--thickness-spread", metavar="REL",
                                                help="With --thickness-prior common: each "
                                                "position's relative spread around the mean "
                                                "(1 sd; default 0.05)."),
) -> None:
    """Map a plate: thickness and distance to support at each position, the support located."""
    from solitonde.instrument.cli.common import table_path
    from solitonde.instrument.inference.plate_map import build
    from solitonde.instrument.inference.table_set import TableSet

    options = _options(joint, suggest, suggest_for, thickness_prior, thickness_spread)

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
    positions, scan = (_from_store(source, plate_id, estimator) if suffix in STORE_SUFFIXES
                       else _from_estimates(source, plate_id))
    plate_map = build(plate_id, positions, estimator.plate_size())
    if options.wanted:
        plate_map = _joint(plate_map, scan, estimator, options)
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
        typer.echo(support_line(support))
    else:
        typer.echo(f"support: not located ({plate_map['support_reason']})")
    if plate_map.get("joint"):
        _print_joint(plate_map)
    for s in plate_map.get("suggestions", []):
        typer.echo(f"next: x {s['x_m'] * 1e3:.1f} mm, y {s['y_m'] * 1e3:.1f} mm "
                   f"({s['distance_m'] * 1e3:.1f} mm from the support): expected gain "
                   f"{s['expected_gain'] * 1e3:.2f} mm")
    if out is not None:
        typer.echo(f"wrote {out}")


def _joint(plate_map: PlateMap, scan: ScanReader, estimator: TableSet,
           options: JointOptions) -> PlateMap:
    from solitonde.instrument.inference.joint_map import JointMapError
    from solitonde.instrument.inference.plate_map import with_joint
    from solitonde.instrument.inference.table_set import TableChoiceError

    if not estimator.loaded:
        _fail(f"--table: {estimator.reason}", 1)
    try:
        positions, tables = scan()
        return with_joint(plate_map, positions, tables, estimator, options)
    except JointMapError as exc:
        _fail(f"{FLAG_OF.get(exc.field, exc.field)}: {exc.message}", 1)
    except TableChoiceError as exc:
        _fail(f"--table: {exc.message}", 1)
    return plate_map  # not reached


def _print_joint(plate_map: PlateMap) -> None:
    """The joint answer, a line per position, then its fit and warnings."""
    def mm(p: ParameterDict | None) -> str:
        if not p:
            return "-"
        lo, hi = (_mm(v) for v in p.get("ci95") or (None, None))
        if p.get("status") in ("constrained", "inconsistent") and p.get("median") is not None:
            return f"{_mm(p['median'])} ({lo}..{hi})"
        if p.get("status") == "lower_bound_only":
            return f">= {lo}"
        if p.get("status") == "upper_bound_only":
            return f"<= {hi}"
        return str(p.get("status"))

    prior = plate_map.get("thickness_prior")
    spread = prior.get("spread_rel") if prior else None
    typer.echo(f"joint: thickness {prior['kind'] if prior else None}"
               + (f" (spread {100 * spread:.3g} %)" if spread else "")
               + "; mm, 95 % in brackets:")
    for p in plate_map["positions"]:
        own = p.get("per_position") or {}
        line = (f"  {p['position']}: thickness {mm(p.get('thickness_m'))}, distance "
                f"{mm(p.get('distance_m'))}")
        if own:
            line += f"  (alone: thickness {mm(own.get('thickness_m'))})"
        if p.get("joint_reason"):
            line += f"  (not in the joint answer: {p['joint_reason']})"
        typer.echo(line)
    fit = plate_map.get("fit")
    if fit and fit["chi2"] is not None:
        typer.echo(f"fit: chi2 {fit['chi2']:.3g} for {fit['dof']:.3g} dof, p = "
                   f"{fit['p_value']:.3g}")
    for w in plate_map.get("warnings", []):
        typer.echo(f"warning: {w}")


def register(app: typer.Typer) -> None:
    """Add `map` to the CLI."""
    app.command("map")(map_command)


def support_line(support: Mapping[str, Any]) -> str:
    """The located edge as printed. A joint fit whose positions have no constrained distance
    has no residual to state: it says so instead of failing."""
    lo, hi = support["ci95_offset_m"]
    residual = support.get("residual_m")
    rms = ("n/a (no position's distance is constrained)" if residual is None
           else f"{residual * 1e3:.2f} mm")
    return (f"support: x cos({support['normal_angle_deg']:.2f} deg) + y sin(...) = "
            f"{support['offset_m'] * 1e3:.2f} mm (95 % {lo * 1e3:.2f}..{hi * 1e3:.2f} mm), "
            f"{support['n_positions']} positions, rms residual {rms}")
