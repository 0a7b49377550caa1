"""`solitonde bench accuracy [--json]`: what each plate model and resolution costs and buys.
`solitonde bench plates [--kind greens|coupled]`: where the Mindlin plate suffices."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import typer
from rich.console import Console
from rich.table import Table

from solitonde.instrument.cli.main import HELP_MARKUP

if TYPE_CHECKING:
    from solitonde.instrument.studies.accuracy import BenchResult


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


def _print(result: BenchResult) -> None:
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


def _floats(text: str | None, option: str, zero: bool = False) -> list[float] | None:
    """A comma-separated list of lengths in metres (positive; also 0 where ``zero``)."""
    if text is None:
        return None
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        values = []
    if not values or not all((v >= 0.0 if zero else v > 0.0) and v < 10.0 for v in values):
        typer.echo(f"error: {option}: {text!r} is not a comma-separated list of lengths in "
                   f"metres (allowed: {'0 <=' if zero else '0 <'} value < 10, e.g. "
                   "2.29e-3,4.83e-3)", err=True)
        raise typer.Exit(2)
    return values


def plates_command(
    kind: str = typer.Option("greens", "--kind",
                             help="greens: Green's functions (what tables use, greens against "
                                  "mindlin_greens); coupled: sem against mindlin."),
    diameters: str | None = typer.Option(None, "--diameters",
                                         help="Sphere diameters, m, comma-separated "
                                              "(default 4.76e-3,9.53e-3,19.05e-3)."),
    thicknesses: str | None = typer.Option(None, "--thicknesses",
                                           help="Plate thicknesses, m (default 1.5, 2.29, 3.18, "
                                                "4.83, 6 mm)."),
    distances: str | None = typer.Option(None, "--distances",
                                         help="Distances to the support, m (default 0.02,0.457)."),
    reference: str = typer.Option("same-mesh", "--reference",
                                  help="The 3-D plate's in-plane mesh: same-mesh (the Mindlin "
                                       "plate's: the theories compared) or default-mesh (the 3-D "
                                       "tier's own sem.elements)."),
    overrides: list[str] | None = typer.Option(
        None, "--set", help="Your set-up, as for simulate, e.g. --set plate.material=ti_6al_4v."),
    as_json: bool = typer.Option(False, "--json", help="Print the results as JSON."),
    quick: bool = typer.Option(False, "--quick", help="Two cheap scenes (checks the machinery)."),
) -> None:
    """The Mindlin plate against the 3-D plate: TOF and ARR errors and the speed-up, per scene."""
    from itertools import product

    from tqdm import tqdm

    from solitonde.instrument.studies import plate_theory
    from solitonde.model.errors import SceneError
    from solitonde.signal.json_ready import json_ready

    if kind not in plate_theory.PAIRS:
        typer.echo(f"error: --kind: {kind!r} (allowed: {', '.join(plate_theory.PAIRS)})",
                   err=True)
        raise typer.Exit(2)
    if reference not in plate_theory.REFERENCES:
        typer.echo(f"error: --reference: {reference!r} (allowed: "
                   f"{', '.join(plate_theory.REFERENCES)})", err=True)
        raise typer.Exit(2)
    given = [_floats(diameters, "--diameters"), _floats(thicknesses, "--thicknesses"),
             _floats(distances, "--distances", zero=True)]
    if quick or all(g is None for g in given):
        points = plate_theory.default_points(quick)
    else:
        axes = [g if g is not None else list(d) for g, d in zip(given, (
            plate_theory.DIAMETERS_M, plate_theory.THICKNESSES_M, plate_theory.DISTANCES_M),
            strict=True)]
        points = [plate_theory.Point(*p) for p in product(*axes)]
    with tqdm(total=len(points), desc="bench plates", disable=not sys.stderr.isatty()) as bar:
        def tick(label: str) -> None:
            bar.set_postfix_str(label)
            bar.update(1)

        try:
            result = plate_theory.compare(points, kind, tick, overrides or [], reference)
        except SceneError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(2) from None
    if as_json:
        typer.echo(json.dumps(json_ready(result), indent=2))
        return
    models, budget = result["models"], result["budget"]
    table = Table(title=f"Mindlin ({models['mindlin']}) against the 3-D plate ({models['3d']}, "
                        f"{result['reference_mesh']}); budget TOF {budget['tof']:.0%}, "
                        f"ARR {budget['arr']:.0%}")
    for name in ("D mm", "t mm", "L mm", "D/t", "elements", "TOF 3-D us", "ARR 3-D", "TOF err %",
                 "ARR err %", "3-D s", "Mindlin s", "speed-up", "ok"):
        table.add_column(name, justify="right")
    for r in result["rows"]:
        table.add_row(f"{r['diameter_m'] * 1e3:.2f}", f"{r['thickness_m'] * 1e3:.2f}",
                      f"{r['distance_m'] * 1e3:.0f}", f"{r['d_over_t']:.2f}",
                      "x".join(map(str, r["elements_mindlin"])),
                      f"{r['tof_3d_s'] * 1e6:.1f}", f"{r['arr_3d']:.4f}",
                      f"{100 * r['tof_error']:.2f}", f"{100 * r['arr_error']:.2f}",
                      f"{r['wall_3d_s']:.2f}", f"{r['wall_mindlin_s']:.2f}",
                      f"{r['speedup']:.1f}", "yes" if r["within_budget"] else "NO")
    console = Console()
    console.print(table)
    console.print("summary: " + json.dumps(json_ready(result["summary"]), indent=2))


def register(app: typer.Typer) -> None:
    """Add the `bench` command group."""
    group = typer.Typer(help="Benchmarks of the model.", no_args_is_help=True,
                        rich_markup_mode=HELP_MARKUP)
    group.command("accuracy")(accuracy_command)
    group.command("plates")(plates_command)
    app.add_typer(group, name="bench")
