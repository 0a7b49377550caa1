"""`solitonde analyze`: TOF, ARR, SNR and flags for every shot in waveform files or folders.

One row per shot, an aggregate per position (plate, position, coordinates, sphere diameter); a
file that names neither plate nor position is a position of its own. A file that fails, for
whatever reason, is reported with its error and the others go on; the exit code says whether all
succeeded (0 all, 1 some files or shots failed, 2 usage: a missing file, a bad option or
manifest).

Files come from the vendors' software as they are (scope CSVs, DAQ TDMS, HDF5 ...). A file with
several channels is analysed on the channels named by ``--channel``/``--group``, or else on those
that are sensor traces (signal.channels): a trigger step or a flat line is never a shot, and is
reported as skipped. Where a file does not carry them, the sphere size, plate, position and its
coordinates come from the command line (``--sphere-diameter`` ...) or a campaign manifest
(``--manifest``, instrument.manifest); a file's own metadata must agree with them, and all of it
is held to the limits the service holds it to (a file whose metadata the service would refuse
fails here too, naming the key; a flag's value, naming the flag).

Reading, checking, grouping by position and summarising are the measured-shot road's
(instrument.inference.measured_shots), shared with `calibrate` and the service; this module
translates the command line into its calls and its errors into messages and exit codes.

The global reader options apply where they make sense: ``--sample-rate`` gives the rate of data
without a time axis and must agree with any file's own; ``--units`` says what data that do not
state their units are in, and must agree with any file that does; ``--calibration`` converts the
files in volts that carry no calibration (a run in which no file used it reports that).
"""

from __future__ import annotations

import io
import json
import math
import re
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn, NotRequired, TypedDict, cast

import typer
from rich.console import Console

from solitonde.instrument.cli.analyze_estimates import (
    PositionEstimate,
    estimate_failures,
    estimates_for_locations,
    write_estimates,
)
from solitonde.instrument.cli.common import sphere_sizes
from solitonde.instrument.cli.console_tables import Column, fitted_table
from solitonde.instrument.cli.manifest import ManifestError, Row
from solitonde.instrument.inference import measured_shots
from solitonde.instrument.inference.measured_shots import (
    LOCATION_KEYS,
    PEAK_READING,
    PositionShots,
    ShotInputError,
    ShotLocation,
    ShotRow,
)
from solitonde.instrument.inference.pipeline import AggregateDict
from solitonde.signal import io as signal_io
from solitonde.signal.errors import WaveformError
from solitonde.signal.features import FEATURES
from solitonde.signal.waveform import UNITS

if TYPE_CHECKING:
    from solitonde.instrument.inference.setups import Setup

OUT_SUFFIXES = (".csv", ".parquet")
ROW_KEYS = ("source", "shot", "channel", *FEATURES, *PEAK_READING, "flags", "arr_upper_bound",
            "baseline",
            *LOCATION_KEYS, "error")
FLAGS = {"plate_id": "--plate-id", "position": "--position", "x_m": "--x", "y_m": "--y",
         "sphere_diameter": "--sphere-diameter", "sample_rate": "--sample-rate",
         "dt": "--sample-rate", "units": "--units", "calibration": "--calibration",
         "channel": "--channel", "group": "--group", "format": "--format",
         "baseline": "--baseline"}
"""Command-line flags by the option or metadata key they set (for messages)."""


def flag_message(text: str) -> str:
    """A reader's message with its option names (``sample_rate=``, a leading ``units:``) as the
    command line's flags (``--sample-rate``)."""
    text = text.replace("sample_rate= in Hz (or dt= in s)", "--sample-rate in Hz")
    for key, flag in FLAGS.items():
        text = re.sub(rf"(?<![\w-]){key}=", flag + " ", text)
        if text.startswith(f"{key}: "):
            text = f"{flag}: {text[len(key) + 2:]}"
    return text


class StatedLocation(TypedDict, total=False):
    """The location metadata the command line states for every file (the keys given)."""

    plate_id: str
    position: str
    x_m: float
    y_m: float
    sphere_diameter: float
    baseline: str


@dataclass(frozen=True)
class Choice:
    """What the command line says about every file: channels, group and location metadata."""

    channels: tuple[str, ...] = ()
    group: str | None = None
    metadata: StatedLocation = field(default_factory=StatedLocation)


