"""Tables per plate family: a table records what it was built for; the service and the command
line hold several and pick the one a measurement belongs to, or refuse, naming why.

Two tiny tables (infinite plate, D = 9.53 mm, t 2-4.83 mm, about a second each): the paper's
aluminium plate and a structural steel plate given by name in a YAML scene.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app as build_cli
from solitonde.instrument.inference.fine_grid import predict
from solitonde.instrument.inference.table_set import TableChoiceError, TableSet
from solitonde.instrument.service.app import build_app
from solitonde.instrument.service.settings import Settings
from solitonde.instrument.tables.measured import as_measured
from solitonde.instrument.tables.table import ModelTable
from solitonde.model.scene import scene_from_dict
from solitonde.model.simulate import simulate
from solitonde.signal.synth import degrade

D = 9.53e-3
THICKNESSES = "2.0e-3,2.5e-3,3.18e-3,4.0e-3,4.83e-3"
STEEL_T = 3.18e-3


def _build(tmp: Path, name: str, scene: str | None, table_id: str | None = None) -> Path:
    args = ["table", "build", "--out", str(tmp / f"{name}.h5"), "--diameters", str(D),
            "--thicknesses", THICKNESSES, "--distances", "0.3,0.4", "--workers", "1",
            "--no-progress", "--set", "effects.plate_model=infinite"]
    if scene:
        (tmp / f"{name}.yaml").write_text(scene)
        args += ["--scene", str(tmp / f"{name}.yaml")]
    if table_id:
        args += ["--id", table_id]
    res = CliRunner().invoke(build_cli(), args)
    assert res.exit_code == 0, res.output
    return tmp / f"{name}.h5"


@pytest.fixture(scope="module")
def tables(tmp_path_factory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("tables")
    return {"al": _build(tmp, "al_plates", None),
            "steel": _build(tmp, "steel", "plate: {material: steel_structural}\n", "steel-A36")}


def _steel_shots(n: int = 3) -> list[dict]:
    scene = scene_from_dict({"chain": {"diameter": D},
                             "plate": {"thickness": STEEL_T, "material": "steel_structural",
                                       "distance_to_support": 0.35},
                             "effects": {"plate_model": "infinite"}})
    result = simulate(scene)
    clean = as_measured(result)
    peak = float(result.truth["incident_peak_N"] - result.truth["static_sensor_N"])
    return [{"t0": clean.t0, "dt": clean.dt,
             "samples": degrade(clean.samples, 40.0, np.random.default_rng(k), peak,
                                bits=12).tolist(),
             "metadata": {"plate_id": "S1", "position": "A", "sphere_diameter": D, "shot": k}}
            for k in range(n)]


def test_a_table_records_its_id_and_family(tables):
    res = CliRunner().invoke(build_cli(), ["table", "info", str(tables["steel"]), "--json"])
    info = json.loads(res.stdout)
    assert info["id"] == "steel-A36"
    family = info["family"]
    assert family["plate_material"]["name"] == "steel_structural"
    assert family["plate_material"]["youngs_modulus"] == 200e9
    assert family["sphere_material"]["name"] == "steel_440c"
    assert (family["plate_size_m"], family["supports"], family["gravity"],
            family["n_particles"], family["sensor_index"]) == ([0.914, 0.914], "opposite_edges",
                                                                True, 20, 7)
    res = CliRunner().invoke(build_cli(), ["table", "info", str(tables["al"]), "--json"])
    assert json.loads(res.stdout)["id"] == "al_plates"  # no --id: the file's stem
    bad = CliRunner().invoke(build_cli(), ["table", "build", "--out", "x.h5", "--id", "a b"])
    assert bad.exit_code == 2 and "--id" in bad.stderr


def test_the_rule_that_picks_a_table(tables):
    both = TableSet([tables["al"], tables["steel"]])
    assert set(both.by_id) == {"al_plates", "steel-A36"}
    assert both.choose([D], plate_material="steel_structural").table.table_id == "steel-A36"
    assert both.choose([D], plate_material="al_6061").table.table_id == "al_plates"
    assert both.choose([D], table="al_plates").table.table_id == "al_plates"
    cases = [({}, "table", "more than one table"),
             ({"table": "nope"}, "table", "al_plates, steel-A36"),
             ({"plate_material": "ti_6al_4v"}, "plate_material", "no table serves"),
             ({"plate_material": "unobtainium"}, "plate_material", "unknown material"),
             ({"table": "al_plates", "plate_material": "steel_structural"}, "plate_material",
              "another plate family")]
    for kwargs, field, words in cases:
        with pytest.raises(TableChoiceError) as err:
            both.choose([D], **kwargs)
        assert err.value.field == field and words in str(err.value), (kwargs, str(err.value))
    with pytest.raises(TableChoiceError) as err:
        both.choose([19.05e-3])
    assert "19.05" in str(err.value) or "0.01905" in str(err.value)


def test_the_service_serves_both_and_a_steel_shot_gets_its_thickness(tables, tmp_path):
    settings = Settings(store_path=tmp_path / "s.sqlite", table_path=tables["al"],
                        table_paths=(tables["steel"],))
    shots = _steel_shots()
    with TestClient(build_app(settings)) as client:
        listed = client.get("/v1/tables").json()["items"]
        assert {t["id"]: t["family"]["plate_material"]["name"] for t in listed} == {
            "al_plates": "al_6061", "steel-A36": "steel_structural"}
        r = client.post("/v1/measurements", json={"shots": shots})
        assert r.status_code == 422 and r.json()["field"] == "metadata.table"
        assert "al_plates, steel-A36" in r.json()["detail"]
        for meta in ({"table": "steel-A36"}, {"plate_material": "steel_structural"}):
            r = client.post("/v1/measurements", json={"shots": shots, "metadata": meta,
                                                      "allow_duplicate": True})
            assert r.status_code == 201, r.text
            est = r.json()["estimate"]
            assert est["table"] == "steel-A36"
            lo, hi = est["thickness_m"]["ci95"]
            assert lo <= STEEL_T <= hi, est["thickness_m"]
        r = client.post("/v1/measurements", json={"shots": shots, "metadata": {
            "table": "al_plates", "plate_material": "steel_structural"}})
        assert r.status_code == 422 and r.json()["field"] == "metadata.plate_material"
        assert "another plate family" in r.json()["detail"]
        assert len(client.get("/v1/measurements").json()["items"]) == 2  # refused: not stored
        body = {"inputs": [{"diameter_m": D, "tof_s": 5.3e-4, "arr": 0.5}]}
        r = client.post("/v1/invert", json=body)
        assert r.status_code == 422 and r.json()["field"] == "table"
        r = client.post("/v1/invert", json={**body, "table": "steel-A36"})
        assert r.status_code == 200 and r.json()["estimate"]["table"] == "steel-A36"


def test_the_command_line_takes_several_tables_by_the_same_rule(tables):
    # features the steel table holds at 3.5 mm (an answer, not an inconsistent one, which
    # exits 1)
    tof, arr = predict(ModelTable.load(tables["steel"]), D, 3.5e-3, 0.35)
    base = ["invert", "--tof", repr(tof), "--arr", repr(arr), "--diameter", str(D), "--table",
            str(tables["al"]), "--table", str(tables["steel"]), "--json"]
    res = CliRunner().invoke(build_cli(), base)
    assert res.exit_code == 2 and "al_plates, steel-A36" in res.stderr
    res = CliRunner().invoke(build_cli(), [*base, "--plate-material", "steel_structural"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["table"] == "steel-A36"
    res = CliRunner().invoke(build_cli(), [*base[:-5], "--table", str(tables["al"]),
                                           "--plate-material", "steel_structural"])
    assert res.exit_code == 2 and "--plate-material" in res.stderr
