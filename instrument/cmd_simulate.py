"""`solitonde simulate`: run one scene through the chain model and measure its sensor trace.

The model (``solitonde.model``) makes the trace; the features (TOF, ARR, pulse peaks) are
measured from the sampled trace the way a recorded waveform would be measured.

``--out`` writes the trace as CSV: ``# key: <JSON>`` comment lines first (``format``,
``scene``, ``plate_model``, ``plate_model_reason``, ``units``, ``sample_rate_hz``), then the
header ``time_s,force_N`` and one row per sample.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from solitonde.model.errors import SceneError, SimulationError
from solitonde.model.scene import load_scene
from solitonde.model.simulate import SimulationResult, simulate

CSV_FORMAT = "solitonde-trace-csv/1"


def two_largest_separated_peaks(
    time: np.ndarray, force: np.ndarray
) -> dict[str, float]:
    """TOF and ARR from the two largest local maxima that are further apart than the pulse.

    The baseline is the first sample (the static load). The separation needed is twice the
    largest pulse's full width at half its rise, so a pulse's own shoulders never count twice.
    """
    base = float(force[0])
    rise = force - base
    inner = np.flatnonzero((rise[1:-1] > rise[:-2]) & (rise[1:-1] >= rise[2:])) + 1
    nan = {"incident_time_s": math.nan, "incident_peak_N": math.nan,
           "reflected_time_s": math.nan, "reflected_peak_N": math.nan,
           "tof_s": math.nan, "arr": math.nan}
    if inner.size == 0:
        return nan
    order = inner[np.argsort(rise[inner])[::-1]]
    top = order[0]
    above = rise >= 0.5 * rise[top]
    left = top
    while left > 0 and above[left - 1]:
        left -= 1
    right = top
    while right < rise.size - 1 and above[right + 1]:
        right += 1
    min_gap = 2.0 * max(time[right] - time[left], time[1] - time[0])
    second = next((k for k in order[1:] if abs(time[k] - time[top]) > min_gap), None)
    if second is None:
        return nan
    first, later = sorted((int(top), int(second)))
    return {
        "incident_time_s": float(time[first]),
        "incident_peak_N": float(force[first]),
        "reflected_time_s": float(time[later]),
        "reflected_peak_N": float(force[later]),
        "tof_s": float(time[later] - time[first]),
        "arr": float(rise[later] / rise[first]),
    }


def measure(result: SimulationResult) -> dict[str, float]:
    """Pulse features of the sampled sensor trace."""
    return two_largest_separated_peaks(result.time, result.samples)


def summary(result: SimulationResult, features: dict[str, float]) -> dict[str, Any]:
    """The JSON of ``solitonde simulate --json`` (the first twelve keys are a public contract)."""
    d = result.diagnostics
    return {
        "plate_model": result.plate_model,
        "tof_s": features["tof_s"],
        "arr": features["arr"],
        "incident_peak_N": features["incident_peak_N"],
        "reflected_peak_N": features["reflected_peak_N"],
        "incident_time_s": features["incident_time_s"],
        "reflected_time_s": features["reflected_time_s"],
        "energy_drift": d["energy_drift"],
        "steps": d["steps"],
        "dt_s": d["dt_s"],
        "wall_s": d["wall_s"],
        "status": d["status"],
        "plate_model_reason": result.plate_model_reason,
        "sample_rate_hz": 1.0 / result.dt,
        "n_samples": int(result.samples.size),
        "duration_s": d["duration_s"],
        "plate_work_J": d["plate_work_J"],
        "dissipated_J": d["dissipated_J"],
        "model_truth": result.truth,
    }


def _finite(value: float) -> float | None:
    return value if isinstance(value, float) and math.isfinite(value) else None


def _json_safe(data: Any) -> Any:
    """NaN and inf are not JSON: they become null."""
    if isinstance(data, dict):
        return {k: _json_safe(v) for k, v in data.items()}
    if isinstance(data, float):
        return _finite(data)
    return data


def write_csv(path: Path, result: SimulationResult) -> None:
    """Write the sensor trace with the scene as metadata, atomically (temporary name, rename)."""
    header = {
        "format": CSV_FORMAT,
        "scene": result.scene.to_dict(),
        "plate_model": result.plate_model,
        "plate_model_reason": result.plate_model_reason,
        "units": "N",
        "sample_rate_hz": 1.0 / result.dt,
    }
    lines = [f"# {key}: {json.dumps(value)}" for key, value in header.items()]
    lines.append("time_s,force_N")
    body = "\n".join(f"{t:.12e},{f:.12e}" for t, f in zip(result.time, result.samples, strict=True))
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write("\n".join(lines) + "\n" + body + "\n")
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_plot(path: Path, result: SimulationResult, features: dict[str, float]) -> None:
    """Sensor trace with the detected incident and reflected pulses marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4))
    ax.plot(result.time * 1e3, result.samples, lw=1.0, color="0.2", label="sensor")
    for name, color in (("incident", "tab:blue"), ("reflected", "tab:red")):
        t, f = features[f"{name}_time_s"], features[f"{name}_peak_N"]
        if math.isfinite(t) and math.isfinite(f):
            ax.plot([t * 1e3], [f], "o", color=color, label=f"{name} {f:.3g} N at {t * 1e3:.4g} ms")
    s = result.scene
    ax.set_title(
        f"D = {s.chain.diameter * 1e3:.2f} mm, t = {s.plate.thickness * 1e3:.2f} mm, "
        f"{result.plate_model}: TOF = {features['tof_s'] * 1e3:.4g} ms, ARR = {features['arr']:.3g}"
    )
    ax.set_xlabel("time after impact (ms)")
    ax.set_ylabel("sensor force (N)")
    ax.legend(loc="upper right", fontsize="small")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _table(data: dict[str, Any]) -> Table:
    table = Table(title="Chain simulation", show_header=True)
    table.add_column("quantity")
    table.add_column("value", justify="right")
    rows = [
        ("plate model", data["plate_model"]),
        ("TOF (ms)", data["tof_s"] * 1e3 if _finite(data["tof_s"]) is not None else "n/a"),
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
    scene_file: Path | None = typer.Argument(
        None, help="Scene file (YAML or JSON); the paper's setup when omitted."
    ),
    overrides: list[str] | None = typer.Option(
        None, "--set", help="Override a scene value, e.g. --set plate.thickness=3.18e-3."
    ),
    out: Path | None = typer.Option(None, "--out", help="Write the sensor trace as CSV."),
    plot: Path | None = typer.Option(None, "--plot", help="Draw the trace (PNG) with pulses."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of a table."),
) -> None:
    """Simulate one shot (striker, chain, plate) and report TOF, ARR and diagnostics."""
    try:
        scene = load_scene(scene_file, overrides or [])
        result = simulate(scene)
    except SceneError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=2) from None
    except SimulationError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=1) from None
    features = measure(result)
    data = summary(result, features)
    if out is not None:
        write_csv(out, result)
    if plot is not None:
        write_plot(plot, result, features)
    if as_json:
        typer.echo(json.dumps(_json_safe(data), indent=2))
    else:
        Console().print(_table(data))


def register(app: typer.Typer) -> None:
    """Add `simulate` to the CLI."""
    app.command("simulate")(simulate_command)
