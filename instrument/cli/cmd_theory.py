"""`solitonde theory`: the paper's closed-form predictions for a scene, or for its 3 x 3 grid."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TypedDict, cast

import typer
from rich.console import Console
from rich.table import Table

from solitonde.model.errors import SceneError
from solitonde.model.scene import Scene, load_scene
from solitonde.model.zener import A0_K, RAYLEIGH_K, predict

GRID_DIAMETERS_M = (4.76e-3, 9.53e-3, 19.05e-3)  # 3/16, 3/8, 3/4 in (paper Sec. 2)
GRID_THICKNESSES_M = (2.29e-3, 3.18e-3, 4.83e-3)

GridRow = TypedDict("GridRow", {
    "diameter_m": float, "thickness_m": float, "d_over_t": float, "lambda": float, "e": float,
    "arr": float, "tof_s": float, "tof_over_d_s_per_m": float})
"""One sphere/plate combination of the grid (``theory --grid --json``)."""

TheoryJSON = TypedDict("TheoryJSON", {
    "lambda": float, "e": float, "tau_c": float, "contact_time_s": float, "arr": float,
    "tof_s": float, "travel_time_s": float, "critical_distance_m": dict[str, float],
    "critical_distance_k057_m": float, "critical_distance_k02_m": float,
    "solitary_wave_speed_m_s": float, "incident_peak_force_N": float, "travel_diameters": int,
    "diameter_m": float, "thickness_m": float, "d_over_t": float, "impact_velocity_m_s": float})
"""``theory --json`` (:meth:`solitonde.model.zener.TheoryPrediction.to_dict`)."""


def grid_rows(scene: Scene) -> list[GridRow]:
    """Theory for the paper's sphere/plate combinations, other scene settings kept, by D/t."""
    rows: list[GridRow] = []
    for diameter in GRID_DIAMETERS_M:
        for thickness in GRID_THICKNESSES_M:
            variant = scene.with_overrides(
                {"chain.diameter": diameter, "plate.thickness": thickness}
            )
            p = predict(variant)
            rows.append({
                "diameter_m": diameter,
                "thickness_m": thickness,
                "d_over_t": p.d_over_t,
                "lambda": p.lambda_,
                "e": p.e,
                "arr": p.arr,
                "tof_s": p.tof_s,
                "tof_over_d_s_per_m": p.tof_s / diameter,
            })
    return sorted(rows, key=lambda row: row["d_over_t"])


def _scene_table(data: TheoryJSON) -> Table:
    table = Table(title="Zener theory (infinite plate)", show_header=True)
    table.add_column("quantity")
    table.add_column("value", justify="right")
    table.add_column("unit")
    lines = [
        ("sphere diameter D", data["diameter_m"] * 1e3, "mm"),
        ("plate thickness t", data["thickness_m"] * 1e3, "mm"),
        ("D/t", data["d_over_t"], ""),
        ("impact velocity v_imp", data["impact_velocity_m_s"], "m/s"),
        ("inelasticity lambda", data["lambda"], ""),
        ("restitution e", data["e"], ""),
        ("contact time tau_c", data["tau_c"], "(dimensionless)"),
        ("contact time T_c", data["contact_time_s"] * 1e6, "us"),
        ("amplitude ratio ARR", data["arr"], ""),
        ("time of flight TOF", data["tof_s"] * 1e3, "ms"),
        (f"travel time ({data['travel_diameters']} D each way)", data["travel_time_s"] * 1e3,
         "ms"),
        (f"critical distance, k = {RAYLEIGH_K}", data["critical_distance_k057_m"] * 1e3, "mm"),
        (f"critical distance, k = {A0_K}", data["critical_distance_k02_m"] * 1e3, "mm"),
        ("solitary wave speed V_s", data["solitary_wave_speed_m_s"], "m/s"),
        ("incident peak force F_m", data["incident_peak_force_N"], "N"),
    ]
    for name, value, unit in lines:
        table.add_row(name, f"{value:.6g}", unit)
    return table


def _grid_table(rows: list[GridRow]) -> Table:
    table = Table(title="Zener theory on the paper's 3 x 3 grid (infinite plate)")
    for name in ("D mm", "t mm", "D/t", "lambda", "e", "ARR", "TOF ms", "TOF/D s/m"):
        table.add_column(name, justify="right")
    for row in rows:
        table.add_row(
            f"{row['diameter_m'] * 1e3:.2f}", f"{row['thickness_m'] * 1e3:.2f}",
            f"{row['d_over_t']:.3f}", f"{row['lambda']:.4f}", f"{row['e']:.4g}",
            f"{row['arr']:.4g}", f"{row['tof_s'] * 1e3:.4f}", f"{row['tof_over_d_s_per_m']:.4f}",
        )
    return table


def theory(
    scene_file: Path | None = typer.Option(
        None, "--scene", help="Scene file (YAML or JSON); the paper's setup when omitted."
    ),
    overrides: list[str] | None = typer.Option(
        None, "--set", help="Override a scene value, e.g. --set plate.thickness=3.18e-3."
    ),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of a table."),
    grid: bool = typer.Option(
        False, "--grid", help="The paper's 3 x 3 sphere/plate combinations, sorted by D/t."
    ),
) -> None:
    """Closed-form predictions (Zener impact, ARR, TOF, critical distance) for a scene."""
    console = Console()
    try:
        scene = load_scene(scene_file, overrides or [])
        if grid:
            rows = grid_rows(scene)
            if as_json:
                typer.echo(json.dumps(rows, indent=2))
            else:
                console.print(_grid_table(rows))
            return
        data = cast(TheoryJSON, predict(scene).to_dict())
    except SceneError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=2) from None
    if as_json:
        typer.echo(json.dumps(data, indent=2))
    else:
        console.print(_scene_table(data))


def register(app: typer.Typer) -> None:
    """Add `theory` to the CLI."""
    app.command("theory")(theory)
