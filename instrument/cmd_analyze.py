"""`solitonde analyze`: TOF, ARR, SNR and flags for every shot in waveform files or folders.

One row per shot, an aggregate per position (plate, position, sphere diameter); a file that names
neither plate nor position is a position of its own. A file that fails, for whatever reason, is
reported with its error and the others go on; the exit code says whether all succeeded (0 all,
1 some failed or nothing to analyse, 2 usage).

The global reader options apply where they make sense: ``--sample-rate`` gives the rate of data
without a time axis and must agree with any file's own; ``--units`` says what data that do not
state their units are in, and must agree with any file that does; ``--calibration`` converts the
files in volts that carry no calibration (a run in which no file used it reports that).
"""

from __future__ import annotations

import io
import json
import math
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import typer
from rich.console import Console
from rich.table import Table

from solitonde.signal import io as signal_io
from solitonde.signal.errors import WaveformError
from solitonde.signal.features import FEATURES, aggregate, extract_many
from solitonde.signal.waveform import UNITS

OUT_SUFFIXES = (".csv", ".parquet")
ROW_KEYS = ("source", "shot", *FEATURES, "flags", "arr_upper_bound", "plate_id", "position",
            "sphere_diameter", "error")


def collect(paths: Iterable[Path], fmt: str | None = None
            ) -> tuple[list[Path], list[dict[str, Any]]]:
    """Files to analyse, each once, and the paths that gave none (missing, or a folder with no
    files).

    Folders are searched recursively: for the known extensions, or, with ``fmt`` given, every
    regular file whose name does not start with a dot.
    """
    files: list[Path] = []
    missing: list[dict[str, Any]] = []
    for p in paths:
        if p.is_dir():
            found = sorted(f for f in p.rglob("*") if f.is_file() and (
                not f.name.startswith(".") if fmt is not None
                else f.suffix.lower() in signal_io.EXTENSIONS))
            if not found:
                what = ("no files" if fmt is not None else "no files with the extensions " +
                        ", ".join(sorted(signal_io.EXTENSIONS)) + " (use --format for others)")
                missing.append({"source": str(p), "error": f"{p}: {what}"})
            files.extend(found)
        elif p.exists():
            files.append(p)
        else:
            missing.append({"source": str(p), "error": f"no such file or folder: {p}"})
    seen: set[Path] = set()
    unique = []
    for f in files:  # a file named twice (itself and in its folder) is one set of shots
        key = f.resolve()
        if key not in seen:
            seen.add(key)
            unique.append(f)
    return unique, missing


