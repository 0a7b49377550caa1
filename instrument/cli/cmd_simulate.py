"""`solitonde simulate`: run one scene through the chain model and measure its sensor trace.

The model (``solitonde.model``) makes the trace; the features (TOF, ARR, pulse peaks) are
measured by ``solitonde.signal`` exactly as a recorded waveform would be, so simulated and
measured shots share one extractor and its biases.

``--out`` writes the trace as it is measured (a static pre-trigger before the impact at t = 0,
then the shot) with ``solitonde.signal.io`` as CSV: ``# key: <JSON>`` comment lines first
(``scene``, ``plate_model``, ``plate_model_reason``, ``source``, ``sphere_diameter``), then the
header ``time_s,force_N`` and one row per sample; ``solitonde.signal.io.read`` reads it back
with the scene in ``metadata["scene"]``.

``--shots N --snr-db S [--drift F] [--seed K]`` makes N noisy repeated shots of the one simulated
trace with the acquisition model ``validate`` uses (signal.synth.degrade: white noise over the
whole record, pre-trigger included, at S dB below the incident peak above the baseline; with
``--drift`` a baseline drift of F times that peak), to plan an experiment or test a set-up;
``--out`` then holds one column per shot, and the report adds every shot's TOF and ARR with
their mean and spread. The noise is seeded: the same K gives the same shots.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any, NoReturn, NotRequired, TypedDict

import typer
from rich.console import Console
from rich.table import Table

from solitonde.instrument.tables import greens_cache
from solitonde.instrument.tables.measured import as_measured, check_resolved, detect_options
from solitonde.model.errors import SceneError, SimulationError
from solitonde.model.scene import load_scene
from solitonde.model.simulate import SimulationResult, simulate
from solitonde.signal import io as signal_io
from solitonde.signal.errors import WaveformError
from solitonde.signal.features import Features, extract
from solitonde.signal.json_ready import json_ready
from solitonde.signal.waveform import Waveform


class Acquisition(TypedDict):
    """How the noisy shots were made (``--shots``, ``--snr-db``, ``--drift``, ``--seed``) and
    the incident peak their noise and drift are relative to."""

    shots: int
    snr_db: float
    drift: float
    seed: int
    reference_N: float


class ShotReading(TypedDict):
    """A noisy shot's TOF, ARR, SNR and flags, or why its pulses could not be found."""

    shot: int
    tof_s: float
    arr: float
    snr_db: float
    flags: list[str]
    error: NotRequired[str]


class SimulationSummary(TypedDict):
    """The JSON of ``solitonde simulate --json``, its keys in this order."""

    plate_model: str
    tof_s: float
    arr: float
    incident_peak_N: float
    reflected_peak_N: float
    incident_time_s: float
    reflected_time_s: float
    energy_drift: float
    steps: int
    dt_s: float
    wall_s: float
    status: str
    plate_model_reason: str
    sample_rate_hz: float
    n_samples: int
    t0_s: float
    duration_s: float
    plate_work_J: float
    dissipated_J: float
    snr_db: float
    tof_peak_s: float
    arr_peak: float
    flags: list[str]
    feature_error: str | None
    model_truth: dict[str, float]
    mesh: NotRequired[Any]  # the meshed plate models' diagnostics, as the model gives them
    dt_stability_ratio: NotRequired[float]
    chain_dt_s: NotRequired[float]
    greens_cached: NotRequired[bool]
    shots: NotRequired[list[ShotReading]]
    acquisition: NotRequired[Acquisition]


def to_waveform(result: SimulationResult) -> Waveform:
    """The simulated trace as recorded (:func:`~solitonde.instrument.tables.measured.as_measured`,
    the table builder's and the service's bridge too), with the scene as metadata."""
    return as_measured(result, {
        "scene": result.scene.to_dict(),
        "plate_model_reason": result.plate_model_reason,
        "source": "solitonde simulate",
    })


def _nan(value: float | None) -> float:
    return math.nan if value is None else float(value)


