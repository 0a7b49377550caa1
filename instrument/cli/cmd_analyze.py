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
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer
from rich.console import Console

from solitonde.instrument.cli.common import sphere_sizes
from solitonde.instrument.cli.console_tables import Column, fitted_table
from solitonde.instrument.cli.manifest import ManifestError, Row
from solitonde.instrument.inference import measured_shots
from solitonde.instrument.inference.measured_shots import (
    LOCATION_KEYS,
    PEAK_READING,
    PositionShots,
    ShotInputError,
)
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
MISSING_SIZE_FLAG = ("--sphere-diameter: --invert needs the sphere size, and these shots state "
                     "none (give --sphere-diameter M, or a manifest's sphere_diameter_m)")


def flag_message(text: str) -> str:
    """A reader's message with its option names (``sample_rate=``, a leading ``units:``) as the
    command line's flags (``--sample-rate``)."""
    text = text.replace("sample_rate= in Hz (or dt= in s)", "--sample-rate in Hz")
    for key, flag in FLAGS.items():
        text = re.sub(rf"(?<![\w-]){key}=", flag + " ", text)
        if text.startswith(f"{key}: "):
            text = f"{flag}: {text[len(key) + 2:]}"
    return text


@dataclass(frozen=True)
class Choice:
    """What the command line says about every file: channels, group and location metadata."""

    channels: tuple[str, ...] = ()
    group: str | None = None
    metadata: dict[str, Any] = field(default_factory=dict)


def analyse_file(path: Path, fmt: str | None, options: dict[str, Any],
                 calibration: float | None = None, choice: Choice | None = None,
                 row: Row | None = None) -> tuple[list[dict[str, Any]], bool]:
    """One row per shot of ``path`` (instrument.inference.measured_shots.measure_file) and
    whether ``calibration`` (a fallback for files in volts without their own) was used.

    What the command line (``choice``) and the manifest ``row`` state joins each shot's own
    metadata; a manifest row's calibration serves its file before ``--calibration``."""
    choice = choice or Choice()
    own = row.calibration if row is not None and row.calibration is not None else None
    sources = [(FLAGS[k], {k: v}) for k, v in choice.metadata.items()]
    if row is not None and row.metadata:
        sources.append((row.where, row.metadata))
    rows, used = measured_shots.measure_file(
        path, fmt, options, fallback_calibration=own if own is not None else calibration,
        channels=choice.channels, group=choice.group, stated=sources)
    return rows, used and own is None  # whether --calibration served


def aggregates(groups: list[PositionShots]) -> list[dict[str, Any]]:
    """The summaries as JSON: location, then the aggregate; each rejected shot names its file
    and shot number."""
    out = []
    for g in groups:
        agg = g.summary.aggregate.to_dict()
        for rej in agg["rejected"]:
            m = g.rows[rej["index"]]
            rej.update(source=m["source"], shot=m["shot"])
        out.append({**g.location, **agg})
    return out


def estimates_for_locations(groups: Sequence[PositionShots], table_files: Sequence[Path] | None,
                            calibration_file: Path | None,
                            plate_material: Any = None,
                            setup: Setup | None = None) -> list[dict[str, Any]]:
    """Estimates per (plate_id, position) from `analyze`'s summaries, sphere sizes combined,
    each against the table of its family (instrument.table_set's rule) or the one its manifest
    row or ``setup`` names, through the one estimate path (instrument.inference.pipeline).

    With ``setup`` its table is found by id among ``table_files``, the bundled tables and
    ``$SOLITONDE_TABLE``, and its chain calibration is applied, as the service does.

    Raises TableError/CalibrationError when a table or the calibration cannot be read.
    """
    from solitonde.instrument.cli.common import choice_error, setup_tables, table_set
    from solitonde.instrument.inference.calibration import Calibration
    from solitonde.instrument.inference.inversion import InversionError
    from solitonde.instrument.inference.pipeline import MISSING_SIZE, estimate
    from solitonde.instrument.inference.table_set import TableChoiceError
    from solitonde.instrument.tables.table import TableError

    tables = table_set(table_files) if setup is None else setup_tables(setup, table_files)
    cal = Calibration.load(calibration_file) if calibration_file else None
    if setup is not None and setup.chain_calibration is not None:
        cal = setup.calibration()
    by_location = measured_shots.by_position(
        groups, lambda g: tuple(g.location.get(k) for k in measured_shots.POSITION_KEYS))
    out = []
    for (plate, position, x_m, y_m), sizes in by_location.items():
        row: dict[str, Any] = {"plate_id": plate, "position": position, "x_m": x_m, "y_m": y_m}
        usable = [g.summary for g in sizes if g.summary.skip_reason() is None]
        # the command line names its flag, not the metadata key the inversion reads
        row["skipped"] = [{"sphere_diameter": g.location["sphere_diameter"],
                           "reason": MISSING_SIZE_FLAG if g.summary.skip_reason() == MISSING_SIZE
                           else g.summary.skip_reason()} for g in sizes
                          if g.summary.skip_reason()]
        row["diameters_m"] = [s.diameter_m for s in usable]
        row["n_shots"] = sum(s.inputs().n_shots for s in usable)
        row["estimate"] = None
        if not usable:
            out.append(row)
            continue
        chosen = _chosen_for(sizes, setup, plate_material)
        if "error" in chosen:
            row["error"] = chosen["error"]
            out.append(row)
            continue
        try:
            found = estimate(tables, usable, cal, table=chosen.get("table"),
                             plate_material=chosen.get("plate_material"),
                             skipped=row["skipped"])
            row["estimate"] = found.to_dict()
        except TableChoiceError as exc:
            row["error"] = choice_error(exc)
        except (InversionError, TableError) as exc:
            row["error"] = str(exc)
        out.append(row)
    return out


