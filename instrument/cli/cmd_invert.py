"""`solitonde invert`: thickness and distance to the support from TOF and ARR.

One ``--tof/--arr/--diameter`` triple per sphere size (repeat the options, in the same order, to
combine sizes). Without ``--tof-std``/``--arr-std`` the rig's per-shot scatter is used where
``--calibration`` measured it on its references, else the inversion's stated defaults (1 % of
TOF, 0.03 in ARR per shot).

Exit status: 0 with an answer (bounds included), 1 when the answer is ``inconsistent`` or
``out_of_range`` (printed in full, with the reason on stderr), 2 for bad options.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from solitonde.instrument.cli.common import (
    choice_error,
    parse_material,
    sphere_sizes,
    table_set,
)
from solitonde.instrument.cli.estimate_text import estimate_lines
from solitonde.instrument.inference.calibration import Calibration, CalibrationError
from solitonde.instrument.inference.estimate import Estimate
from solitonde.instrument.inference.inversion_inputs import FeatureSummary, InversionError
from solitonde.instrument.inference.pipeline import estimate
from solitonde.instrument.inference.table_set import TableChoiceError
from solitonde.instrument.tables.table import TableError

if TYPE_CHECKING:
    pass


def _fail(message: str) -> None:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(2)


def describe(est: Estimate) -> str:
    """Human-readable lines for an estimate, its warnings last."""
    if est.out_of_range:
        return "\n".join([f"out of range: {est.reason}", *(f"warning: {w}" for w in
                                                          est.warnings)])
    return "\n".join(estimate_lines(est.to_dict()))


def invert_command(
    tof: list[float] = typer.Option(..., "--tof", help="mean time of flight, s (repeat per "
                                    "sphere size)"),
    arr: list[float] = typer.Option(..., "--arr", help="mean amplitude ratio (repeat)"),
    diameter: list[float] = typer.Option(..., "--diameter", help="sphere diameter, m (repeat)",
                                         callback=sphere_sizes),
    tof_std: list[float] = typer.Option([], "--tof-std", help="shot scatter of TOF, s (default: "
                                        "the calibration's measured one, else 1 % of TOF)"),
    arr_std: list[float] = typer.Option([], "--arr-std", help="shot scatter of ARR (default: "
                                        "the calibration's measured one, else 0.03)"),
    shots: list[int] = typer.Option([], "--shots", help="number of shots averaged"),
    table: list[Path] = typer.Option([], "--table", help="model table or folder of tables "
                                     "(repeat for several plate families; default: "
                                     "$SOLITONDE_TABLE, else data_samples/default_table.h5)"),
    plate_material: str | None = typer.Option(None, "--plate-material", help="the plate's "
                                              "material, a library name or a JSON property "
                                              "mapping (spread keys optional): picks the table "
                                              "of that family; another family is refused"),
    calibration: Path | None = typer.Option(None, "--calibration", help="calibration JSON from "
                                            "`solitonde calibrate`"),
    posterior: bool = typer.Option(False, "--posterior", help="include the 2-D posterior (JSON)"),
    as_json: bool = typer.Option(False, "--json", help="print JSON"),
) -> None:
    """Estimate plate thickness and distance to the nearest support from TOF and ARR."""
    n = len(tof)
    if len(arr) != n or len(diameter) != n:
        _fail(f"--tof, --arr and --diameter must be given the same number of times "
              f"(got {n}, {len(arr)}, {len(diameter)})")
    for name, values in (("--tof-std", tof_std), ("--arr-std", arr_std), ("--shots", shots)):
        if values and len(values) != n:
            _fail(f"{name} must be given once per sphere size ({n}) or not at all")
    try:
        items = [FeatureSummary(diameter[i], tof[i], arr[i],
                                tof_std[i] if tof_std else None, arr_std[i] if arr_std else None,
                                shots[i] if shots else 1) for i in range(n)]
        try:
            material = None if plate_material is None else parse_material(plate_material)
        except ValueError as exc:
            _fail(f"--plate-material: {exc}")
            return
        tables = table_set(table)
        cal = Calibration.load(calibration) if calibration else None
        result = estimate(tables, items, cal, plate_material=material, posterior=posterior)
    except TableChoiceError as exc:
        _fail(choice_error(exc))
        return
    except (InversionError, TableError, CalibrationError) as exc:
        _fail(str(exc))
        return
    if as_json:
        typer.echo(json.dumps(result.to_dict(posterior=posterior)))
    else:
        typer.echo(describe(result.estimate))
    if result.estimate.inconsistent:
        # printed in full above, but no answer to act on: a script must not take it for one
        est = result.estimate
        reason = est.reason or "the table does not explain these features"
        why = est.warnings[0] if est.warnings else f"{est.thickness_m.status}: {reason}"
        typer.echo(f"error: {why}", err=True)
        raise typer.Exit(1)


def register(app: typer.Typer) -> None:
    """Add `invert` to the CLI."""
    app.command("invert")(invert_command)
