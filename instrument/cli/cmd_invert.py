"""`solitonde invert`: thickness and distance to the support from TOF and ARR.

One ``--tof/--arr/--diameter`` triple per sphere size (repeat the options, in the same order, to
combine sizes). Without ``--tof-std``/``--arr-std`` the inversion's stated defaults are used
(1 % of TOF, 0.03 in ARR per shot).

Exit status: 0 with an answer (bounds included), 1 when the answer is ``inconsistent`` or
``out_of_range`` (printed in full, with the reason on stderr), 2 for bad options.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from solitonde.instrument.cli.cmd_table import DEFAULT_TABLE_PATH
from solitonde.instrument.cli.common import sphere_sizes
from solitonde.instrument.inference.calibration import Calibration, CalibrationError
from solitonde.instrument.inference.inversion import Estimate, FeatureSummary, InversionError
from solitonde.instrument.inference.pipeline import estimate
from solitonde.instrument.inference.table_set import TableChoiceError, TableSet
from solitonde.instrument.tables.table import TableError

if TYPE_CHECKING:
    from solitonde.instrument.inference.setups import Setup


def table_path(option: Path | None) -> Path:
    """``--table``, else ``$SOLITONDE_TABLE``, else the default table in data_samples/."""
    if option is not None:
        return option
    env = os.environ.get("SOLITONDE_TABLE")
    return Path(env) if env else DEFAULT_TABLE_PATH


def table_set(options: Sequence[Path] | None) -> TableSet:
    """The tables ``--table`` names (files or folders, repeatable), else the default one.

    Raises TableError when one cannot be loaded (a command line names only tables it means)."""
    paths = list(options or []) or [table_path(None)]
    tables = TableSet(paths, warm_up=False)
    if tables.problems:
        raise TableError("table", "; ".join(tables.problems))
    return tables


def setup_tables(setup: Setup, options: Sequence[Path] | None) -> TableSet:
    """The table a set-up names by id, looked for in this order: ``--table`` (files or
    folders), the bundled tables, ``$SOLITONDE_TABLE``. TableError when none has that id."""
    from solitonde.instrument.tables.bundled import bundled_tables

    env = os.environ.get("SOLITONDE_TABLE")
    found: list[str] = []
    for paths in (list(options or []), bundled_tables(), [Path(env)] if env else []):
        if not paths:
            continue
        tables = TableSet(paths, warm_up=False)
        if setup.table in tables.by_id:
            return TableSet([tables.by_id[setup.table].path], warm_up=False)
        found += [tid for tid in tables.by_id if tid not in found]
    raise TableError("table", f"set-up {setup.id!r} names table {setup.table!r}, which is none "
                     f"of --table, the bundled tables and $SOLITONDE_TABLE (found: "
                     f"{', '.join(found) or 'none'})")


def choice_error(exc: TableChoiceError) -> str:
    """A table-choice error in the command line's words (the flag that picks the table)."""
    flag = "--plate-material" if exc.field == "plate_material" else "--table"
    return f"{flag}: {exc.message}"


def parse_material(text: str) -> Any:
    """``--plate-material``: a library name, or a JSON property mapping (checked here, so a bad
    key is named before anything runs). Raises ValueError naming the key."""
    from solitonde.model.materials import properties_from

    text = text.strip()
    if not text.startswith("{"):
        properties_from(text)
        return text
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"not a library name nor a JSON mapping ({exc.msg} at character "
                         f"{exc.pos})") from None
    properties_from(value)
    return value


def where_estimated(row: Mapping[str, Any]) -> str:
    """Where an `analyze --invert` estimate was made, in words (a missing plate id or position
    is said so, never printed as None)."""
    plate = row.get("plate_id")
    position = row.get("position")
    return (f"estimate for plate {plate if plate is not None else '(no plate id)'}, position "
            f"{position if position is not None else '(no position)'}")


def _fail(message: str) -> None:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(2)


def _fmt_mm(v: float | None) -> str:
    return "-" if v is None else f"{v * 1e3:.3f}"


def _parameter_text(p: Mapping[str, Any], full: bool) -> str:
    """One parameter's answer in words (``full``: with the MAP and the 68 % interval)."""
    status, ci95 = p["status"], p.get("ci95") or [None, None]
    if status == "constrained":
        if full:
            return (f"{_fmt_mm(p['median'])} mm (MAP {_fmt_mm(p['map'])}; 68 % "
                    f"{_fmt_mm(p['ci68'][0])}..{_fmt_mm(p['ci68'][1])}; 95 % "
                    f"{_fmt_mm(ci95[0])}..{_fmt_mm(ci95[1])} mm)")
        return f"{_fmt_mm(p['median'])} mm (95 % {_fmt_mm(ci95[0])}..{_fmt_mm(ci95[1])} mm)"
    if status == "lower_bound_only":
        return f"at least {_fmt_mm(ci95[0])} mm (95 %)" + (
            "; the data do not bound it from above" if full else "")
    if status == "upper_bound_only":
        return f"at most {_fmt_mm(ci95[1])} mm (95 %)" + (
            "; the data do not bound it from below" if full else "")
    if status == "ambiguous":
        lo, hi = ci95
        span = (f"{_fmt_mm(lo)}..{_fmt_mm(hi)} mm" if lo is not None and hi is not None else
                f"from {_fmt_mm(lo)} mm" if lo is not None else
                f"up to {_fmt_mm(hi)} mm" if hi is not None else "unbounded")
        return f"AMBIGUOUS: the data fit the readings below, {span} over them all (95 %)"
    if status == "inconsistent":
        return "INCONSISTENT with the table's family (no estimate)"
    return "unconstrained by these data" if full else status


def estimate_lines(est: Mapping[str, Any], full: bool = True, indent: str = "") -> list[str]:
    """An estimate (``Estimate.to_dict()``) in words: each parameter, an ambiguous answer's
    readings, the fit, the warnings last."""
    lines = []
    for key, name in (("thickness_m", "thickness"), ("distance_m", "distance to support")):
        lines.append(f"{indent}{name}: {_parameter_text(est[key], full)}")
    for k, r in enumerate(est.get("readings") or [], 1):
        lines.append(f"{indent}  reading {k} (weight {r['weight']:.2g}): thickness "
                     f"{_parameter_text(r['thickness_m'], False)}, distance to support "
                     f"{_parameter_text(r['distance_m'], False)}")
    fit = est.get("fit") or {}
    if fit.get("p_value") is not None:
        lines.append(f"{indent}fit: chi^2 {fit['chi2']:.3g} for {fit['dof']:.2g} degrees of "
                     f"freedom, p = {fit['p_value']:.2g}")
    lines += [f"{indent}warning: {w}" for w in est.get("warnings", [])]
    return lines


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
    tof_std: list[float] = typer.Option([], "--tof-std", help="shot scatter of TOF, s"),
    arr_std: list[float] = typer.Option([], "--arr-std", help="shot scatter of ARR"),
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


def describe_row(row: Mapping[str, Any]) -> str:
    """One `analyze --invert` estimate as text."""
    head = where_estimated(row)
    if row.get("x_m") is not None and row.get("y_m") is not None:
        head += f" (x {row['x_m']:g} m, y {row['y_m']:g} m)"
    head += ":"
    est = row.get("estimate")
    if est is None:
        why = row.get("error") or "; ".join(s["reason"] for s in row.get("skipped", [])) or "-"
        return f"{head} none ({why})"
    lines = [head, *estimate_lines(est, full=False, indent="  ")]
    return "\n".join(lines)
