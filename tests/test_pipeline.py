"""One path from shots to an estimate (instrument.inference.pipeline): the same two recorded shots
give the same estimate through `analyze --invert`, POST /v1/measurements, POST /v1/invert and
`solitonde invert`; no other module calls the inversion; a size without a reflection is left out
with its reason while the others are inverted."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app as build_cli
from solitonde.instrument.inference.estimates import EstimateUnavailable
from solitonde.instrument.inference.pipeline import estimate, summarise
from solitonde.instrument.inference.table_set import TableSet
from solitonde.instrument.service.app import build_app
from solitonde.instrument.service.settings import Settings
from solitonde.signal import io as signal_io
from solitonde.signal.features import extract
from solitonde.signal.synth import pulse_train
from solitonde.signal.waveform import Waveform

ROOT = Path(__file__).resolve().parents[1]
TABLE = ROOT / "data_samples" / "default_table.h5"
CSV = ROOT / "data_samples" / "waveforms" / "synthetic_D9.53_t4.83_snr40.csv"
STUDIES = {"studies/validate.py"}  # inverts its synthetic plates itself, with a profile study


def _cli(*args: str) -> dict:
    res = CliRunner().invoke(build_cli(), [*args, "--json"])
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout)


def test_every_entry_point_gives_the_same_estimate(tmp_path: Path) -> None:
    analyzed = _cli("analyze", str(CSV), "--invert", "--table", str(TABLE))
    (row,) = analyzed["estimates"]
    (agg,) = analyzed["aggregates"]
    d = agg["sphere_diameter"]
    tof, arr = agg["tof_s"], agg["arr"]
    inverted = _cli("invert", "--table", str(TABLE), "--diameter", repr(d),
                    "--tof", repr(tof["mean"]), "--arr", repr(arr["mean"]),
                    "--tof-std", repr(tof["std"]), "--arr-std", repr(arr["std"]),
                    "--shots", str(tof["count"]))
    shots = [w.to_dict() for w in signal_io.read(CSV)]
    settings = Settings(store_path=tmp_path / "s.sqlite", table_path=TABLE)
    with TestClient(build_app(settings)) as client:
        measured = client.post("/v1/measurements", json={"shots": shots})
        assert measured.status_code == 201, measured.text
        posted = client.post("/v1/invert", json={"inputs": [{
            "diameter_m": d, "tof_s": tof["mean"], "arr": arr["mean"], "tof_std_s": tof["std"],
            "arr_std": arr["std"], "n_shots": tof["count"]}]})
        assert posted.status_code == 200, posted.text
    answers = [row["estimate"], inverted, measured.json()["estimate"], posted.json()["estimate"]]
    medians = {a["thickness_m"]["median"] for a in answers}
    assert len(medians) == 1, medians
    assert {tuple(a["distance_m"]["ci95"]) for a in answers} == {
        tuple(answers[0]["distance_m"]["ci95"])}
    assert all(a["table"] == "default_table" and a["skipped"] == [] for a in answers)


def test_a_size_without_a_reflection_is_left_out_with_its_reason() -> None:
    feats = [extract(w) for w in signal_io.read(CSV)]
    sizes = summarise([9.53e-3] * len(feats), feats)
    tables = TableSet([TABLE], warm_up=False)
    result = estimate(tables, sizes)
    assert result.skipped == [] and result.table_id == "default_table"
    dt = 5e-7  # an incident pulse and nothing after it
    lone = Waveform(0.0, dt, pulse_train(4000, dt, [(300e-6, 50.0, 40e-6)]))
    silent = summarise([19.05e-3], [extract(lone)])
    assert "has a detected reflection" in silent[0].skip_reason()
    both = estimate(tables, [*sizes, *silent])
    assert both.estimate.thickness_m.median == result.estimate.thickness_m.median
    assert both.skipped == [{"sphere_diameter": 19.05e-3, "reason": silent[0].skip_reason()}]
    no_size = summarise([None] * len(feats), feats)
    with pytest.raises(EstimateUnavailable, match="sphere_diameter is missing"):
        estimate(tables, no_size)


def test_no_module_but_the_pipeline_calls_the_inversion() -> None:
    root = ROOT / "instrument"
    callers = set()
    for path in root.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) \
                    and node.func.id == "invert":
                callers.add(str(path.relative_to(root)))
    assert callers == {"inference/pipeline.py", *STUDIES}, callers


def test_the_service_leaves_a_silent_size_out_and_exports_the_sizes_it_used(tmp_path) -> None:
    """One measurement, two sphere sizes, the larger without a reflection: the estimate comes
    from the other, lists the silent one in ``skipped``, and the estimates export names only the
    size that was inverted."""
    import csv as csv_module
    import io

    shots = [w.to_dict() for w in signal_io.read(CSV)]
    dt = 5e-7
    lone = Waveform(0.0, dt, pulse_train(4000, dt, [(300e-6, 50.0, 40e-6)]),
                    metadata={**signal_io.read(CSV)[0].metadata, "sphere_diameter": 0.01905})
    settings = Settings(store_path=tmp_path / "s.sqlite", table_path=TABLE)
    with TestClient(build_app(settings)) as client:
        r = client.post("/v1/measurements", json={"shots": [*shots, lone.to_dict()]})
        assert r.status_code == 201, r.text
        est = r.json()["estimate"]
        assert est["thickness_m"]["status"] == "constrained"
        assert [s["sphere_diameter"] for s in est["skipped"]] == [0.01905]
        rows = list(csv_module.DictReader(io.StringIO(client.get(
            "/v1/measurements/export", params={"kind": "estimates"}).text)))
    assert [row["sphere_diameters_m"] for row in rows] == ["0.00953"]
