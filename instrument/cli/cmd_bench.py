"""`solitonde bench accuracy [--json]`: what each plate model and resolution costs and buys."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import typer
from rich.console import Console
from rich.table import Table

from solitonde.instrument.cli.main import HELP_MARKUP


def accuracy_command(
    as_json: bool = typer.Option(False, "--json", help="Print the results as JSON."),
    out: Path | None = typer.Option(None, "--out",
                                    help="Also write accuracy.csv, accuracy.json and "
                                         "accuracy_pareto.png here."),
    quick: bool = typer.Option(False, "--quick",
                               help="Tiny meshes only (checks the machinery in seconds)."),
) -> None:
    """TOF and ARR error against a converged reference, and wall time, per plate model and mesh."""
    from tqdm import tqdm

    from solitonde.instrument.studies.accuracy import configs, run_bench, write_outputs
    from solitonde.signal.json_ready import json_ready

    if out is not None and out.exists() and not out.is_dir():  # before minutes of runs
        typer.echo(f"error: --out: {str(out)!r} is a file; give a folder", err=True)
        raise typer.Exit(2)
    total = 2 * (len(configs(quick)) + 1)
    with tqdm(total=total, desc="bench accuracy", disable=not sys.stderr.isatty()) as bar:
        def tick(label: str) -> None:
            bar.set_postfix_str(label)
            bar.update(1)

        result = run_bench(quick, tick)
    write_error = None
    if out is not None:
        try:
            write_outputs(result, out)
        except OSError as exc:  # the results are still printed; the exit code says it failed
            write_error = f"error: --out: cannot write into {str(out)!r}: {exc.strerror or exc}"
    if as_json:
        typer.echo(json.dumps(json_ready(result), indent=2))
    else:
        _print(result)
    if write_error:
        typer.echo(write_error, err=True)
        raise typer.Exit(1)


def _print(result: dict[str, Any]) -> None:
    from solitonde.instrument.studies.accuracy import table_rows
    from solitonde.signal.json_ready import json_ready

    quick = " (quick: tiny meshes, numbers not converged)" if result.get("quick") else ""
    table = Table(title=f"What accuracy costs (reference: {result['reference']['config']}){quick}")
    for name in ("config", "scene", "TOF us", "ARR", "TOF err %", "ARR err %", "wall s",
                 "cached s", "Pareto"):
        table.add_column(name, justify="left" if name in ("config", "scene") else "right")
    for row in table_rows(result):
        table.add_row(*row)
    console = Console()
    console.print(table)
    console.print(("recommendation (quick: machinery only, not advice): " if quick else
                   "recommendation: ") + json.dumps(json_ready(result["recommendation"]), indent=2))


def register(app: typer.Typer) -> None:
    """Add the `bench` command group."""
    group = typer.Typer(help="Benchmarks of the model.", no_args_is_help=True,
                        rich_markup_mode=HELP_MARKUP)
    group.command("accuracy")(accuracy_command)
    app.add_typer(group, name="bench")
