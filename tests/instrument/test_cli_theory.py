"""`solitonde theory`: JSON contract, table, grid, clean errors, from the root and elsewhere."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app
from solitonde.model import scene_from_dict
from solitonde.model.zener import predict

ROOT = Path(__file__).resolve().parents[2]
EXE = Path(sys.executable).with_name("solitonde")
KEYS = {"lambda", "e", "tau_c", "contact_time_s", "arr", "tof_s", "critical_distance_m",
        "critical_distance_k057_m", "critical_distance_k02_m", "solitary_wave_speed_m_s",
        "incident_peak_force_N"}
runner = CliRunner()


def _run(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(EXE), *args], cwd=cwd, capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("where", ["root", "elsewhere"])
def test_json_from_root_and_elsewhere(where, tmp_path):
    cwd = ROOT if where == "root" else tmp_path
    out = _run("theory", "--json", cwd=cwd)
    assert out.returncode == 0, out.stderr
    data = json.loads(out.stdout)
    assert set(data) >= KEYS
    assert set(data["critical_distance_m"]) == {"0.57", "0.2"}
    for key in ("diameter_m", "thickness_m", "d_over_t", "impact_velocity_m_s"):
        assert key in data
    expected = predict(scene_from_dict({})).to_dict()
    assert data["critical_distance_m"] == pytest.approx(expected.pop("critical_distance_m"))
    assert {k: data[k] for k in expected} == pytest.approx(expected, rel=1e-12)


def test_scene_file_and_set(tmp_path):
    scene = tmp_path / "s.yaml"
    scene.write_text("chain:\n  diameter: 0.01905\n")
    result = runner.invoke(build_app(), ["theory", "--scene", str(scene), "--set",
                                         "plate.thickness=2.29e-3", "--json"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.output)
    assert data["diameter_m"] == 0.01905 and data["thickness_m"] == 2.29e-3
    assert data["arr"] < 1e-3  # D/t = 8.3: essentially no reflection


def test_table_output_names_every_quantity():
    result = runner.invoke(build_app(), ["theory"])
    assert result.exit_code == 0, result.output
    for word in ("lambda", "restitution", "ARR", "TOF", "critical distance", "k = 0.57",
                 "k = 0.2", "solitary wave speed", "peak force"):
        assert word in result.output


def test_grid_json_is_the_paper_3x3_sorted_by_d_over_t():
    result = runner.invoke(build_app(), ["theory", "--grid", "--json"])
    assert result.exit_code == 0, result.output
    rows = json.loads(result.output)
    assert len(rows) == 9
    assert {r["diameter_m"] for r in rows} == {4.76e-3, 9.53e-3, 19.05e-3}
    assert {r["thickness_m"] for r in rows} == {2.29e-3, 3.18e-3, 4.83e-3}
    ratios = [r["d_over_t"] for r in rows]
    assert ratios == sorted(ratios)
    for r in rows:
        assert {"d_over_t", "lambda", "e", "arr", "tof_s", "tof_over_d_s_per_m"} <= set(r)
        assert r["tof_over_d_s_per_m"] == pytest.approx(r["tof_s"] / r["diameter_m"])
    table = runner.invoke(build_app(), ["theory", "--grid"])
    assert table.exit_code == 0 and "TOF/D" in table.output and "19.05" in table.output


BAD = [
    (["--set", "plate.thickness=-1"], "plate.thickness"),
    (["--set", "chain.sensor_index=40"], "chain.sensor_index"),
    (["--set", "plate.colour=red"], "plate.colour"),
    (["--set", "plate.thickness"], "plate.thickness"),
    (["--scene", "/nonexistent/scene.yaml"], "scene"),
]


@pytest.mark.parametrize(("args", "field"), BAD)
def test_scene_errors_are_one_clean_line_with_exit_code_2(args, field):
    result = runner.invoke(build_app(), ["theory", *args])
    assert result.exit_code == 2
    assert result.exception is None or isinstance(result.exception, SystemExit)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {field}")
    assert result.stdout == ""


def test_scene_error_in_a_real_process_has_no_traceback(tmp_path):
    out = _run("theory", "--set", "chain.diameter=0", cwd=tmp_path)
    assert out.returncode == 2
    assert out.stderr.strip().splitlines() == [
        "error: chain.diameter: must be >= 0.0001, got 0"]
