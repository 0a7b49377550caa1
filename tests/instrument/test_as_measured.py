"""One bridge from a simulation to a Waveform (``tables.measured.as_measured``): the command line
and the service measure a scene identically, and no producer of features from a simulation builds
its own Waveform (a walk over the code of instrument/)."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app as build_cli
from solitonde.instrument.service.app import build_app
from solitonde.instrument.service.settings import Settings
from solitonde.instrument.tables.measured import MIN_PRETRIGGER, PRETRIGGER_FRACTION, as_measured
from solitonde.instrument.tables.plate_task import simulate_point
from solitonde.model.scene import scene_from_dict
from solitonde.model.simulate import simulate

INSTRUMENT = Path(__file__).resolve().parents[2] / "instrument"
SCENE = {"plate": {"thickness": 4.83e-3}, "effects": {"plate_model": "infinite"}}

# Modules that build a Waveform from something other than a simulation, and why.
OTHER_WAVEFORMS = {
    "service/ingest.py": "shots posted over REST or read from uploaded files",
    "service/routes_measurements.py": "raw binary uploads",
    "cli/cmd_samples.py": "cuts already measured shots to one time axis; a scan file named nothing",
}
# Modules that extract features from recorded shots, not simulations.
RECORDED_EXTRACTS = {"inference/shot_measure.py"}  # measure_shot: every recorded shot
MEASURED_CALLS = {"as_measured", "to_waveform"}  # to_waveform: cmd_simulate's call of as_measured


def test_the_cli_and_the_service_report_identical_tof_and_arr(tmp_path: Path) -> None:
    """`solitonde simulate --json` and POST /v1/simulate on the same scene: the same numbers,
    and the same as a table point of that scene."""
    scene_file = tmp_path / "scene.json"
    scene_file.write_text(json.dumps(SCENE))
    res = CliRunner().invoke(build_cli(), ["simulate", "--scene", str(scene_file), "--json"])
    assert res.exit_code == 0, res.output
    cli = json.loads(res.stdout)
    with TestClient(build_app(Settings(store_path=tmp_path / "s.sqlite"))) as client:
        r = client.post("/v1/simulate", json={"scene": SCENE, "include_trace": False})
    assert r.status_code == 200, r.text
    service = r.json()["features"]
    point = simulate_point(scene_from_dict(SCENE))
    assert cli["tof_s"] == service["tof_s"] == point["tof_s"]
    assert cli["arr"] == service["arr"] == point["arr"]
    assert cli["n_samples"] == r.json()["n_samples"]


def test_as_measured_keeps_the_impact_at_zero_and_prepends_the_static_reading() -> None:
    result = simulate(scene_from_dict({"effects": {"plate_model": "rigid"}}))
    wf = as_measured(result, {"plate_id": "P1"})
    n_pre = wf.n - result.samples.size
    assert n_pre == max(MIN_PRETRIGGER, int(PRETRIGGER_FRACTION * result.samples.size))
    assert wf.t0 == pytest.approx(result.t0 - n_pre * result.dt, abs=1e-15)
    np.testing.assert_array_equal(wf.samples[n_pre:], result.samples)
    assert np.all(wf.samples[:n_pre] == result.samples[0])
    assert wf.units == "N"
    assert wf.metadata["sphere_diameter"] == result.scene.chain.diameter
    assert wf.metadata["plate_id"] == "P1" and wf.metadata["source"] == "simulation"


def _calls(tree: ast.AST, name: str) -> list[ast.Call]:
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            f = node.func
            called = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) \
                else None
            if called == name:
                out.append(node)
    return out


def _is_measured(expr: ast.expr, assigned: dict[str, ast.expr], depth: int = 0) -> bool:
    """as_measured(...), a name bound to one, or .with_samples/.with_metadata of one."""
    if depth > 10:
        return False
    if isinstance(expr, ast.Call):
        f = expr.func
        if isinstance(f, ast.Name) and f.id in MEASURED_CALLS:
            return True
        if isinstance(f, ast.Attribute) and f.attr in ("with_samples", "with_metadata"):
            return _is_measured(f.value, assigned, depth + 1)
    if isinstance(expr, ast.Name) and expr.id in assigned:
        return _is_measured(assigned[expr.id], assigned, depth + 1)
    return False


def _sources() -> dict[str, ast.AST]:
    return {str(p.relative_to(INSTRUMENT)): ast.parse(p.read_text())
            for p in INSTRUMENT.rglob("*.py") if p.name != "measured.py"}


def test_every_feature_from_a_simulation_is_measured_through_as_measured() -> None:
    """Each extract() in instrument/ reads a Waveform made by as_measured (directly, through a
    name, or with noise added by with_samples), except where recorded shots are measured."""
    unmeasured = set()
    for rel, tree in _sources().items():
        assigned = {t.id: node.value for node in ast.walk(tree) if isinstance(node, ast.Assign)
                    for t in node.targets if isinstance(t, ast.Name)}
        for call in _calls(tree, "extract"):
            if not (call.args and _is_measured(call.args[0], assigned)):
                unmeasured.add(rel)
    assert unmeasured == RECORDED_EXTRACTS, unmeasured


def test_no_module_builds_its_own_waveform_from_a_simulation() -> None:
    builders = {rel for rel, tree in _sources().items() if _calls(tree, "Waveform")}
    assert builders == set(OTHER_WAVEFORMS), builders


def test_a_sample_rate_that_cannot_resolve_the_pulse_is_refused_before_the_run(
        tmp_path: Path) -> None:
    """20 kHz puts under 2 samples across the default scene's 89 us pulse: 422 naming
    scene.output.sample_rate from the service, exit 2 from the command line, no simulation."""
    scene = {"output": {"sample_rate": 2e4}}
    with TestClient(build_app(Settings(store_path=tmp_path / "s.sqlite"))) as client:
        r = client.post("/v1/simulate", json={"scene": scene})
    assert r.status_code == 422 and r.json()["field"] == "scene.output.sample_rate", r.text
    assert "44,715 Hz" in r.json()["detail"]
    res = CliRunner().invoke(build_cli(), ["simulate", "--set", "output.sample_rate=2e4"])
    assert res.exit_code == 2 and "output.sample_rate" in res.output
