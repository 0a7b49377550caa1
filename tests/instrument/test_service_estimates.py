"""The service with a model table: estimates on measurements, /v1/invert, /v1/table, readiness."""

from __future__ import annotations

from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from service_support import (
    TABLE_DIAMETER,
    TABLE_DISTANCES,
    TABLE_THICKNESSES,
    build_tiny_table,
    simulated_shots,
)


@pytest.fixture(scope="module")
def table_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_tiny_table(tmp_path_factory.mktemp("table") / "tiny_table.h5")


@pytest.fixture
def client(service_client, table_path: Path) -> TestClient:
    return service_client(table_path=table_path)


def test_ready_and_table_summary(client: TestClient) -> None:
    """readyz says estimates are on; /v1/table lists the axes the table was built on."""
    ready = client.get("/readyz").json()
    assert ready["table_loaded"] is True and ready["estimates"] is True
    table = client.get("/v1/table").json()
    assert table["loaded"] is True
    axes = table["summary"]["axes"]
    assert axes["thickness_m"]["values"] == pytest.approx(list(TABLE_THICKNESSES))
    assert axes["distance_m"]["values"] == pytest.approx(list(TABLE_DISTANCES))
    assert axes["diameter_m"]["values"] == pytest.approx([TABLE_DIAMETER])
    assert "provenance" in table["summary"]


def test_measurement_gets_an_estimate_that_brackets_the_truth(client: TestClient) -> None:
    """Shots simulated at t = 3.18 mm (between grid points is not needed: on one) with 40 dB
    noise: the 95 % interval holds 3.18 mm; the distance, beyond the critical distance at both
    table distances, is not constrained (the inversion must not invent a number)."""
    r = client.post("/v1/measurements", json={"shots": simulated_shots(3.18e-3)})
    assert r.status_code == 201, r.text
    body = r.json()
    est = body["estimate"]
    assert est is not None and body["estimate_reason"] is None
    thickness = est["thickness_m"]
    assert thickness["status"] == "constrained"
    lo, hi = thickness["ci95"]
    assert lo < 3.18e-3 < hi
    assert est["distance_m"]["status"] != "constrained"
    # the stored measurement carries the same estimate; the listing too
    assert client.get(f"/v1/measurements/{body['id']}").json()["estimate"] == est
    listed = client.get("/v1/measurements", params={"plate_id": "sim"}).json()["items"]
    assert listed[0]["estimate"] == est


def test_invert_route_matches_the_measurement_estimate(client: TestClient) -> None:
    """/v1/invert on the aggregate a measurement reported gives the same thickness estimate."""
    body = client.post("/v1/measurements", json={"shots": simulated_shots(4.0e-3)}).json()
    (agg,) = body["aggregates"]
    inputs = [{"diameter_m": agg["sphere_diameter"], "tof_s": agg["tof_s"]["mean"],
               "tof_std_s": agg["tof_s"]["std"], "arr": agg["arr"]["mean"],
               "arr_std": agg["arr"]["std"], "n_shots": agg["tof_s"]["count"]}]
    r = client.post("/v1/invert", json={"inputs": inputs})
    assert r.status_code == 200, r.text
    assert r.json()["estimate"]["thickness_m"] == body["estimate"]["thickness_m"]
    lo, hi = r.json()["estimate"]["thickness_m"]["ci95"]
    assert lo < 4.0e-3 < hi


def test_invert_errors_name_the_field(client: TestClient) -> None:
    """A sphere size the table lacks, a bad calibration: 422 naming the field."""
    r = client.post("/v1/invert", json={"inputs": [{"diameter_m": 0.01905, "tof_s": 1e-3,
                                                    "arr": 0.2}]})
    assert r.status_code == 422 and r.json()["field"] == "inputs.diameter_m"
    assert "not a sphere size of this table" in r.json()["detail"]
    r = client.post("/v1/invert", json={"inputs": [{"diameter_m": TABLE_DIAMETER,
                                                    "tof_s": 5e-4, "arr": 0.3}],
                                        "calibration": {"arr_factor": 0}})
    assert r.status_code == 422 and r.json()["field"] == "calibration.arr_factor"


def test_measurement_without_sphere_size_says_why_no_estimate(client: TestClient) -> None:
    """No sphere diameter in the metadata: stored, features measured, estimate null with the
    reason."""
    shots = simulated_shots(3.18e-3, n_shots=1)
    del shots[0]["metadata"]["sphere_diameter"]
    body = client.post("/v1/measurements", json={"shots": shots}).json()
    assert body["estimate"] is None and "sphere_diameter" in body["estimate_reason"]