def analyse_file(path: Path, fmt: str | None, options: ReaderOptions,
                 calibration: float | None = None, choice: Choice | None = None,
                 row: Row | None = None) -> tuple[list[ShotRow], bool]:
    """One row per shot of ``path`` (instrument.inference.measured_shots.measure_file) and
    whether ``calibration`` (a fallback for files in volts without their own) was used.

    What the command line (``choice``) and the manifest ``row`` state joins each shot's own
    metadata; a manifest row's calibration serves its file before ``--calibration``."""
    choice = choice or Choice()
    own = row.calibration if row is not None and row.calibration is not None else None
    sources: list[tuple[str, Mapping[str, Any]]] = [
        (FLAGS[k], {k: v}) for k, v in choice.metadata.items()]
    if row is not None and row.metadata:
        sources.append((row.where, row.metadata))
    rows, used = measured_shots.measure_file(
        path, fmt, options, fallback_calibration=own if own is not None else calibration,
        channels=choice.channels, group=choice.group, stated=sources)
    return rows, used and own is None  # whether --calibration served


class PositionAggregate(ShotLocation, AggregateDict):
    """A summary as `analyze --json` prints it: the location, then the aggregate."""


def aggregates(groups: list[PositionShots]) -> list[PositionAggregate]:
    """The summaries as JSON: location, then the aggregate; each rejected shot names its file
    and shot number."""
    out: list[PositionAggregate] = []
    for g in groups:
        agg = cast(AggregateDict, g.summary.aggregate.to_dict())
        for rej in agg["rejected"]:
            m = g.rows[rej["index"]]
            rej["source"] = m["source"]
            rej["shot"] = m["shot"]
        out.append({**g.location, **agg})
    return out


def _write_rows(out: Path, rows: list[ShotRow]) -> None:
    import pandas as pd

    table = pd.DataFrame([{k: r.get(k) for k in ROW_KEYS} for r in rows], columns=list(ROW_KEYS))
    table["flags"] = table["flags"].map(lambda f: ";".join(f) if isinstance(f, list) else "")
    table["shot"] = table["shot"].astype("Int64")
    for col in ("plate_id", "position", "sphere_diameter", "error", "source", "channel"):
        table[col] = table[col].map(lambda v: None if v is None else str(v))
    from solitonde.instrument.inference.estimate_rows import neutralised
    from solitonde.instrument.studies.figures import write_bytes

    if out.suffix.lower() == ".parquet":
        buf = io.BytesIO()
        table.to_parquet(buf, index=False)
        write_bytes(out, buf.getvalue())
    else:
        write_bytes(out, neutralised(table).to_csv(index=False).encode())


def _write_plots(folder: Path, rows: list[ShotRow]) -> None:
    """One PNG per measured shot, named ``<stem>_shot<k>.png`` after its file and shot number.

    Files that share a stem (``x.csv`` and ``x.npy``, or ``a/x.csv`` and ``b/x.csv``) keep the
    extension in the name and then a counter, so no shot's plot overwrites another's.
    """
    from solitonde.instrument.plotting import trace_png
    from solitonde.instrument.studies.figures import write_bytes

    folder.mkdir(parents=True, exist_ok=True)
    used: set[str] = set()
    for r in rows:
        if "features" not in r:
            continue
        w = r["waveform"]
        shot = r["shot"] if r["shot"] is not None else 0
        name = f"{Path(r['source']).stem}_shot{shot}.png"
        if name in used:
            base, k = f"{Path(r['source']).name}_shot{shot}", 2
            name = f"{base}.png"
            while name in used:
                name, k = f"{base}_{k}.png", k + 1
        used.add(name)
        png = trace_png(w.t0, w.dt, w.samples, r["features"].to_dict(), units="N",
                        title=f"{Path(r['source']).name}, shot {r['shot']}")
        write_bytes(folder / name, png)


def _fmt(value: Any, scale: float = 1.0, digits: int = 4) -> str:
    return "-" if value is None else f"{value * scale:.{digits}g}"