def _chosen_for(sizes: Sequence[PositionShots], setup: Setup | None,
                plate_material: Any) -> dict[str, Any]:
    """The table and plate material a position is estimated with: its manifest row's, else the
    set-up's, else the command line's material; ``error`` where a row names another set-up
    than ``--setup``, or a table that contradicts it."""
    from solitonde.instrument.cli.common import parse_material

    loc = sizes[0].location
    named = loc.get("setup")
    if named is not None and (setup is None or named != setup.id):
        return {"error": f"--manifest: setup {named!r}: give that set-up's file with --setup"
                + ("" if setup is None else f" (--setup is {setup.id!r})")}
    if setup is not None:
        for g in sizes:
            d = g.location.get("sphere_diameter")
            if d is not None and setup.size_of(float(d)) is None:
                return {"error": f"sphere_diameter {float(d):g} m contradicts --setup "
                        f"{setup.id!r}, whose sphere_diameters_m are "
                        f"{', '.join(f'{s:g}' for s in setup.sphere_diameters_m)} m"}
    table = loc.get("table")
    if setup is not None and table is not None and table != setup.table:
        return {"error": f"--manifest: table {table!r} contradicts --setup {setup.id!r}, whose "
                f"table is {setup.table!r}"}
    material = loc.get("plate_material")
    try:
        material = plate_material if material is None else parse_material(str(material))
    except ValueError as exc:
        return {"error": f"--manifest: plate_material: {exc}"}
    if material is None and setup is not None:
        material = setup.plate_material
    return {"table": table if table is not None else None if setup is None else setup.table,
            "plate_material": material}


def _write_rows(out: Path, rows: list[dict[str, Any]]) -> None:
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