def summary(
    result: SimulationResult, recorded: Waveform, features: Features | None,
    feature_error: str | None = None,
) -> SimulationSummary:
    """The JSON of ``solitonde simulate --json`` (the first twelve keys are a public contract).

    Pulse quantities the trace does not support (no reflection found, or no pulse the signal
    extractor could detect: ``features`` None, ``feature_error`` says why) are NaN here, null in
    JSON.
    """
    d = result.diagnostics
    if features is None:
        features = Features(None, None, math.nan, None, math.nan, None, math.nan, ["no_features"])
    data: SimulationSummary = {
        "plate_model": result.plate_model,
        "tof_s": _nan(features.tof_s),
        "arr": _nan(features.arr),
        "incident_peak_N": _nan(features.incident_peak_N),
        "reflected_peak_N": _nan(features.reflected_peak_N),
        "incident_time_s": _nan(features.incident_time_s),
        "reflected_time_s": _nan(features.reflected_time_s),
        "energy_drift": d["energy_drift"],
        "steps": d["steps"],
        "dt_s": d["dt_s"],
        "wall_s": d["wall_s"],
        "status": d["status"],
        "plate_model_reason": result.plate_model_reason,
        "sample_rate_hz": 1.0 / result.dt,
        "n_samples": recorded.n,  # the record measured: pre-trigger and run
        "t0_s": recorded.t0,
        "duration_s": d["duration_s"],
        "plate_work_J": d["plate_work_J"],
        "dissipated_J": d["dissipated_J"],
        "snr_db": features.snr_db,
        "tof_peak_s": _nan(features.tof_peak_s),  # the trace's own peaks (tof_s: the template's)
        "arr_peak": _nan(features.arr_peak),
        "flags": list(features.flags),
        "feature_error": feature_error,
        "model_truth": result.truth,
    }
    # meshed plate models (sem, greens, mindlin, mindlin_greens) only
    if "mesh" in d:
        data["mesh"] = d["mesh"]
    if "dt_stability_ratio" in d:
        data["dt_stability_ratio"] = d["dt_stability_ratio"]
    if "chain_dt_s" in d:
        data["chain_dt_s"] = d["chain_dt_s"]
    if "greens_cached" in d:
        data["greens_cached"] = d["greens_cached"]
    return data


def write_plot(path: Path, result: SimulationResult, recorded: Waveform,
               data: SimulationSummary) -> None:
    """The measured sensor trace with the detected incident and reflected pulses marked (PNG)."""
    from solitonde.instrument.plotting import trace_png
    from solitonde.instrument.studies.figures import write_bytes

    s = result.scene
    title = (f"D = {s.chain.diameter * 1e3:.2f} mm, t = {s.plate.thickness * 1e3:.2f} mm, "
             f"L = {s.plate.distance_to_support * 1e3:.0f} mm, {result.plate_model}")
    write_bytes(path, trace_png(recorded.t0, recorded.dt, recorded.samples, data,
                                  title=title))


def noisy_shots(result: SimulationResult, recorded: Waveform, n: int, snr_db: float,
                drift: float = 0.0, seed: int = 0) -> list[Waveform]:
    """``n`` shots of ``recorded`` as an acquisition makes them, with validate's noise model:
    signal.synth.degrade with the incident peak above the baseline (the model's own trace) as
    the reference of the SNR and the drift, seeded by ``seed``."""
    import numpy as np

    from solitonde.signal.synth import degrade

    rng = np.random.default_rng(seed)
    reference = float(result.samples.max() - result.samples[0])
    acquisition: Acquisition = {"shots": n, "snr_db": snr_db, "drift": drift, "seed": seed,
                                "reference_N": reference}
    return [recorded.with_samples(degrade(recorded.samples, snr_db, rng, reference, drift))
            .with_metadata(acquisition=acquisition, shot=k) for k in range(n)]


def shot_features(measured: list[Features | str]) -> list[ShotReading]:
    """TOF, ARR, SNR and flags of each noisy shot as the signal package measured them, or why
    a shot's pulses could not be found."""
    out: list[ShotReading] = []
    for k, f in enumerate(measured):
        if isinstance(f, str):
            out.append({"shot": k, "tof_s": math.nan, "arr": math.nan, "snr_db": math.nan,
                        "flags": [], "error": f})
            continue
        out.append({"shot": k, "tof_s": _nan(f.tof_s), "arr": _nan(f.arr),
                    "snr_db": f.snr_db, "flags": list(f.flags)})
    return out