def analyze(
    files: list[Path] = typer.Argument(None, help="Waveform files or folders (recursive); "
                                       "optional with --manifest.", show_default=False),
    fmt: str | None = typer.Option(None, "--format", help="Force a format: " +
                                   ", ".join(signal_io.FORMATS) + "."),
    out: Path | None = typer.Option(None, "--out", help="Write the per-shot rows to a .csv or "
                                    ".parquet file."),
    as_json: bool = typer.Option(False, "--json", help="Print shots, aggregates and errors as "
                                 "JSON."),
    sample_rate: float | None = typer.Option(None, "--sample-rate", help="Hz, for data without a "
                                             "time axis (a file's own time axis must agree)."),
    calibration: float | None = typer.Option(None, "--calibration", help="N/V, for files in "
                                             "volts that carry no calibration."),
    units: str | None = typer.Option(None, "--units", help="N or V, for data that do not state "
                                     "their units (a file that states them must agree)."),
    channel: list[str] = typer.Option([], "--channel", help="Analyse this channel (repeat): a "
                                      "column name, or a TDMS channel as group/channel or "
                                      "channel. Default: the channels that are sensor traces."),
    group: str | None = typer.Option(None, "--group", help="Only the channels of this TDMS "
                                     "group."),
    sphere_diameter: float | None = typer.Option(None, "--sphere-diameter", callback=sphere_sizes,
                                                 help="m, for every file (a file's own must "
                                                 "agree)."),
    baseline: str | None = typer.Option(None, "--baseline", help="What a shot of a stated "
                                        "sphere size has its baseline measured on: gap (the "
                                        "default: the pre-trigger and the gap before the "
                                        "reflection, less the chain's simulated relaxation; "
                                        "drift-proof) or pre-trigger (for a chain unlike the "
                                        "paper's: another length or sensor, horizontal)."),
    plate_id: str | None = typer.Option(None, "--plate-id", help="Plate, for every file."),
    position: str | None = typer.Option(None, "--position", help="Position name, for every "
                                        "file."),
    x: float | None = typer.Option(None, "--x", help="m, the position's x on the plate."),
    y: float | None = typer.Option(None, "--y", help="m, the position's y on the plate."),
    manifest: Path | None = typer.Option(None, "--manifest", help="Campaign manifest (.csv or "
                                         ".yaml): per file or glob, plate_id, position, x_m, "
                                         "y_m, sphere_diameter_m, calibration_N_per_V."),
    invert: bool = typer.Option(False, "--invert", help="Also estimate thickness and distance "
                                "to support per position (sphere sizes combined)."),
    estimates_out: Path | None = typer.Option(None, "--estimates-out", help="Write the "
                                              "estimates, one row per plate and position, to a "
                                              ".csv or .parquet file (implies --invert)."),
    table: list[Path] = typer.Option([], "--table", help="Model table (or folder of tables) for "
                                     "--invert; repeat for several plate families."),
    plate_material: str | None = typer.Option(None, "--plate-material", help="The plate's "
                                              "material: a library name, or a JSON property "
                                              "mapping {name, youngs_modulus, poisson_ratio, "
                                              "density[, youngs_modulus_rel_sd, poisson_ratio_sd,"
                                              " density_rel_sd]}: --invert uses the table of "
                                              "that family, refuses another, and carries the "
                                              "stated spread."),
    calibration_file: Path | None = typer.Option(None, "--calibration-file", help="Calibration "
                                                 "JSON (solitonde calibrate) for --invert."),
    plots: Path | None = typer.Option(None, "--plots", help="Folder for one PNG per shot (trace "
                                      "with the detected pulses marked)."),
    setup_file: Path | None = typer.Option(None, "--setup", help="An instrument set-up saved "
                                           "from the service (GET /v1/setups/ID): its sphere "
                                           "size, table (found by id among --table, the "
                                           "bundled tables and $SOLITONDE_TABLE) and chain "
                                           "calibration, as the service applies them."),
) -> None:
    """Measure TOF, ARR, SNR and quality flags of every shot; aggregate per position."""
    request = AnalyzeRequest(
        files=list(files or []), fmt=fmt, out=out, as_json=as_json, sample_rate=sample_rate,
        calibration=calibration, units=units, channels=tuple(channel), group=group,
        sphere_diameter=sphere_diameter, baseline=baseline, plate_id=plate_id,
        position=position, x=x, y=y, manifest=manifest,
        invert=invert or estimates_out is not None, estimates_out=estimates_out, table=table,
        plate_material=plate_material, calibration_file=calibration_file, plots=plots,
        setup_file=setup_file)
    raise typer.Exit(code=run_analysis(request))


