"""The tutorial's walk (docs/tutorial.md), run as written: describe, build the table, calibrate,
analyze, map, report and verify (a few minutes on 2 cores: marked slow,
`pytest -m slow tests/test_readme_your_plate.py`)."""

from __future__ import annotations

import csv
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def walk_script() -> str:
    """The tutorial's first bash block."""
    body = (ROOT / "docs" / "tutorial.md").read_text()
    return re.search(r"```bash\n(.*?)```", body, flags=re.S).group(1)


@pytest.mark.slow
def test_the_your_plate_walk_runs_as_written(tmp_path):
    env = {k: v for k, v in os.environ.items() if not k.startswith("SOLITONDE_")}
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    run = subprocess.run(["bash", "-e", "-c", walk_script()], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=1800)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    out = run.stdout
    assert out.startswith("plan: 120 points = 1 sphere size x 6 thicknesses x 20 distances"), out
    assert "estimated time: " in out and "wrote my_plate.h5: 120 scenes" in out
    rows = list(csv.DictReader((tmp_path / "my_plate" / "my_estimates.csv").open()))
    assert [r["position"] for r in rows] == ["A1", "A2", "A3", "A4"]
    far = next(r for r in rows if r["position"] == "A4")
    assert far["thickness_m_status"] == "constrained"
    assert float(far["thickness_m_ci95_low"]) <= 3.2e-3 <= float(far["thickness_m_ci95_high"])
    assert "support: x cos" in out, out[-2000:]
    assert (tmp_path / "my_plate" / "my_map.png").stat().st_size > 10_000
    assert (tmp_path / "my_plate" / "my_report.pdf").read_bytes().startswith(b"%PDF")
    assert "matches plate 'MY-1'" in out, out[-2000:]
