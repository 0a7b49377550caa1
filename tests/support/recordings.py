"""What the tests of a recording's faults share: editing a scope CSV's shots after the noise (a
clip at the rail, a step of the level), and ``analyze --invert`` with a stated sphere size and
table, as a user runs it."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app


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


def analyze_inverted(path: Path, table: Path, diameter_m: float = 9.53e-3
                     ) -> tuple[int, dict[str, Any]]:
    """``solitonde analyze PATH --invert --sphere-diameter D --table TABLE --json``: its exit code
    and its JSON."""
    result = CliRunner().invoke(build_app(), [
        "analyze", str(path), "--invert", "--sphere-diameter", str(diameter_m), "--table",
        str(table), "--json"])
    return result.exit_code, json.loads(result.stdout)