@dataclass
class AnalyzeRequest:
    """The options of one `analyze` run, as the command line gives them (``invert`` already
    implied by ``estimates_out``; ``sphere_diameter`` filled in from a one-size set-up)."""

    files: list[Path]
    fmt: str | None
    out: Path | None
    as_json: bool
    sample_rate: float | None
    calibration: float | None
    units: str | None
    channels: tuple[str, ...]
    group: str | None
    sphere_diameter: float | None
    baseline: str | None
    plate_id: str | None
    position: str | None
    x: float | None
    y: float | None
    manifest: Path | None
    invert: bool
    estimates_out: Path | None
    table: list[Path]
    plate_material: str | None
    calibration_file: Path | None
    plots: Path | None
    setup_file: Path | None


class ReaderOptions(TypedDict):
    """The global reader options `analyze` passes to every file it reads."""

    sample_rate: float | None
    units: str | None


class FailedSource(TypedDict):
    """A file, shot, option or position that failed, as `analyze` reports it."""

    source: str
    shot: NotRequired[int | None]
    error: str | None


class SkippedChannel(TypedDict):
    """A channel that is not a sensor trace, and why it was left out."""

    source: str
    channel: str | None
    reason: str


@dataclass
class Analysis:
    """What a run measured: the shots, their summaries per position, what was left out and
    what failed (``estimates`` None unless ``--invert``, or when no estimate could be made)."""

    rows: list[ShotRow]  # measured_shots' rows, one per shot
    groups: list[PositionShots]
    skipped: list[SkippedChannel]
    errors: list[FailedSource]
    estimates: list[PositionEstimate] | None = None


def _usage(message: str) -> NoReturn:
    """A usage error: one unwrapped line for scripts and logs, exit code 2."""
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(code=2)


def run_analysis(request: AnalyzeRequest) -> int:
    """Check the options, measure every file, estimate, write and print; the exit code (0 all
    succeeded, 1 some files or shots failed or there were none; usage errors exit 2 here)."""
    console = Console(stderr=request.as_json)
    setup = _load_setup(request)
    _check_outputs(request)
    material = _check_reading(request)
    choice = Choice(request.channels, request.group, _stated(request))
    jobs = _jobs(request)
    analysis = _measure(jobs, request, choice)
    if request.invert:
        analysis.estimates = _estimate(analysis, request, material, setup)
    _write_outputs(request, analysis)
    _show(console, request, analysis)
    return 1 if analysis.errors or not jobs else 0


def _load_setup(request: AnalyzeRequest) -> Setup | None:
    """The ``--setup`` file, checked against ``--calibration-file`` and ``--sphere-diameter``;
    a set-up of one sphere size gives ``request`` that size when it states none."""
    if request.setup_file is None:
        return None
    from solitonde.instrument.inference.setups import Setup, SetupError

    try:
        setup = Setup.load(request.setup_file)
    except SetupError as exc:
        _usage(f"--setup: {exc}")
    if request.calibration_file is not None and setup.chain_calibration is not None:
        _usage(f"--calibration-file: set-up {setup.id!r} (revision {setup.revision}) has "
               "its own chain calibration; give one of the two")
    size = request.sphere_diameter
    if size is not None and setup.size_of(size) is None:
        _usage(f"--sphere-diameter: {size:g} m contradicts --setup {setup.id!r}, "
               f"whose sphere_diameters_m are "
               f"{', '.join(f'{d:g}' for d in setup.sphere_diameters_m)} m")
    if size is None and len(setup.sphere_diameters_m) == 1:
        request.sphere_diameter = setup.sphere_diameters_m[0]
    return setup


def _check_outputs(request: AnalyzeRequest) -> None:
    """The output paths: a table's suffix, a file where a file goes, a folder for the plots."""
    for flag, path in (("--out", request.out), ("--estimates-out", request.estimates_out)):
        if path is not None and path.suffix.lower() not in OUT_SUFFIXES:
            _usage(f"{flag}: {path.name} must end in {' or '.join(OUT_SUFFIXES)}")
    for flag, path, want in (("--out", request.out, "file"),
                             ("--estimates-out", request.estimates_out, "file"),
                             ("--plots", request.plots, "folder")):
        if path is not None and (path.is_dir() if want == "file"
                                 else path.exists() and not path.is_dir()):
            _usage(f"{flag}: {str(path)!r} is a {'folder' if want == 'file' else 'file'}; "
                   f"give a {want}")