def test_invert_takes_the_per_size_calibration_file_calibrate_writes(client: TestClient,
                                                                      tmp_path: Path) -> None:
    """The JSON ``solitonde calibrate`` writes posts as it is: its per-size entry is applied (an
    ARR factor of 0.5 halves the model ARR the measurement is compared with, so doubling the
    measured ARR gives back the uncalibrated answer), a duplicate size is a 422 naming it."""
    from solitonde.instrument.inference.calibration import Calibration as FileCalibration

    body = client.post("/v1/measurements", json={"shots": simulated_shots(4.0e-3)}).json()
    (agg,) = body["aggregates"]
    inputs = [{"diameter_m": agg["sphere_diameter"], "tof_s": agg["tof_s"]["mean"],
               "tof_std_s": agg["tof_s"]["std"], "arr": agg["arr"]["mean"],
               "arr_std": agg["arr"]["std"], "n_shots": agg["tof_s"]["count"]}]
    plain = client.post("/v1/invert", json={"inputs": inputs}).json()["estimate"]
    path = FileCalibration(1.0, 0.0, {TABLE_DIAMETER: {"arr_factor": 0.5, "tof_offset_s": 0.0,
                                                        "arr_factor_std": 0.0,
                                                        "n_references": 2}},
                           {"plate": "reference"}).save(tmp_path / "cal.json")
    import json

    cal = json.loads(path.read_text())
    halved = [{**inputs[0], "arr": 0.5 * inputs[0]["arr"], "arr_std": 0.5 * inputs[0]["arr_std"]}]
    r = client.post("/v1/invert", json={"inputs": halved, "calibration": cal})
    assert r.status_code == 200, r.text
    est = r.json()["estimate"]
    assert est["thickness_m"]["median"] == pytest.approx(plain["thickness_m"]["median"],
                                                        rel=0.02)
    assert est["calibration"]["per_diameter"][0]["arr_factor"] == 0.5
    # the same size listed twice, and a bad entry: 422 naming the entry's field
    cal["per_diameter"].append(dict(cal["per_diameter"][0]))
    r = client.post("/v1/invert", json={"inputs": halved, "calibration": cal})
    assert r.status_code == 422, r.text
    assert r.json()["field"] == "calibration.per_diameter[1].diameter_m"
    cal["per_diameter"] = [{"diameter_m": TABLE_DIAMETER, "arr_factor": -1}]
    r = client.post("/v1/invert", json={"inputs": halved, "calibration": cal})
    assert r.status_code == 422 and "per_diameter" in r.json()["field"]


def test_invert_reads_a_single_shot_with_the_calibrations_rig_scatter(client: TestClient,
                                                                      table_path: Path) -> None:
    """A calibration that carries the references' per-shot scatter (``shot_*``) reads an input
    without a stated scatter with it, over REST as in Python, and says so; stated, it is kept."""
    from solitonde.instrument.inference.inversion import invert
    from solitonde.instrument.tables.table import ModelTable

    body = client.post("/v1/measurements", json={"shots": simulated_shots(4.0e-3)}).json()
    (agg,) = body["aggregates"]
    one = {"diameter_m": agg["sphere_diameter"], "tof_s": agg["tof_s"]["mean"],
           "arr": agg["arr"]["mean"]}
    cal = {"arr_factor": 1.0, "tof_offset_s": 0.0, "per_diameter": [
        {"diameter_m": TABLE_DIAMETER, "arr_factor": 1.0, "tof_offset_s": 0.0,
         "shot_tof_rel_std": 5e-4, "shot_arr_std": 0.004, "shot_scatter_dof": 8}]}
    rest = client.post("/v1/invert", json={"inputs": [one], "calibration": cal})
    assert rest.status_code == 200, rest.text
    est = rest.json()["estimate"]
    assert any("measured on the calibration's reference shots" in w for w in est["warnings"])
    local = invert(ModelTable.load(table_path), [one], cal).to_dict()
    assert est["thickness_m"] == local["thickness_m"]
    assumed = client.post("/v1/invert", json={"inputs": [one]}).json()["estimate"]
    assert not any("reference shots" in w for w in assumed["warnings"])
    stated = {**one, "tof_std_s": 1e-6, "arr_std": 0.01, "n_shots": 1}
    kept = client.post("/v1/invert", json={"inputs": [stated], "calibration": cal}).json()
    assert not any("reference shots" in w for w in kept["estimate"]["warnings"])