def _shots_line(rows: list[ShotReading], acquisition: Acquisition) -> str:
    import numpy as np

    tof = np.array([r["tof_s"] for r in rows], dtype=float)
    arr = np.array([r["arr"] for r in rows], dtype=float)
    ok = np.isfinite(tof) & np.isfinite(arr)
    head = (f"{len(rows)} noisy shots (SNR {acquisition['snr_db']:g} dB, drift "
            f"{acquisition['drift']:g}, seed {acquisition['seed']}): ")
    if not ok.any():
        return head + "no shot with both pulses found"
    ddof = 1 if ok.sum() > 1 else 0
    return (head + f"{int(ok.sum())} measured; TOF {tof[ok].mean() * 1e6:.2f} +- "
            f"{tof[ok].std(ddof=ddof) * 1e6:.2f} us, ARR {arr[ok].mean():.4f} +- "
            f"{arr[ok].std(ddof=ddof):.4f}")


def _table(data: SimulationSummary) -> Table:
    table = Table(title="Chain simulation", show_header=True)
    table.add_column("quantity")
    table.add_column("value", justify="right")
    rows = [
        ("plate model", data["plate_model"]),
        ("TOF (ms)", data["tof_s"] * 1e3 if math.isfinite(data["tof_s"]) else "n/a"),
        ("ARR", data["arr"]),
        ("incident peak (N)", data["incident_peak_N"]),
        ("reflected peak (N)", data["reflected_peak_N"]),
        ("energy drift", data["energy_drift"]),
        ("steps", data["steps"]),
        ("dt (s)", data["dt_s"]),
        ("wall (s)", data["wall_s"]),
        ("status", data["status"]),
    ]
    for name, value in rows:
        table.add_row(name, f"{value:.6g}" if isinstance(value, float) else str(value))
    table.caption = data["plate_model_reason"]
    return table


