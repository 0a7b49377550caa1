"""`solitonde validate`: synthetic validation of the table and the inversion (see
:mod:`solitonde.instrument.validate` for exactly what is simulated and scored)."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from .cmd_invert import table_path
from .table import ModelTable, TableError
from .table_build import default_workers
from .validate import validate


def validate_command(
    n: int = typer.Option(200, "--n", min=1, help="number of random plates"),
    seed: int = typer.Option(0, "--seed", help="random seed"),
    table: Path | None = typer.Option(None, "--table", help="model table"),
    workers: int | None = typer.Option(None, help="local worker processes (default: one per "
                                       "core); 1 runs serially"),
    scheduler: str | None = typer.Option(None, help="address of an existing Dask scheduler"),
    diameters: str | None = typer.Option(None, "--diameters", help="sphere sizes to measure, m, "
                                         "comma list (default: all of the table's)"),
    measurements: Path | None = typer.Option(None, "--measurements", help="JSON file keeping the "
                                             "simulated shots; reused when it matches the draw"),
    out: Path | None = typer.Option(None, "--out", help="also write every scene's row as JSON"),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="progress bar"),
    as_json: bool = typer.Option(False, "--json", help="print the metrics as JSON"),
) -> None:
    """Simulate random plates with noise and dissipation, invert, and score the answers."""
    try:
        model = ModelTable.load(table_path(table))
    except TableError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None
    report = validate(model, n, seed, workers=default_workers() if workers is None else workers,
                      scheduler=scheduler, progress=progress,
                      diameters=[float(x) for x in diameters.split(",")] if diameters else None,
                      measurements=measurements)
    m = report.metrics
    if out is not None:
        out.write_text(json.dumps({"metrics": m, "scenes": report.scenes}, indent=1) + "\n")
    if as_json:
        typer.echo(json.dumps(m, indent=2))
        return
    typer.echo(f"validation on {m['table']}: {m['n']} plates, seed {m['seed']}")
    typer.echo(f"  thickness error (relative): median {m['thickness_error_median']:.4f}, "
               f"90th percentile {m['thickness_error_p90']:.4f} ({m['n_estimated']} estimated)")
    typer.echo(f"  coverage of the 95 % interval: thickness {m['coverage_95']:.3f}, "
               f"distance {m['distance_coverage_95']:.3f}")
    typer.echo(f"  status right: {m['status_accuracy']:.3f}; distance statuses "
               f"{m['distance_status_counts']}")


def register(app: typer.Typer) -> None:
    """Add `validate` to the CLI."""
    app.command("validate")(validate_command)
