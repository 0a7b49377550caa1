"""`solitonde validate`: synthetic validation of the table and the inversion (see
:mod:`solitonde.instrument.studies.validate` for exactly what is simulated and scored)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import NoReturn

import typer

from solitonde.instrument.cli.common import table_path
from solitonde.instrument.parallel import default_workers
from solitonde.instrument.studies.validate import SHOTS, ValidationInputError, validate
from solitonde.instrument.tables.table import ModelTable, TableError


def _fail(message: str) -> NoReturn:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(2)


def parse_diameters(text: str | None, model: ModelTable) -> list[float] | None:
    """``--diameters``: a comma list of sphere sizes in m, each one of the table's, each once."""
    if text is None:
        return None
    out: list[float] = []
    for item in text.split(","):
        try:
            d = float(item)
        except ValueError:
            _fail(f"--diameters: {item.strip()!r} is not a number (give sphere sizes in m, "
                  "comma-separated, e.g. 4.76e-3,9.53e-3)")
        try:
            d = float(model.axes["diameter_m"][model.diameter_index(d)])
        except TableError as exc:
            _fail(f"--diameters: {exc.full_message}")
        if d in out:
            _fail(f"--diameters: {item.strip()} is listed twice")
        out.append(d)
    return out


def validate_command(
    n: int = typer.Option(200, "--n", min=1, help="number of random plates"),
    seed: int = typer.Option(0, "--seed", help="random seed"),
    table: Path | None = typer.Option(None, "--table", help="model table"),
    workers: int | None = typer.Option(None, help="local worker processes (default: one per "
                                       "core); 1 runs serially"),
    scheduler: str | None = typer.Option(None, help="address of an existing Dask scheduler"),
    diameters: list[str] | None = typer.Option(None, "--diameters", help="sphere sizes to "
                                               "measure, m: a comma list, or the option repeated "
                                               "(default: all of the table's)"),
    measurements: Path | None = typer.Option(None, "--measurements", help="JSON file keeping the "
                                             "simulated shots; reused when it matches the draw"),
    truth_plate_theory: str = typer.Option(
        "auto", "--truth-plate-theory", help="plate theory of the simulated truths near a support "
        "(sem.plate_theory: auto, 3d, mindlin): 3d checks a table built on the Mindlin plate "
        "against 3-D plates, meshed with the Mindlin plate's in-plane elements"),
    wrong_family: str | None = typer.Option(
        None, "--wrong-family", help="simulate the truths on a plate of this library material "
        "(e.g. steel_structural against the aluminium table): how often the answer is flagged "
        "or covers the truth anyway"),
    draw_material: bool = typer.Option(
        True, "--draw-material/--exact-material", help="give each plate a material drawn from "
        "the spread of the table's plate material (default), or the table's exact properties"),
    shots: int = typer.Option(SHOTS, "--shots", min=1, help="shots per plate and sphere size "
                              "(1: a lab reading one shot at a time)"),
    near_support: float | None = typer.Option(
        None, "--near-support", help="draw the distances within this many m of a support "
        "(e.g. 0.05) instead of over the whole table"),
    out: Path | None = typer.Option(None, "--out", help="also write every scene's row as JSON"),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="progress bar"),
    as_json: bool = typer.Option(False, "--json", help="print the metrics as JSON"),
) -> None:
    """Simulate random plates with noise and dissipation, invert, and score the answers."""
    if seed < 0:
        _fail(f"--seed: must be an integer >= 0, got {seed}")
    # checked before the simulations: a bad path would only show after all of them
    for flag, path in (("--out", out), ("--measurements", measurements)):
        if path is not None and path.is_dir():
            _fail(f"{flag}: {str(path)!r} is a directory; give the name of a JSON file")
        if path is not None and not path.parent.is_dir():
            _fail(f"{flag}: the folder {str(path.parent)!r} does not exist")
    try:
        model = ModelTable.load(table_path(table))
    except TableError as exc:
        _fail(str(exc))
    sizes = parse_diameters(",".join(diameters) if diameters else None, model)
    try:
        report = validate(model, n, seed,
                          workers=default_workers() if workers is None else workers,
                          scheduler=scheduler, progress=progress, diameters=sizes,
                          measurements=measurements, truth_plate_theory=truth_plate_theory,
                          wrong_family=wrong_family, draw_material=draw_material,
                          shots=shots, near_support_m=near_support)
    except ValidationInputError as exc:
        flag = "near-support" if exc.field == "near_support_m" else exc.field.replace("_", "-")
        _fail(f"--{flag}: {exc.full_message}")
    m = report.metrics
    if out is not None:
        try:
            out.write_text(json.dumps({"metrics": m, "scenes": report.scenes}, indent=1) + "\n")
        except OSError as exc:
            _fail(f"--out: cannot write {str(out)!r}: {exc.strerror or exc}")
    if as_json:
        typer.echo(json.dumps(m, indent=2))
        return
    def num(v: float | None, fmt: str = ".3f") -> str:
        return "-" if v is None else format(v, fmt)

    typer.echo(f"validation on {m['table']}: {m['n']} plates, seed {m['seed']}"
               + (f", truths on {m['wrong_family']}" if m.get("wrong_family") else ""))
    typer.echo(f"  thickness error (relative): median {num(m['thickness_error_median'], '.4f')}, "
               f"90th percentile {num(m['thickness_error_p90'], '.4f')} ({m['n_estimated']} "
               "estimated)")
    typer.echo(f"  answered {num(m['answered'])}; coverage of the 95 % interval: thickness "
               f"{num(m['coverage_95'])} (two-sided only {num(m['coverage_95_two_sided'])}), "
               f"distance {num(m['distance_coverage_95'])}; median width "
               f"{num(m['interval_width_median'], '.4f')} of t")
    typer.echo(f"  flagged inconsistent {num(m['inconsistent_rate'])}; flagged or covered "
               f"{num(m['flagged_or_covered'])}; constrained, missed, unflagged "
               f"{num(m['missed_unflagged'])} (and unwarned {num(m['missed_unwarned'])}; "
               f"another reading warned {num(m['other_reading_rate'])})")
    if m.get("material_spread_drawn"):
        typer.echo("  each plate's material drawn from the table material's spread "
                   "(--exact-material: the table's own)")
    typer.echo(f"  ambiguous (separate readings near a support) {num(m['ambiguous_rate'])}")
    typer.echo(f"  status right: {num(m['status_accuracy'])}; distance statuses "
               f"{m['distance_status_counts']}")
    for b in m["by_distance"]:
        lo, hi = b["distance_m"]
        assert lo is not None  # a bin's lower edge is a number; only the last bin is open
        span = f"{lo * 1e3:g}-{hi * 1e3:g} mm" if hi is not None else f"beyond {lo * 1e3:g} mm"
        typer.echo(f"  {span} from the support: {b['n']} plates, answered {num(b['answered'])}, "
                   f"coverage {num(b['coverage_95'])}, missed unflagged "
                   f"{num(b['missed_unflagged'])}, ambiguous {num(b['ambiguous_rate'])}")


def register(app: typer.Typer) -> None:
    """Add `validate` to the CLI."""
    app.command("validate")(validate_command)