def _check_reading(request: AnalyzeRequest) -> Any:
    """The reader options and numbers checked; the parsed ``--plate-material`` (or None)."""
    if request.fmt is not None:
        try:
            signal_io.detect_format("x", request.fmt)
        except WaveformError as exc:
            _usage(f"--format: {exc.message} (allowed: {exc.allowed})")
    if request.units is not None and request.units not in UNITS:
        _usage(f"--units: {request.units!r} is not N or V")
    material: Any = None
    if request.plate_material is not None:
        from solitonde.instrument.cli.common import parse_material

        try:
            material = parse_material(request.plate_material)
        except ValueError as exc:
            _usage(f"--plate-material: {exc}")
    for flag, value in (("--x", request.x), ("--y", request.y),
                        ("--sample-rate", request.sample_rate),
                        ("--calibration", request.calibration)):
        if value is not None and not math.isfinite(value):
            _usage(f"{flag}: {value} is not a finite number")
    for flag, value in (("--sample-rate", request.sample_rate),
                        ("--calibration", request.calibration)):
        if value is not None and value <= 0:
            _usage(f"{flag}: {value:g} must be > 0")
    return material


def _stated(request: AnalyzeRequest) -> StatedLocation:
    """The location metadata the flags state for every file, held to the limits the service
    holds metadata to."""
    given = StatedLocation()
    if request.plate_id is not None:
        given["plate_id"] = request.plate_id
    if request.position is not None:
        given["position"] = request.position
    if request.x is not None:
        given["x_m"] = request.x
    if request.y is not None:
        given["y_m"] = request.y
    if request.sphere_diameter is not None:
        given["sphere_diameter"] = request.sphere_diameter
    if request.baseline is not None:
        given["baseline"] = request.baseline
    try:
        measured_shots.check_metadata([given], measured_shots.shot_fields(""))
    except ShotInputError as exc:
        _usage(flag_message(str(exc)))
    return given


def _jobs(request: AnalyzeRequest) -> list[tuple[Path, Row | None]]:
    """The files to read, each with its manifest row where ``--manifest`` gives one."""
    files = request.files
    if not files and request.manifest is None:
        _usage("give waveform files or folders, or --manifest")
    paths, missing = measured_shots.collect(files, request.fmt)
    if missing:
        _usage("; ".join(m["error"] for m in missing))
    if request.manifest is not None:
        return _manifest_jobs(request.manifest, paths if files else None, request.fmt)
    return [(p, None) for p in paths]


def _measure(jobs: list[tuple[Path, Row | None]], request: AnalyzeRequest,
             choice: Choice) -> Analysis:
    """Every file's shots measured, the channels left out set apart, the failures listed, the
    shots summarised per position."""
    options: ReaderOptions = {"sample_rate": request.sample_rate, "units": request.units}
    if jobs:  # a fresh install: a few shots interpreted while the extractor compiles
        from solitonde.signal import kernel_choice

        kernel_choice.start()
    calibration_used = False
    rows: list[ShotRow] = []
    errors: list[FailedSource] = []
    from tqdm import tqdm

    for path, row in tqdm(jobs, desc="analyze", unit="file", file=sys.stderr,
                          disable=len(jobs) < 5 or not sys.stderr.isatty()):
        try:
            file_rows, used = analyse_file(path, request.fmt, options, request.calibration,
                                           choice, row)
        except WaveformError as exc:
            errors.append({"source": str(path), "error": flag_message(str(exc))})
            continue
        except ShotInputError as exc:  # metadata the service would refuse too
            errors.append({"source": str(path), "error": str(exc)})
            continue
        except Exception as exc:  # any broken file is its own error; Ctrl-C still stops the run
            errors.append({"source": str(path), "error": f"{type(exc).__name__}: {exc}"})
            continue
        rows.extend(file_rows)
        calibration_used = calibration_used or used
    if request.calibration is not None and jobs and not calibration_used and not errors:
        errors.append({"source": "--calibration", "error": "no file holds volts without a "
                       "calibration of its own; --calibration was not used"})
    skipped: list[SkippedChannel] = [
        {"source": r["source"], "channel": r["channel"], "reason": r["skipped"]}
        for r in rows if "skipped" in r]
    rows = [r for r in rows if "skipped" not in r]
    for r in rows:
        if "error" in r:
            errors.append({"source": r["source"], "shot": r["shot"],
                           "error": flag_message(r["error"])})
    return Analysis(rows, measured_shots.summarise_positions(rows), skipped, errors)


