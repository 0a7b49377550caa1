"""What the tests of a recording's faults share: the 4 mm structural-steel plate of the
independent solve and its five noisy shots, editing a scope CSV's shots after the noise (a clip
at the rail, a step of the level), and ``analyze --invert`` with a stated sphere size and table,
as a user runs it, or the shots posted to the service."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from independent_chain import write_shots
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app
from solitonde.signal import io as signal_io

ROOT = Path(__file__).resolve().parents[2]
STEEL_TABLE = ROOT / "data_samples" / "steel_table.h5"
STEEL = {"youngs_modulus": 210e9, "poisson_ratio": 0.30, "density": 7850.0}
"""The recordings' plate: structural steel as EN 1993-1-1 states it, not the steel table's."""


def steel_shots(path: Path, t: np.ndarray, force: np.ndarray, shots: int = 5) -> Path:
    """``shots`` noisy shots (40 dB, seed 1) of one trace of the 4 mm steel plate, written as a
    scope's CSV of plate ``steel-4mm``."""
    return write_shots(path, t, force, shots=shots, snr_db=40.0, seed=1,
                       metadata={"plate_id": "steel-4mm"})


def edit_shots(path: Path, change: Callable[[float, int, float], float]) -> Path:
    """Rewrite the CSV at ``path`` (``write_shots``' layout) in place with ``change(time, shot,
    value)`` applied to every sample of every shot; header lines are kept."""
    out = []
    for line in path.read_text().splitlines():
        if line.startswith("#") or line.startswith("time"):
            out.append(line)
            continue
        values = line.split(",")
        time = float(values[0])
        out.append(",".join([values[0], *(repr(float(change(time, k, float(v))))
                                          for k, v in enumerate(values[1:]))]))
    path.write_text("\n".join(out) + "\n")
    return path


def analyze_inverted(path: Path, table: Path = STEEL_TABLE, diameter_m: float = 9.53e-3
                     ) -> tuple[int, dict[str, Any]]:
    """``solitonde analyze PATH --invert --sphere-diameter D --table TABLE --json``: its exit code
    and its JSON."""
    result = CliRunner().invoke(build_app(), [
        "analyze", str(path), "--invert", "--sphere-diameter", str(diameter_m), "--table",
        str(table), "--json"])
    return result.exit_code, json.loads(result.stdout)


def post_recording(path: Path, table: Path, store: Path, diameter_m: float = 9.53e-3) -> Any:
    """The recording's shots posted as JSON to ``POST /v1/measurements`` of a service on
    ``table``, each stating its sphere size: the service's response."""
    from fastapi.testclient import TestClient

    from solitonde.instrument.service.app import build_app as build_service
    from solitonde.instrument.service.settings import Settings

    shots = [w.to_dict() for w in signal_io.read(path)]
    for shot in shots:
        shot["metadata"]["sphere_diameter"] = diameter_m
    with TestClient(build_service(Settings(store_path=store, table_path=table))) as client:
        return client.post("/v1/measurements", json={"shots": shots})