def _write_plots(folder: Path, rows: list[dict[str, Any]]) -> None:
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
    console = Console(stderr=as_json)

    def usage(message: str) -> None:
        typer.echo(f"error: {message}", err=True)  # unwrapped, one line for scripts and logs
        raise typer.Exit(code=2)

    setup = None
    if setup_file is not None:
        from solitonde.instrument.inference.setups import Setup, SetupError

        try:
            setup = Setup.load(setup_file)
        except SetupError as exc:
            usage(f"--setup: {exc}")
            return
        if calibration_file is not None and setup.chain_calibration is not None:
            usage(f"--calibration-file: set-up {setup.id!r} (revision {setup.revision}) has "
                  "its own chain calibration; give one of the two")
        if sphere_diameter is not None and setup.size_of(sphere_diameter) is None:
            usage(f"--sphere-diameter: {sphere_diameter:g} m contradicts --setup {setup.id!r}, "
                  f"whose sphere_diameters_m are "
                  f"{', '.join(f'{d:g}' for d in setup.sphere_diameters_m)} m")
        if sphere_diameter is None and len(setup.sphere_diameters_m) == 1:
            sphere_diameter = setup.sphere_diameters_m[0]

    for flag, path in (("--out", out), ("--estimates-out", estimates_out)):
        if path is not None and path.suffix.lower() not in OUT_SUFFIXES:
            usage(f"{flag}: {path.name} must end in {' or '.join(OUT_SUFFIXES)}")
    for flag, path, want in (("--out", out, "file"), ("--estimates-out", estimates_out, "file"),
                             ("--plots", plots, "folder")):
        if path is not None and (path.is_dir() if want == "file"
                                 else path.exists() and not path.is_dir()):
            usage(f"{flag}: {str(path)!r} is a {'folder' if want == 'file' else 'file'}; "
                  f"give a {want}")
    if fmt is not None:
        try:
            signal_io.detect_format("x", fmt)
        except WaveformError as exc:
            usage(f"--format: {exc.message} (allowed: {exc.allowed})")
    if units is not None and units not in UNITS:
        usage(f"--units: {units!r} is not N or V")
    material: Any = None
    if plate_material is not None:
        from solitonde.instrument.cli.common import parse_material

        try:
            material = parse_material(plate_material)
        except ValueError as exc:
            usage(f"--plate-material: {exc}")
    for flag, value in (("--x", x), ("--y", y), ("--sample-rate", sample_rate),
                        ("--calibration", calibration)):
        if value is not None and not math.isfinite(value):
            usage(f"{flag}: {value} is not a finite number")
    for flag, value in (("--sample-rate", sample_rate), ("--calibration", calibration)):
        if value is not None and value <= 0:
            usage(f"{flag}: {value:g} must be > 0")
    given = {k: v for k, v in (("plate_id", plate_id), ("position", position), ("x_m", x),
                               ("y_m", y), ("sphere_diameter", sphere_diameter),
                               ("baseline", baseline))
             if v is not None}
    try:  # the limits the service holds metadata to, for the flags' values too
        measured_shots.check_metadata([given], measured_shots.shot_fields(""))
    except ShotInputError as exc:
        usage(flag_message(str(exc)))
    choice = Choice(tuple(channel), group, given)
    files = list(files or [])
    if not files and manifest is None:
        usage("give waveform files or folders, or --manifest")
    paths, missing = measured_shots.collect(files, fmt)
    if missing:
        usage("; ".join(m["error"] for m in missing))
    jobs: list[tuple[Path, Row | None]] = [(p, None) for p in paths]
    if manifest is not None:
        jobs = _manifest_jobs(manifest, paths if files else None, fmt, usage)
    invert = invert or estimates_out is not None
    options = {"sample_rate": sample_rate, "units": units}
    if jobs:  # a fresh install: a few shots interpreted while the extractor compiles
        from solitonde.signal import kernel_choice

        kernel_choice.start()
    calibration_used = False
    rows: list[dict[str, Any]] = []
    errors: list[dict[str, Any]] = []
    from tqdm import tqdm

    for path, row in tqdm(jobs, desc="analyze", unit="file", file=sys.stderr,
                          disable=len(jobs) < 5 or not sys.stderr.isatty()):
        try:
            file_rows, used = analyse_file(path, fmt, options, calibration, choice, row)
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
    if calibration is not None and jobs and not calibration_used and not errors:
        errors.append({"source": "--calibration", "error": "no file holds volts without a "
                       "calibration of its own; --calibration was not used"})
    skipped = [{"source": r["source"], "channel": r["channel"], "reason": r["skipped"]}
               for r in rows if "skipped" in r]
    rows = [r for r in rows if "skipped" not in r]
    for r in rows:
        if "error" in r:
            errors.append({"source": r["source"], "shot": r["shot"],
                           "error": flag_message(r["error"])})
    groups = measured_shots.summarise_positions(rows)
    aggs = aggregates(groups)
    estimates = None
    if invert:
        from solitonde.instrument.cli.common import table_path
        from solitonde.instrument.inference.calibration import CalibrationError
        from solitonde.instrument.inference.pipeline import (
            ALL_EARLY,
            ALL_REJECTED,
            ALL_SATURATED,
            ALL_TRUNCATED,
            ALL_UNSTEADY,
        )
        from solitonde.instrument.tables.table import TableError

        try:
            estimates = estimates_for_locations(groups, table, calibration_file, material,
                                                setup)
        except CalibrationError as exc:
            errors.append({"source": str(calibration_file), "error": str(exc)})
        except (TableError, ValueError, OSError) as exc:  # table unreadable
            errors.append({"source": ", ".join(map(str, table)) or str(table_path(None)),
                           "error": str(exc)})
        from solitonde.instrument.cli.estimate_text import where_estimated

        for est in estimates or []:
            where = where_estimated(est)
            if est.get("error"):  # an inversion that failed (e.g. a size the table lacks)
                errors.append({"source": where, "error": est["error"]})
            elif est.get("estimate") is None and any(
                    s.get("reason") == MISSING_SIZE_FLAG for s in est.get("skipped", [])):
                errors.append({"source": where, "error": MISSING_SIZE_FLAG})
            elif est.get("estimate") is None and (unreadable := [
                    s["reason"] for s in est.get("skipped", [])
                    if any(every in s["reason"] for every in (
                        ALL_TRUNCATED, ALL_SATURATED, ALL_EARLY, ALL_UNSTEADY, ALL_REJECTED))]):
                # records too short, or clipped: no answer can be read from them
                errors.append({"source": where, "error": unreadable[0]})
            elif (est.get("estimate") or {}).get("thickness_m", {}).get("status") in (
                    "inconsistent", "out_of_range"):
                # an answer the table's family does not explain is no answer to act on
                errors.append({"source": where, "error": est["estimate"]["warnings"][0]
                               if est["estimate"].get("warnings") else
                               est["estimate"].get("reason")})
    outputs = [("--out", out, lambda target: _write_rows(target, rows)),
               ("--plots", plots, lambda target: _write_plots(target, rows))]
    if estimates is not None:
        outputs.append(("--estimates-out", estimates_out,
                        lambda target: _write_estimates(target, estimates)))
    for flag, target, write in outputs:
        if target is None:
            continue
        try:
            write(target)
        except OSError as exc:  # the analysis stands; say what could not be written
            errors.append({"source": flag, "error": f"cannot write {str(target)!r}: "
                           f"{exc.strerror or exc}"})
    shots = [{k: r.get(k) for k in ROW_KEYS if k != "error" or "error" in r} for r in rows]
    if as_json:
        json.dump({"shots": shots, "aggregates": aggs, "skipped_channels": skipped,
                   "errors": errors, **({"estimates": estimates} if invert else {})},
                  sys.stdout, indent=1, default=str)
        sys.stdout.write("\n")
    else:
        _print(console, rows, aggs, skipped, errors)
        if estimates is not None:
            from solitonde.instrument.cli.estimate_text import describe_row

            for est in estimates:
                console.print(describe_row(est), highlight=False)
    raise typer.Exit(code=1 if errors or not jobs else 0)