def _estimate(analysis: Analysis, request: AnalyzeRequest, material: Any,
              setup: Setup | None) -> list[PositionEstimate] | None:
    """The estimates per position (None when a table or the calibration cannot be read); what
    fails is added to ``analysis.errors``."""
    from solitonde.instrument.cli.common import table_path
    from solitonde.instrument.inference.calibration import CalibrationError
    from solitonde.instrument.tables.table import TableError

    estimates = None
    try:
        estimates = estimates_for_locations(analysis.groups, request.table,
                                            request.calibration_file, material, setup)
    except CalibrationError as exc:
        analysis.errors.append({"source": str(request.calibration_file), "error": str(exc)})
    except (TableError, ValueError, OSError) as exc:  # table unreadable
        analysis.errors.append({"source": ", ".join(map(str, request.table))
                                or str(table_path(None)), "error": str(exc)})
    for where, why in estimate_failures(estimates or []):
        analysis.errors.append({"source": where, "error": why})
    return estimates


def _write_outputs(request: AnalyzeRequest, analysis: Analysis) -> None:
    """``--out``, ``--plots`` and ``--estimates-out``; a file that cannot be written is an
    error of the run, and the analysis stands."""
    rows, estimates = analysis.rows, analysis.estimates
    outputs: list[tuple[str, Path | None, Callable[[Path], None]]] = [
        ("--out", request.out, lambda target: _write_rows(target, rows)),
        ("--plots", request.plots, lambda target: _write_plots(target, rows))]
    if estimates is not None:
        outputs.append(("--estimates-out", request.estimates_out,
                        lambda target: write_estimates(target, estimates)))
    for flag, target, write in outputs:
        if target is None:
            continue
        try:
            write(target)
        except OSError as exc:  # the analysis stands; say what could not be written
            analysis.errors.append({"source": flag, "error": f"cannot write {str(target)!r}: "
                                    f"{exc.strerror or exc}"})


def _show(console: Console, request: AnalyzeRequest, analysis: Analysis) -> None:
    """The shots, aggregates, skipped channels, errors (and estimates) as JSON or tables."""
    rows = analysis.rows
    aggs = aggregates(analysis.groups)
    if request.as_json:
        shots = [{k: r.get(k) for k in ROW_KEYS if k != "error" or "error" in r} for r in rows]
        json.dump({"shots": shots, "aggregates": aggs, "skipped_channels": analysis.skipped,
                   "errors": analysis.errors,
                   **({"estimates": analysis.estimates} if request.invert else {})},
                  sys.stdout, indent=1, default=str)
        sys.stdout.write("\n")
        return
    _print(console, rows, aggs, analysis.skipped, analysis.errors)
    if analysis.estimates is not None:
        from solitonde.instrument.cli.estimate_text import describe_row

        for est in analysis.estimates:
            console.print(describe_row(est), highlight=False)


def _manifest_jobs(manifest: Path, given: list[Path] | None,
                   fmt: str | None) -> list[tuple[Path, Row | None]]:
    """The files a manifest names, each with its row; with files given on the command line
    too, every one of them must have a row (the manifest's other rows are then not read)."""
    from solitonde.instrument.cli import manifest as campaign

    if not manifest.is_file():
        _usage(f"--manifest: no such file: {manifest}")
    try:
        rows = campaign.load(manifest)
        matched = campaign.match(rows, manifest.parent,
                                 None if fmt is not None else signal_io.EXTENSIONS)
    except ManifestError as exc:
        _usage(str(exc))
    if given is None:
        return list(matched)
    by_file = {p.resolve(): (p, r) for p, r in matched}
    unmatched = [str(p) for p in given if p.resolve() not in by_file]
    if unmatched:
        _usage(f"--manifest: no row of {manifest.name} matches {unmatched[0]}"
               + (f" (and {len(unmatched) - 1} more)" if len(unmatched) > 1 else ""))
    return [(p, by_file[p.resolve()][1]) for p in given]


