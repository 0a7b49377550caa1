"""`solitonde calibrate`: fit the chain's damping, ARR factor and TOF offset from shots on a
reference plate.

Against a table with a dissipation layer (the bundled ones) the chain's Kuwabara-Kono damping
tau comes first, and the table is read at it (instrument.tables.dissipation): the loss then
follows the plate, as a real chain's does. The factor and offset hold what damping leaves.

The reference plate's thickness and the chain's distance to the support are known; the shots are
waveform files (analysed and aggregated per sphere size, as `analyze` does) or, with ``--tof``,
``--arr`` and ``--diameter`` (repeatable, same order), already measured means. Several reference
plates, or one plate at several distances, are given with ``--reference THICKNESS_M,DISTANCE_M,
FILE_OR_FOLDER`` (repeatable; beside or instead of the one-plate form): references at two or more
distances give the factor and offset per distance as well (``by_distance``), which the inversion
reads at each candidate distance. The result is written as JSON (``--out``) for
`invert --calibration` and the service.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import NoReturn

import typer

from solitonde.instrument.cli.common import sphere_sizes, table_path
from solitonde.instrument.inference.calibration import Calibration, CalibrationError
from solitonde.instrument.inference.calibration_fit import Reference, fit_calibration
from solitonde.instrument.inference.inversion_inputs import FeatureSummary, InversionError
from solitonde.instrument.tables.table import ModelTable, TableError
from solitonde.signal.errors import WaveformError


def _fail(message: str) -> NoReturn:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(2)


def summaries_from_files(files: list[Path], diameter: float | None) -> list[FeatureSummary]:
    """Per sphere size: the aggregate of every shot in ``files`` (the measured-shot road, as
    `analyze` walks it); ``diameter`` is the sphere size of every shot (for files without one)."""
    from solitonde.instrument.inference import measured_shots
    from solitonde.instrument.inference.pipeline import no_reflection

    paths, missing = measured_shots.collect(files)
    if missing:
        raise CalibrationError("files", missing[0]["error"])
    rows = []
    for p in paths:
        try:
            file_rows, _ = measured_shots.measure_file(p, None, {})
        except (WaveformError, measured_shots.ShotInputError) as exc:
            raise CalibrationError("files", f"{p}: {exc}") from None
        rows.extend(file_rows)
    if diameter is not None:
        for r in rows:
            r["sphere_diameter"] = diameter
    out = []
    for g in measured_shots.summarise_positions(rows):
        if g.summary.diameter_m is None:
            raise CalibrationError("sphere_diameter", "the shots carry no sphere_diameter "
                                   "metadata; give --diameter")
        reason = g.summary.skip_reason()
        if reason is None and g.summary.hidden:  # a bound is no reference measurement
            reason = no_reflection(g.summary.diameter_m)
        if reason is not None:
            raise CalibrationError("files", reason)
        out.append(g.summary.inputs())
    if not out:
        raise CalibrationError("files", "no shot could be analysed")
    return out


def parse_reference(text: str) -> tuple[float, float, Path]:
    """``THICKNESS_M,DISTANCE_M,FILE_OR_FOLDER`` as (thickness, distance, path); the path is the
    rest after the second comma (it may hold commas itself).

    Raises
    ------
    CalibrationError
        (field ``--reference``) When a part is missing, a number is not a positive finite one
        (the distance may be 0: the clamp itself), or the path does not exist.
    """
    parts = text.split(",", 2)
    if len(parts) != 3 or not parts[2].strip():
        raise CalibrationError("--reference", f"expected THICKNESS_M,DISTANCE_M,FILE_OR_FOLDER, "
                               f"got {text!r}")
    numbers = []
    for name, raw in (("thickness", parts[0]), ("distance", parts[1])):
        try:
            value = float(raw)
        except ValueError:
            raise CalibrationError("--reference", f"{text!r}: the {name} {raw.strip()!r} is not "
                                   "a number (in m)") from None
        if not math.isfinite(value) or value < 0 or (name == "thickness" and value == 0):
            raise CalibrationError("--reference", f"{text!r}: the {name} must be a "
                                   f"{'positive' if name == 'thickness' else 'non-negative'} "
                                   f"finite number of m, got {raw.strip()!r}")
        numbers.append(value)
    path = Path(parts[2].strip())
    if not path.exists():
        raise CalibrationError("--reference", f"{text!r}: {str(path)!r} does not exist")
    return numbers[0], numbers[1], path


def calibrate_command(
    files: list[Path] = typer.Argument(None, help="waveform files or folders of reference shots"),
    thickness: float | None = typer.Option(None, "--thickness",
                                           help="reference plate thickness, m"),
    distance: float | None = typer.Option(None, "--distance",
                                          help="reference distance to support, m"),
    reference: list[str] = typer.Option(
        [], "--reference", metavar="THICKNESS_M,DISTANCE_M,FILE_OR_FOLDER",
        help="a reference plate's thickness, the chain's distance to its support and its shot "
        "files (repeat for several plates or distances; references at two or more distances "
        "give the factor and offset per distance)"),
    diameter: list[float] = typer.Option([], "--diameter", callback=sphere_sizes,
                                         help="sphere diameter, m (for files "
                                         "without metadata: one value; with --tof: repeat)"),
    tof: list[float] = typer.Option([], "--tof", help="mean TOF, s (instead of files; repeat)"),
    arr: list[float] = typer.Option([], "--arr", help="mean ARR (instead of files; repeat)"),
    tof_std: list[float] = typer.Option([], "--tof-std", help="TOF shot scatter, s"),
    arr_std: list[float] = typer.Option([], "--arr-std", help="ARR shot scatter"),
    shots: list[int] = typer.Option([], "--shots", help="shots per mean"),
    table: Path | None = typer.Option(None, "--table", help="model table"),
    out: Path = typer.Option(Path("calibration.json"), "--out", help="calibration JSON to write"),
    as_json: bool = typer.Option(False, "--json", help="print the calibration as JSON"),
) -> None:
    """Fit the chain's damping (with a table's dissipation layer), ARR factor and TOF offset per
    sphere size on a reference plate; write them as JSON.

    References at two or more distances to the support (--reference, repeated) give the
    factor and offset per distance as well."""
    if out.is_dir():  # before any work: the fit would be lost
        _fail(f"--out: {str(out)!r} is a directory; give the name of the JSON file to write")
    try:
        refs = _references(files, thickness, distance, reference, diameter,
                           Means(tof, arr, tof_std, arr_std, shots))
        model = ModelTable.load(table_path(table))
        cal = fit_calibration(model, refs)
    except (CalibrationError, InversionError, TableError) as exc:
        _fail(str(exc))
    try:
        cal.save(out)
    except CalibrationError as exc:
        _fail(f"--out: {exc.full_message}")
    if as_json:
        typer.echo(json.dumps(cal.to_dict(), indent=2))
    else:
        for line in _calibration_lines(cal):
            typer.echo(line)
        typer.echo(f"wrote {out}")


@dataclass(frozen=True)
class Means:
    """Features already measured on the one reference plate (``--tof``, ``--arr`` and their
    scatter and shot counts), one entry per sphere size."""

    tof: list[float]
    arr: list[float]
    tof_std: list[float]
    arr_std: list[float]
    shots: list[int]


def _references(files: list[Path] | None, thickness: float | None, distance: float | None,
                reference: list[str], diameter: list[float], means: Means) -> list[Reference]:
    """The references the options give: the one plate (``--thickness``, ``--distance`` with
    files or means), then each ``--reference``; a combination that does not fit exits 2."""
    refs: list[Reference] = []
    one_plate = bool(means.tof or means.arr or files)
    if one_plate and (thickness is None or distance is None):
        _fail("give the reference plate's --thickness and --distance (or each reference as "
              "--reference THICKNESS_M,DISTANCE_M,FILE_OR_FOLDER)")
    if (thickness is not None or distance is not None) and not one_plate:
        _fail("--thickness and --distance need reference shot files or --tof/--arr/"
              "--diameter; with --reference each reference carries its own")
    if (files or reference) and len(diameter) > 1:
        _fail("with files give at most one --diameter")
    if one_plate:
        assert thickness is not None and distance is not None
        refs += [Reference(thickness, distance, s)
                 for s in _one_plate_summaries(files, diameter, means)]
    for text in reference:
        t_ref, l_ref, path = parse_reference(text)
        refs += [Reference(t_ref, l_ref, s)
                 for s in summaries_from_files([path], diameter[0] if diameter else None)]
    if not refs:
        _fail("give reference shot files, --tof/--arr/--diameter, or --reference "
              "THICKNESS_M,DISTANCE_M,FILE_OR_FOLDER")
    return refs


def _one_plate_summaries(files: list[Path] | None, diameter: list[float],
                         means: Means) -> list[FeatureSummary]:
    """The one reference plate's features per sphere size: the means given, else the shot
    files measured."""
    if means.tof or means.arr:
        n = len(means.tof)
        if len(means.arr) != n or len(diameter) != n:
            _fail("--tof, --arr and --diameter must be given the same number of times")
        return [FeatureSummary(diameter[i], means.tof[i], means.arr[i],
                               means.tof_std[i] if means.tof_std else None,
                               means.arr_std[i] if means.arr_std else None,
                               means.shots[i] if means.shots else 1) for i in range(n)]
    assert files
    return summaries_from_files(files, diameter[0] if diameter else None)


def _calibration_lines(cal: Calibration) -> list[str]:
    """The fitted calibration as printed: per sphere size, then per distance where fitted."""
    lines = []
    for e in cal.to_dict()["per_diameter"]:
        damping = ("" if "damping_s" not in e else
                   f"damping tau {e['damping_s']:.3g} +- {e['damping_std_s']:.2g} s, ")
        lines.append(f"D = {e['diameter_m'] * 1e3:.4g} mm: {damping}"
                     f"arr_factor {e['arr_factor']:.4f} "
                     f"+- {e['arr_factor_std']:.4f}, tof_offset {e['tof_offset_s'] * 1e6:.3f} "
                     f"+- {e['tof_offset_std_s'] * 1e6:.3f} us")
        if "shot_scatter_dof" in e:
            lines.append(f"  per-shot scatter of the references ({e['shot_scatter_dof']} degrees "
                         f"of freedom): TOF {e['shot_tof_rel_std'] * 100:.2g} %, ARR "
                         f"{e['shot_arr_std']:.2g}; single shots are read with it")
        for row in e.get("by_distance", []):
            lines.append(f"  at L = {row['distance_m'] * 1e3:.4g} mm "
                         f"({row.get('n_references', 1)} ref.): arr_factor "
                         f"{row['arr_factor']:.4f} +- {row.get('arr_factor_std', 0.0):.4f}, "
                         f"tof_offset {row['tof_offset_s'] * 1e6:.3f} "
                         f"+- {row.get('tof_offset_std_s', 0.0) * 1e6:.3f} us")
    return lines


def register(app: typer.Typer) -> None:
    """Add `calibrate` to the CLI."""
    app.command("calibrate")(calibrate_command)