def simulate_command(
    scene_arg: Path | None = typer.Argument(
        None, metavar="SCENE", help="The scene file, as --scene (kept for older scripts)."
    ),
    scene_file: Path | None = typer.Option(
        None, "--scene", help="Scene file (YAML or JSON); the paper's setup when omitted."
    ),
    overrides: list[str] | None = typer.Option(
        None, "--set", help="Override a scene value, e.g. --set plate.thickness=3.18e-3."
    ),
    out: Path | None = typer.Option(None, "--out", help="Write the sensor trace as CSV."),
    plot: Path | None = typer.Option(None, "--plot", help="Draw the trace (PNG) with pulses."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of a table."),
    shots: int | None = typer.Option(None, "--shots", min=1, max=10_000, help="Make this many "
                                     "noisy shots of the trace (needs --snr-db); --out gets one "
                                     "column each."),
    snr_db: float | None = typer.Option(None, "--snr-db", min=-20.0, max=200.0, help="dB, "
                                        "noise of the shots: 20 log10(incident peak / noise "
                                        "sigma)."),
    drift: float = typer.Option(0.0, "--drift", min=0.0, max=10.0, help="Baseline drift of "
                                "each shot, as a fraction of the incident peak."),
    seed: int = typer.Option(0, "--seed", min=0, help="Seed of the noise (same seed, same "
                             "shots)."),
) -> None:
    """Simulate one shot (striker, chain, plate) and report TOF, ARR and diagnostics."""
    scene_file, shots = _checked_options(scene_arg, scene_file, shots, snr_db, drift, out, plot)
    # A fresh install: the extractor compiles in two background processes while the model's
    # kernels compile here, and its interpreted kernels measure the shots meanwhile (the same
    # numbers to round-off), as analyze and serve do: seconds, not half a minute, to the answer.
    from solitonde.signal import kernel_choice

    kernel_choice.start()
    result = _simulated(scene_file, overrides or [])
    try:
        waveform = to_waveform(result)
    except WaveformError as exc:  # e.g. fewer samples than a shot needs
        _exit("output.sample_rate / output.duration: the simulated trace cannot be measured: "
              f"{exc}", 2)
    options = detect_options(result.scene)
    data = _measured(result, waveform, options)
    written: Waveform | list[Waveform] = waveform
    if shots is not None and snr_db is not None:
        written = noisy_shots(result, waveform, shots, snr_db, drift, seed)
        data["shots"] = shot_features(_measured_shots(waveform, written, options))
        data["acquisition"] = written[0].metadata["acquisition"]
    failed = _write_files(out, plot, written, result, waveform, data)
    if as_json:
        typer.echo(json.dumps(json_ready(data), indent=2))
    else:
        Console().print(_table(data))
        if "shots" in data:
            Console().print(_shots_line(data["shots"], data["acquisition"]), highlight=False)
    mesh = data.get("mesh")
    coarse = mesh.get("coarse") if isinstance(mesh, dict) else None
    if coarse:
        typer.echo(f"warning: {coarse}", err=True)
    for line in failed:
        typer.echo(line, err=True)
    if failed:
        raise typer.Exit(code=1)


def _exit(message: str, code: int) -> NoReturn:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(code=code)


def _checked_options(scene_arg: Path | None, scene_file: Path | None, shots: int | None,
                     snr_db: float | None, drift: float, out: Path | None,
                     plot: Path | None) -> tuple[Path | None, int | None]:
    """The scene file and the number of noisy shots (one when only ``--snr-db`` or
    ``--drift`` asks for noise), checked before the run, which may take minutes."""
    if scene_arg is not None and scene_file is not None and scene_arg != scene_file:
        _exit(f"--scene: {scene_file} and the positional scene {scene_arg} differ; give one", 2)
    if shots is None and (snr_db is not None or drift):
        shots = 1
    if shots is not None and snr_db is None:
        _exit("--snr-db: needed with --shots (the noise of the shots, in dB)", 2)
    for flag, path in (("--out", out), ("--plot", plot)):
        if path is not None and path.is_dir():
            _exit(f"{flag}: {str(path)!r} is a folder; give a file name", 2)
    return scene_file or scene_arg, shots


def _simulated(scene_file: Path | None, overrides: list[str]) -> SimulationResult:
    """The scene loaded, checked and simulated; a scene that cannot be run exits 2, a
    simulation that fails exits 1."""
    try:
        scene = load_scene(scene_file, overrides)
        check_resolved(scene)
        return simulate(scene, greens_cache=greens_cache.disk_cache())
    except (SceneError, WaveformError) as exc:
        _exit(str(exc), 2)
    except SimulationError as exc:
        _exit(str(exc), 1)


def _measured(result: SimulationResult, waveform: Waveform,
              options: dict[str, float]) -> SimulationSummary:
    """The summary of the simulated trace, its features measured as a recording's are (a
    warning where no pulse could be found)."""
    features: Features | None = None
    feature_error = None
    try:
        features = extract(waveform, **options)
    except WaveformError as exc:
        feature_error = str(exc)
        typer.echo(f"warning: no pulse features from the simulated trace: {exc}", err=True)
    return summary(result, waveform, features, feature_error)


def _measured_shots(waveform: Waveform, written: list[Waveform],
                    options: dict[str, float]) -> list[Features | str]:
    """Each noisy shot measured as any recording, or why its pulses could not be found."""
    measured: list[Features | str] = []
    for shot in written:
        try:  # the recorded trace with this shot's noise, measured as any recording
            measured.append(extract(waveform.with_samples(shot.samples), **options))
        except WaveformError as exc:
            measured.append(str(exc))
    return measured


def _write_files(out: Path | None, plot: Path | None, written: Waveform | list[Waveform],
                 result: SimulationResult, waveform: Waveform,
                 data: SimulationSummary) -> list[str]:
    """``--out`` and ``--plot`` written; an error line for each that could not be (the result is
    still printed, the exit code says what failed)."""
    def write_csv(path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        signal_io.write(path, written, format=None if path.suffix else "csv")

    failed = []
    writers: tuple[tuple[str, Path | None, Callable[[Path], None]], ...] = (
        ("--out", out, write_csv),
        ("--plot", plot, lambda path: write_plot(path, result, waveform, data)))
    for flag, path, write in writers:
        if path is None:
            continue
        try:
            write(path)
        except OSError as exc:
            failed.append(f"error: {flag}: cannot write {str(path)!r}: {exc.strerror or exc}")
    return failed


def register(app: typer.Typer) -> None:
    """Add `simulate` to the CLI."""
    app.command("simulate")(simulate_command)