def _print(console: Console, rows: list[ShotRow], aggs: list[PositionAggregate],
           skipped: list[SkippedChannel], errors: list[FailedSource]) -> None:
    shot_rows = []
    for r in rows:
        if "error" in r:
            continue
        arr = _fmt(r["arr"]) if r["arr"] is not None else f"< {_fmt(r['arr_upper_bound'], 1, 3)}"
        shot_rows.append([Path(r["source"]).name, str(r["shot"]), _fmt(r["tof_s"], 1e6, 5), arr,
                          _fmt(r["incident_time_s"], 1e6, 5), _fmt(r["reflected_time_s"], 1e6, 5),
                          _fmt(r["incident_peak_N"]), _fmt(r["reflected_peak_N"]),
                          _fmt(r["snr_db"], 1, 3), ",".join(r["flags"])])
    shot_columns = [Column("source", text=True), Column("shot"), Column("TOF (us)"),
                    Column("ARR"), Column("t_inc (us)", drop_order=3),
                    Column("t_ref (us)", drop_order=3), Column("F_inc (N)", drop_order=2),
                    Column("F_ref (N)", drop_order=2), Column("SNR (dB)", drop_order=1),
                    Column("flags", text=True)]
    agg_rows = []
    for a in aggs:
        tof, ratio = a["tof_s"], a["arr"]
        source = a.get("source")
        position = a["position"] if source is None else f"(file {Path(source).name})"
        diameter = "-" if a["sphere_diameter"] is None else f"{a['sphere_diameter'] * 1e3:.4g}"
        agg_rows.append([str(a["plate_id"] or "-"), str(position), diameter, str(a["n_shots"]),
                         _fmt(tof["mean"], 1e6, 5), _fmt(tof["std"], 1e6, 3), _fmt(ratio["mean"]),
                         _fmt(ratio["std"], 1, 3), str(len(a["rejected"]))])
    agg_columns = [Column("plate", text=True), Column("position", text=True), Column("D (mm)"),
                   Column("shots"), Column("TOF mean (us)"), Column("TOF std (us)", drop_order=1),
                   Column("ARR mean"), Column("ARR std", drop_order=1),
                   Column("rejected", drop_order=2)]
    for title, columns, table_rows in (("Shots", shot_columns, shot_rows),
                                       ("Per position", agg_columns, agg_rows)):
        table, note = fitted_table(console, title, columns, table_rows, hint="--json or --out")
        console.print(table)
        if note:
            console.print(note, style="dim", highlight=False)
    for line in _outlier_lines(aggs):
        console.print(line, highlight=False, soft_wrap=True)
    for sk in skipped:
        console.print(f"skipped: {Path(sk['source']).name} channel {sk['channel']}: "
                      f"{sk['reason']}", highlight=False)
    for e in errors:
        where = e["source"] + (f" shot {e['shot']}" if e.get("shot") is not None else "")
        console.print(f"[red]failed: {where}: {e['error']}[/red]")


OUTLIER_FEATURES = {"tof_s": ("TOF", 1e6, " us"), "arr": ("ARR", 1.0, "")}
"""How an outlier's feature reads in :func:`_outlier_lines`: name, scale and unit."""


def _outlier_lines(aggs: list[PositionAggregate]) -> list[str]:
    """One line per shot left out of its position's mean as an outlier: which shot, its value and
    why. (A shot rejected for a flag shows the flag in the shots' table.)"""
    lines = []
    for a in aggs:
        for rej in a["rejected"]:
            if rej["feature"] not in OUTLIER_FEATURES:
                continue
            name, scale, unit = OUTLIER_FEATURES[rej["feature"]]
            value = "not a number" if rej["value"] is None else f"{rej['value'] * scale:.5g}{unit}"
            where = ", ".join(str(x) for x in (a["plate_id"], a["position"]) if x is not None)
            lines.append(f"outlier left out: {Path(str(rej.get('source'))).name} shot "
                         f"{rej.get('shot')}{f' ({where})' if where else ''}: {name} {value}, "
                         f"{rej['reason']}")
    return lines


def register(app: typer.Typer) -> None:
    """Add `analyze` to the CLI."""
    app.command("analyze")(analyze)
