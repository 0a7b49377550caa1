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
from solitonde.instrument.inference.loaded_table import EstimateUnavailable
from solitonde.instrument.inference.pipeline import estimate, summarise
from solitonde.instrument.inference.table_set import TableSet
from solitonde.instrument.service.app import build_app
from solitonde.instrument.service.settings import Settings
from solitonde.signal import io as signal_io
from solitonde.signal.features import extract
from solitonde.signal.synth import pulse_train
from solitonde.signal.waveform import Waveform

ROOT = Path(__file__).resolve().parents[2]
TABLE = ROOT / "data_samples" / "default_table.h5"
CSV = ROOT / "data_samples" / "waveforms" / "synthetic_D9.53_t4.83_snr40.csv"
STUDIES = {"studies/validate_scores.py",  # scores synthetic plates, with a profile study
           "studies/map_study.py"}  # inverts its scans' positions one by one beside the joint
JOINT = {"inference/joint_map.py"}
"""A scan's joint posterior inverts each position against the one table the scan's family
chose (its per-position answer and likelihood, instrument.inference.joint_map), not a table
per measurement."""


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


def test_a_size_without_a_reflection_enters_as_the_bound_of_its_hidden_reflection() -> None:
    """Shots with no reflection still bound the plate: alone they answer 'at most ... mm'
    (upper_bound_only); beside a size with a reflection they enter as a bound, named in the
    warnings and adding to the fit's chi^2. Shots without a sphere size give no input."""
    feats = [extract(w) for w in signal_io.read(CSV)]
    sizes = summarise([9.53e-3] * len(feats), feats)
    tables = TableSet([TABLE], warm_up=False)
    result = estimate(tables, sizes)
    assert result.skipped == [] and result.table_id == "default_table"
    dt = 5e-7  # an incident pulse and nothing after it
    lone = Waveform(0.0, dt, pulse_train(4000, dt, [(300e-6, 50.0, 40e-6)]))
    silent = summarise([19.05e-3], [extract(lone)])
    assert silent[0].skip_reason() is None
    bound = silent[0].inputs()
    assert bound.hidden and 0 < bound.arr_upper_bound < 0.05
    alone = estimate(tables, silent).estimate
    assert alone.thickness_m.status == "upper_bound_only"
    low, high = alone.thickness_m.ci95
    assert low is None and 1.5e-3 < high < 6e-3
    both = estimate(tables, [*sizes, *silent])
    assert both.skipped == [] and both.estimate.n_terms == 3
    assert any("no reflection with D = 19.1 mm" in w for w in both.estimate.warnings)
    # the 19.05 mm model reflection at the 9.53 mm answer is far above the bound: it adds misfit
    assert both.estimate.fit["chi2"] > result.estimate.fit["chi2"] + 4
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
    assert callers == {"inference/pipeline.py", *STUDIES, *JOINT}, callers


def test_the_service_inverts_a_silent_size_as_its_bound_and_exports_the_sizes_it_used(
        tmp_path) -> None:
    """One measurement, two sphere sizes, the larger without a reflection: the estimate comes
    from the other with the silent one's ARR bound beside it (not skipped, named in the
    warnings), and the estimates export names both sizes, as both were inverted."""
    import csv as csv_module
    import io

    shots = [w.to_dict() for w in signal_io.read(CSV)]
    dt = 5e-7
    # 87 us at half height: a 50 N solitary wave of 19.05 mm spheres (a narrower one would be
    # implausible_units for that size)
    lone = Waveform(0.0, dt, pulse_train(4000, dt, [(400e-6, 50.0, 290e-6)]),
                    metadata={**signal_io.read(CSV)[0].metadata, "sphere_diameter": 0.01905})
    settings = Settings(store_path=tmp_path / "s.sqlite", table_path=TABLE)
    with TestClient(build_app(settings)) as client:
        r = client.post("/v1/measurements", json={"shots": [*shots, lone.to_dict()]})
        assert r.status_code == 201, r.text
        est = r.json()["estimate"]
        # The silent size is not consistent with the other: a 19.05 mm chain on this 4.8 mm
        # plate returns a reflection of ARR 0.11, five times the bound, so the answer is flagged
        # (p < 0.001; the 8-node table's looser interpolation error let it pass as constrained).
        assert est["thickness_m"]["status"] == "inconsistent"
        assert est["warnings"][0].startswith("inconsistent:")
        assert est["skipped"] == []
        assert [i["arr_upper_bound"] is not None for i in est["inputs"]] == [False, True]
        assert any("no reflection with D = 19.1 mm" in w for w in est["warnings"])
        rows = list(csv_module.DictReader(io.StringIO(client.get(
            "/v1/measurements/export", params={"kind": "estimates"}).text)))
    assert [row["sphere_diameters_m"] for row in rows] == ["0.00953;0.01905"]
    assert rows[0]["fit_p_value"] and "no calibration" in rows[0]["warnings"]
