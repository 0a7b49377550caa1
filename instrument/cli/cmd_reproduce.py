"""`solitonde reproduce --out DIR [--quick]`: regenerate the paper's Figs. 3-10 and check them."""

from __future__ import annotations

import sys
from pathlib import Path

import typer
from rich.console import Console
from rich.table import Table

from solitonde.model.errors import SceneError, SimulationError


def reproduce_command(
    out: Path = typer.Option(..., "--out", help="Output folder: PNGs, CSVs and summary.json."),
    quick: bool = typer.Option(False, "--quick", help="Coarse version for CI (under two minutes)."),
    workers: int | None = typer.Option(None, "--workers", min=1,
                                       help="Processes for the plate sweep (default: all cores)."),
    cache: Path | None = typer.Option(None, "--cache",
                                      help="Folder of the cached plate responses "
                                           "(default: $SOLITONDE_CACHE/greens or ~/.cache)."),
    preset: str = typer.Option("resolved", "--preset",
                               help="Plate contact of the distance sweep: 'resolved' (converged "
                                    "contact patch, the default model) or 'paper' (the paper's "
                                    "single-node load; faster, not mesh-convergent in ARR)."),
) -> None:
    """Regenerate the paper's figures 3-10 (PNG + CSV each) and summary.json with the checks."""
    from solitonde.instrument.studies.reproduce import reproduce

    console = Console(stderr=True)
    if preset not in ("paper", "resolved"):
        console.print(f"[red]error:[/red] --preset: {preset!r} (allowed: paper, resolved)")
        raise typer.Exit(2)
    try:
        summary = reproduce(out, quick, workers=workers, cache_folder=cache,
                            progress=sys.stderr.isatty(), preset=preset)
    except (SceneError, SimulationError, OSError) as exc:
        console.print(f"[red]error:[/red] {exc}")
        raise typer.Exit(1) from None
    table = Table(title=f"Checks ({'quick' if summary['quick'] else 'full'}, "
                        f"{summary['wall_s']:.0f} s)")
    table.add_column("check")
    table.add_column("result")
    for name, check in summary["checks"].items():
        table.add_row(name, "[green]pass[/green]" if check["passed"] else "[red]FAIL[/red]")
    Console().print(table)
    Console().print(f"figures and data in {out}; checks in {out / 'summary.json'}")
    if not summary["all_passed"]:
        raise typer.Exit(3)  # not 2, a usage error: a script can tell a failed check apart


def register(app: typer.Typer) -> None:
    """Add the `reproduce` command."""
    app.command("reproduce")(reproduce_command)