def _clean(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def read_file(path: Path, fmt: str | None, options: dict[str, Any],
              calibration: float | None = None) -> tuple[list[Any], bool]:
    """The shots of ``path`` and whether ``calibration`` was used.

    Only the options the file's reader accepts are passed; ``calibration`` only when the file
    holds volts without a calibration of its own.
    """
    accepted = signal_io.READER_OPTIONS[signal_io.detect_format(path, fmt)]
    opts = {k: v for k, v in options.items() if k in accepted and v is not None}
    try:
        return signal_io.read(path, format=fmt, **opts), False
    except signal_io.OptionNeeded as exc:
        if exc.option != "calibration" or calibration is None or "calibration" not in accepted:
            raise
    return signal_io.read(path, format=fmt, **opts, calibration=calibration), True


def analyse_file(path: Path, fmt: str | None, options: dict[str, Any],
                 calibration: float | None = None) -> tuple[list[dict[str, Any]], bool]:
    """One row per shot of ``path`` and whether ``calibration`` was used; raises on a file that
    cannot be read."""
    waves, used = read_file(path, fmt, options, calibration)
    rows = []
    for w in waves:
        meta = w.metadata
        row: dict[str, Any] = {"source": str(path), "shot": meta.get("shot"),
                               "plate_id": meta.get("plate_id"),
                               "position": meta.get("position"),
                               "sphere_diameter": meta.get("sphere_diameter")}
        try:
            (feat,) = extract_many([w])
        except WaveformError as exc:
            row["error"] = str(exc)
            rows.append(row)
            continue
        d = feat.to_dict()
        row.update({k: _clean(d[k]) for k in FEATURES})
        row["flags"] = d["flags"]
        row["arr_upper_bound"] = _clean(d["arr_upper_bound"])
        row["features"] = feat
        row["waveform"] = w
        rows.append(row)
    return rows, used


def aggregates(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Aggregate per (plate_id, position, sphere_diameter) over the shots that were measured.

    Shots whose file names neither plate nor position are aggregated per file (``source`` is
    then set), never pooled with other files' shots: nothing says they are one position.
    """
    groups: dict[tuple[Any, Any, Any, Any], list[Any]] = {}
    for r in rows:
        if "features" in r:
            plate, position = r.get("plate_id"), r.get("position")
            source = r["source"] if plate is None and position is None else None
            key = (plate, position, r.get("sphere_diameter"), source)
            groups.setdefault(key, []).append(r)
    out = []
    for (plate, position, diameter, source), members in groups.items():
        agg = aggregate([m["features"] for m in members]).to_dict()
        for rej in agg["rejected"]:
            m = members[rej["index"]]
            rej.update(source=m["source"], shot=m["shot"])
        out.append({"plate_id": plate, "position": position, "sphere_diameter": diameter,
                    "source": source, **agg})
    return out


def _write_rows(out: Path, rows: list[dict[str, Any]]) -> None:
    import pandas as pd

    table = pd.DataFrame([{k: r.get(k) for k in ROW_KEYS} for r in rows], columns=list(ROW_KEYS))
    table["flags"] = table["flags"].map(lambda f: ";".join(f) if isinstance(f, list) else "")
    for col in ("plate_id", "position", "sphere_diameter", "error", "source"):
        table[col] = table[col].map(lambda v: None if v is None else str(v))
    from .figures import write_bytes

    if out.suffix.lower() == ".parquet":
        buf = io.BytesIO()
        table.to_parquet(buf, index=False)
        write_bytes(out, buf.getvalue())
    else:
        write_bytes(out, table.to_csv(index=False).encode())


def _write_plots(folder: Path, rows: list[dict[str, Any]]) -> None:
    """One PNG per measured shot, named ``<stem>_shot<k>.png`` after its file and shot number.

    Files that share a stem (``x.csv`` and ``x.npy``, or ``a/x.csv`` and ``b/x.csv``) keep the
    extension in the name and then a counter, so no shot's plot overwrites another's.
    """
    from .figures import write_bytes
    from .plotting import trace_png

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
    files: list[Path] = typer.Argument(..., help="Waveform files or folders (recursive)."),
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
    invert: bool = typer.Option(False, "--invert", help="Also estimate thickness and distance "
                                "to support per position (sphere sizes combined)."),
    table: Path | None = typer.Option(None, "--table", help="Model table for --invert."),
    calibration_file: Path | None = typer.Option(None, "--calibration-file", help="Calibration "
                                                 "JSON (solitonde calibrate) for --invert."),
    plots: Path | None = typer.Option(None, "--plots", help="Folder for one PNG per shot (trace "
                                      "with the detected pulses marked)."),
) -> None:
    """Measure TOF, ARR, SNR and quality flags of every shot; aggregate per position."""
    console = Console(stderr=as_json)
    if out is not None and out.suffix.lower() not in OUT_SUFFIXES:
        console.print(f"[red]--out: {out.name} must end in {' or '.join(OUT_SUFFIXES)}[/red]")
        raise typer.Exit(code=2)
    for flag, path, want in (("--out", out, "file"), ("--plots", plots, "folder")):
        if path is not None and (path.is_dir() if want == "file"
                                 else path.exists() and not path.is_dir()):
            console.print(f"[red]{flag}: {str(path)!r} is a "
                          f"{'folder' if want == 'file' else 'file'}; give a {want}[/red]")
            raise typer.Exit(code=2)
    if fmt is not None:
        try:
            signal_io.detect_format("x", fmt)
        except WaveformError as exc:
            console.print(f"[red]--format: {exc}[/red]")
            raise typer.Exit(code=2) from None
    if units is not None and units not in UNITS:
        console.print(f"[red]--units: {units!r} is not N or V[/red]")
        raise typer.Exit(code=2)
    options = {"sample_rate": sample_rate, "units": units}
    paths, errors = collect(files, fmt)
    calibration_used = False
    rows: list[dict[str, Any]] = []
    from tqdm import tqdm

    for path in tqdm(paths, desc="analyze", unit="file", file=sys.stderr,
                     disable=len(paths) < 5 or not sys.stderr.isatty()):
        try:
            file_rows, used = analyse_file(path, fmt, options, calibration)
        except Exception as exc:  # any broken file is its own error; Ctrl-C still stops the run
            errors.append({"source": str(path), "error": f"{type(exc).__name__}: {exc}"})
            continue
        rows.extend(file_rows)
        calibration_used = calibration_used or used
    if calibration is not None and paths and not calibration_used:
        errors.append({"source": "--calibration", "error": "calibration: no file holds volts "
                       "without a calibration of its own; --calibration was not used"})
    for r in rows:
        if "error" in r:
            errors.append({"source": r["source"], "shot": r["shot"], "error": r["error"]})
    aggs = aggregates(rows)
    estimates = None
    if invert:
        from .calibration import CalibrationError
        from .cmd_invert import estimates_for_aggregates, table_path

        try:
            estimates = estimates_for_aggregates(aggs, table, calibration_file)
        except CalibrationError as exc:
            errors.append({"source": str(calibration_file), "error": str(exc)})
        except ValueError as exc:  # table unreadable
            errors.append({"source": str(table_path(table)), "error": str(exc)})
        for row in estimates or []:
            if row.get("error"):  # an inversion that failed (e.g. a size the table lacks)
                errors.append({"source": f"estimate for plate {row['plate_id']}, position "
                               f"{row['position']}", "error": row["error"]})
    for flag, target, write in (("--out", out, _write_rows), ("--plots", plots, _write_plots)):
        if target is None:
            continue
        try:
            write(target, rows)
        except OSError as exc:  # the analysis stands; say what could not be written
            errors.append({"source": flag, "error": f"cannot write {str(target)!r}: "
                           f"{exc.strerror or exc}"})
    shots = [{k: r.get(k) for k in ROW_KEYS if k != "error" or "error" in r} for r in rows]
    if as_json:
        json.dump({"shots": shots, "aggregates": aggs, "errors": errors,
                   **({"estimates": estimates} if invert else {})},
                  sys.stdout, indent=1, default=str)
        sys.stdout.write("\n")
    else:
        _print(console, rows, aggs, errors)
        if estimates is not None:
            from .cmd_invert import describe_row

            for row in estimates:
                console.print(describe_row(row))
    raise typer.Exit(code=1 if errors or not paths else 0)


def _print(console: Console, rows: list[dict[str, Any]], aggs: list[dict[str, Any]],
           errors: list[dict[str, Any]]) -> None:
    table = Table(title="Shots")
    for col in ("source", "shot", "TOF (us)", "ARR", "t_inc (us)", "t_ref (us)", "F_inc (N)",
                "F_ref (N)", "SNR (dB)", "flags"):
        table.add_column(col)
    for r in rows:
        if "error" in r:
            continue
        arr = _fmt(r["arr"]) if r["arr"] is not None else f"< {_fmt(r['arr_upper_bound'], 1, 3)}"
        table.add_row(Path(r["source"]).name, str(r["shot"]), _fmt(r["tof_s"], 1e6, 5), arr,
                      _fmt(r["incident_time_s"], 1e6, 5), _fmt(r["reflected_time_s"], 1e6, 5),
                      _fmt(r["incident_peak_N"]), _fmt(r["reflected_peak_N"]),
                      _fmt(r["snr_db"], 1, 3), ",".join(r["flags"]))
    console.print(table)
    agg_table = Table(title="Per position")
    for col in ("plate", "position", "D (m)", "shots", "TOF mean (us)", "TOF std (us)",
                "ARR mean", "ARR std", "rejected"):
        agg_table.add_column(col)
    for a in aggs:
        tof, arr = a["tof_s"], a["arr"]
        position = a["position"] if a.get("source") is None else f"(file {Path(a['source']).name})"
        agg_table.add_row(str(a["plate_id"]), str(position), str(a["sphere_diameter"]),
                          str(a["n_shots"]), _fmt(tof["mean"], 1e6, 5), _fmt(tof["std"], 1e6, 3),
                          _fmt(arr["mean"]), _fmt(arr["std"], 1, 3), str(len(a["rejected"])))
    console.print(agg_table)
    for e in errors:
        where = e["source"] + (f" shot {e['shot']}" if e.get("shot") is not None else "")
        console.print(f"[red]failed: {where}: {e['error']}[/red]")


def register(app: typer.Typer) -> None:
    """Add `analyze` to the CLI."""
    app.command("analyze")(analyze)