def _manifest_jobs(manifest: Path, given: list[Path] | None, fmt: str | None,
                   usage: Any) -> list[tuple[Path, Row | None]]:
    """The files a manifest names, each with its row; with files given on the command line
    too, every one of them must have a row (the manifest's other rows are then not read)."""
    from solitonde.instrument.cli import manifest as campaign

    if not manifest.is_file():
        usage(f"--manifest: no such file: {manifest}")
    try:
        rows = campaign.load(manifest)
        matched = campaign.match(rows, manifest.parent,
                                 None if fmt is not None else signal_io.EXTENSIONS)
    except ManifestError as exc:
        usage(str(exc))
        return []
    if given is None:
        return list(matched)
    by_file = {p.resolve(): (p, r) for p, r in matched}
    unmatched = [str(p) for p in given if p.resolve() not in by_file]
    if unmatched:
        usage(f"--manifest: no row of {manifest.name} matches {unmatched[0]}"
              + (f" (and {len(unmatched) - 1} more)" if len(unmatched) > 1 else ""))
    return [(p, by_file[p.resolve()][1]) for p in given]


def _write_estimates(out: Path, estimates: list[dict[str, Any]]) -> None:
    """One row per plate and position (instrument.estimate_rows' columns)."""
    from solitonde.instrument.inference.estimate_rows import estimate_row, to_bytes
    from solitonde.instrument.studies.figures import write_bytes

    table = []
    for est in estimates:
        result = est.get("estimate")
        reason = est.get("error") or ("; ".join(s["reason"] for s in est.get("skipped", []))
                                      if result is None else None)
        table.append(estimate_row(est, est.get("diameters_m", []), est.get("n_shots", 0),
                                  result, reason))
    write_bytes(out, to_bytes(table, "parquet" if out.suffix.lower() == ".parquet" else "csv"))


def _print(console: Console, rows: list[dict[str, Any]], aggs: list[dict[str, Any]],
           skipped: list[dict[str, Any]], errors: list[dict[str, Any]]) -> None:
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
        tof, arr = a["tof_s"], a["arr"]
        position = a["position"] if a.get("source") is None else f"(file {Path(a['source']).name})"
        diameter = "-" if a["sphere_diameter"] is None else f"{a['sphere_diameter'] * 1e3:.4g}"
        agg_rows.append([str(a["plate_id"] or "-"), str(position), diameter, str(a["n_shots"]),
                         _fmt(tof["mean"], 1e6, 5), _fmt(tof["std"], 1e6, 3), _fmt(arr["mean"]),
                         _fmt(arr["std"], 1, 3), str(len(a["rejected"]))])
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
    for sk in skipped:
        console.print(f"skipped: {Path(sk['source']).name} channel {sk['channel']}: "
                      f"{sk['reason']}", highlight=False)
    for e in errors:
        where = e["source"] + (f" shot {e['shot']}" if e.get("shot") is not None else "")
        console.print(f"[red]failed: {where}: {e['error']}[/red]")


def register(app: typer.Typer) -> None:
    """Add `analyze` to the CLI."""
    app.command("analyze")(analyze)
