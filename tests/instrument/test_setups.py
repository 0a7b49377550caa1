"""Instrument set-ups kept by the service: revisions, refusals that name the field, shots that
contradict their set-up, a calibration that reaches the set-up's earlier measurements (a job
any process can answer for), and ``analyze --setup FILE`` offline."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from service_support import shot_json
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app
from solitonde.instrument.inference.setups import Setup, SetupError
from solitonde.instrument.service import jobs
from solitonde.instrument.service.store import Store

ROOT = Path(__file__).resolve().parents[2]
TABLE = ROOT / "data_samples" / "default_table.h5"
SAMPLE = ROOT / "data_samples" / "waveforms" / "synthetic_D9.53_t4.83_snr40.csv"
D = 9.53e-3
RIG = {"id": "lab/rig 1", "sphere_diameters_m": [D], "table": "default_table",
       "labels": {"operator": "kim"}}
RIG_URL = "/v1/setups/lab%2Frig%201"
CALIBRATION = {"arr_factor": 0.97, "tof_offset_s": 2e-6, "per_diameter": [
    {"diameter_m": D, "arr_factor": 0.97, "tof_offset_s": 2e-6, "tof_offset_std_s": 5e-7,
     "arr_factor_std": 0.01}]}


@pytest.fixture
def client(service_client, tmp_path: Path) -> TestClient:
    return service_client(table_path=TABLE, store_path=tmp_path / "store.sqlite")


def _upload(client: TestClient, **fields: str) -> Any:
    with SAMPLE.open("rb") as f:
        return client.post("/v1/measurements", files={"file": ("s.csv", f)},
                           data={"allow_duplicate": "true", **fields})


def _job(client: TestClient, job: dict[str, Any]) -> dict[str, Any]:
    for _ in range(600):
        job = client.get(job["links"]["self"]).json()
        if job["state"] not in ("queued", "running"):
            return job
        time.sleep(0.05)
    raise AssertionError(f"job still {job['state']}")


def test_revisions_are_kept_and_a_measurement_names_the_one_it_used(client: TestClient) -> None:
    r = client.post("/v1/setups", json={**RIG, "chain": {"n_particles": 20, "sensor_index": 7,
                                                         "material": "steel_440c"}})
    assert r.status_code == 201 and r.json()["revision"] == 1
    assert r.headers["location"] == RIG_URL
    assert client.post("/v1/setups", json=RIG).status_code == 409
    first = _upload(client, setup="lab/rig 1").json()
    assert first["provenance"]["setup"] == {"id": "lab/rig 1", "revision": 1}
    assert first["shots"][0]["metadata"]["sphere_diameter"] == D  # from the set-up
    r = client.put(RIG_URL, json={**RIG, "labels": {"operator": "lee"}})
    assert r.status_code == 200 and r.json()["revision"] == 2
    listed = client.get("/v1/setups").json()["items"]
    assert [(s["id"], s["revision"]) for s in listed] == [("lab/rig 1", 2)]
    shown = client.get(RIG_URL).json()
    assert [v["revision"] for v in shown["revisions"]] == [1, 2]
    old = client.get(f"{RIG_URL}/revisions/1").json()
    assert old["labels"] == {"operator": "kim"} and old["revision"] == 1  # as it was
    assert client.get(f"{RIG_URL}/revisions/9").status_code == 404
    # still named by the measurement, which keeps its revision
    assert client.get(f"/v1/measurements/{first['id']}").json()["provenance"]["setup"][
        "revision"] == 1
    r = client.delete(RIG_URL)
    assert r.status_code == 409 and "1 measurements name" in r.json()["detail"]
    client.delete(f"/v1/measurements/{first['id']}")
    assert client.delete(RIG_URL).status_code == 204
    assert client.get(RIG_URL).status_code == 404


@pytest.mark.parametrize(("body", "field", "words"), [
    ({**RIG, "sphere_diameters_m": [9.53]}, "sphere_diameters_m[0]", "sizes are in metres"),
    ({**RIG, "table": "no-such-table"}, "table", "no table 'no-such-table'"),
    ({**RIG, "id": "   "}, "id", "not an id"),
    ({**RIG, "id": "a\tb"}, "id", "control character"),
    ({**RIG, "colour": "red"}, "colour", "unknown field"),
    ({**RIG, "sphere_diameters_m": [19.05e-3 * 3]}, "sphere_diameters_m[0]", "table"),
    ({**RIG, "chain": {"n_particles": 25}}, "chain.n_particles", "25 differs from table"),
    ({**RIG, "chain": {"material": "steel_304"}}, "chain.material", "differs from table"),
    ({**RIG, "chain": {"material": "unobtainium"}}, "chain.material", "unknown material"),
])
def test_a_bad_setup_is_refused_naming_the_field(client: TestClient, body: dict[str, Any],
                                                 field: str, words: str) -> None:
    r = client.post("/v1/setups", json=body)
    assert r.status_code == 422, r.text
    problem = r.json()
    assert problem["field"] == field and words in problem["detail"], problem
    assert client.get("/v1/setups").json()["items"] == []  # nothing stored


def test_a_shot_that_contradicts_its_setup_is_refused_naming_both(client: TestClient) -> None:
    assert client.post("/v1/setups", json=RIG).status_code == 201
    r = _upload(client, setup="lab/rig 1", sphere_diameter="0.01905")
    assert r.status_code == 422
    detail = r.json()["detail"]
    assert r.json()["field"] == "file.shots.0.metadata.sphere_diameter"
    assert "0.01905 m contradicts setup 'lab/rig 1'" in detail and "0.00953" in detail
    body = {"shots": [shot_json(seed=1)], "setup": "lab/rig 1",
            "metadata": {"table": "another_table"}}
    r = client.post("/v1/measurements", json=body)
    assert r.status_code == 422 and r.json()["field"] == "shots.0.metadata.table"
    assert "'another_table' contradicts setup 'lab/rig 1'" in r.json()["detail"]
    r = client.post("/v1/measurements", json={"shots": [shot_json(seed=1)], "setup": "nope"})
    assert r.status_code == 422 and r.json()["field"] == "setup"
    assert "no set-up 'nope' (known: lab/rig 1)" in r.json()["detail"]
    assert client.get("/v1/measurements").json()["items"] == []


def test_the_raw_route_takes_setup_table_and_a_material_by_its_properties(
        client: TestClient) -> None:
    assert client.post("/v1/setups", json=RIG).status_code == 201
    samples = json.loads(json.dumps(shot_json(seed=2)))
    body = bytes(__import__("numpy").asarray(samples["samples"], "<f8").tobytes())
    material = json.dumps({"youngs_modulus": 68.9e9, "poisson_ratio": 0.33, "density": 2700.0})
    r = client.post("/v1/measurements/raw", content=body,
                    headers={"content-type": "application/octet-stream"},
                    params={"dtype": "float64", "dt": samples["dt"], "setup": "lab/rig 1",
                            "table": "default_table", "plate_material": material})
    assert r.status_code == 201, r.text
    m = r.json()
    assert m["provenance"]["setup"]["id"] == "lab/rig 1" and m["table"] == "default_table"
    assert m["shots"][0]["metadata"]["plate_material"]["youngs_modulus"] == 68.9e9
    r = client.post("/v1/measurements/raw", content=body,
                    headers={"content-type": "application/octet-stream"},
                    params={"dtype": "float64", "dt": samples["dt"], "plate_material": "{oops"})
    assert r.status_code == 422 and r.json()["field"] == "plate_material"


def test_a_calibration_reaches_the_setups_measurements_keeping_earlier_results(
        client: TestClient, tmp_path: Path) -> None:
    assert client.post("/v1/setups", json=RIG).status_code == 201
    ids = [_upload(client, setup="lab/rig 1", position=f"A{k}").json()["id"] for k in range(3)]
    before = {i: client.get(f"/v1/measurements/{i}").json()["estimate"] for i in ids}
    r = client.put(f"{RIG_URL}/calibration", json=CALIBRATION)
    assert r.status_code == 201, r.text
    answer = r.json()
    assert answer["revision"] == 2 and answer["chain_calibration"]["arr_factor"] == 0.97
    job = _job(client, answer["job"])
    assert (job["state"], job["done"], job["total"], job["failed"]) == ("done", 3, 3, [])
    # another process (a second worker) reads the job from the store
    other = Store(tmp_path / "store.sqlite", background_checkpoint=False)
    try:
        assert jobs.get(other, job["id"])["state"] == "done"
    finally:
        other.close()
    for i in ids:
        m = client.get(f"/v1/measurements/{i}").json()
        assert m["provenance"]["setup"] == {"id": "lab/rig 1", "revision": 2}
        assert m["provenance"]["chain_calibration"]["arr_factor"] == 0.97
        assert m["estimate"]["thickness_m"] != before[i]["thickness_m"]
        assert m["earlier_results"][0]["estimate"]["thickness_m"] == before[i]["thickness_m"]
    assert client.get("/v1/jobs/not-a-job").status_code == 404


def test_a_calibration_fitted_on_stored_references(client: TestClient) -> None:
    """The sample plate (4.83 mm, far from the supports) as a reference: the fit is what
    `solitonde calibrate` finds on the same file, to the last bit."""
    assert client.post("/v1/setups", json=RIG).status_code == 201
    ref = _upload(client, setup="lab/rig 1", plate_id="REF").json()["id"]
    r = client.post(f"{RIG_URL}/calibration", json={"references": [
        {"measurement_ids": [ref], "thickness_m": 4.83e-3, "distance_m": 0.457}]})
    assert r.status_code == 201, r.text
    fitted = r.json()["chain_calibration"]["per_diameter"][0]
    result = CliRunner().invoke(build_app(), [
        "calibrate", str(SAMPLE), "--thickness", "4.83e-3", "--distance", "0.457", "--table",
        str(TABLE), "--json", "--out", str(Path(r.json()["job"]["id"] + ".json"))])
    Path(r.json()["job"]["id"] + ".json").unlink(missing_ok=True)
    assert result.exit_code == 0, result.output
    by_cli = json.loads(result.stdout[result.stdout.index("{"):])["per_diameter"][0]
    for key in ("arr_factor", "tof_offset_s", "damping_s", "tof_offset_std_s"):
        assert fitted[key] == by_cli[key], key
    r = client.post(f"{RIG_URL}/calibration", json={"references": [
        {"measurement_ids": [99999], "thickness_m": 4.83e-3, "distance_m": 0.457}]})
    assert r.status_code == 422 and r.json()["field"] == "references.0.measurement_ids.0"


def test_a_setup_file_read_offline(tmp_path: Path) -> None:
    saved = tmp_path / "rig.json"
    saved.write_text(json.dumps({**RIG, "revision": 2, "created_at": 1.0,
                                 "chain_calibration": CALIBRATION, "revisions": []}))
    runner = CliRunner()
    with_setup = runner.invoke(build_app(), ["analyze", str(SAMPLE), "--setup", str(saved),
                                             "--invert", "--json"])
    assert with_setup.exit_code == 0, with_setup.output
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(CALIBRATION))
    by_file = runner.invoke(build_app(), ["analyze", str(SAMPLE), "--calibration-file", str(cal),
                                          "--table", str(TABLE), "--invert", "--json"])
    a = json.loads(with_setup.stdout)["estimates"][0]["estimate"]
    b = json.loads(by_file.stdout)["estimates"][0]["estimate"]
    assert a["thickness_m"] == b["thickness_m"] and a["distance_m"] == b["distance_m"]
    contradiction = runner.invoke(build_app(), ["analyze", str(SAMPLE), "--setup", str(saved),
                                                "--sphere-diameter", "19.05e-3", "--invert"])
    assert contradiction.exit_code == 2
    assert "--sphere-diameter: 0.01905 m contradicts --setup 'lab/rig 1'" in contradiction.output
    saved.write_text(json.dumps({**RIG, "table": "elsewhere"}))
    missing = runner.invoke(build_app(), ["analyze", str(SAMPLE), "--setup", str(saved),
                                          "--invert", "--json"])
    assert missing.exit_code == 1
    assert "names table 'elsewhere'" in missing.stdout + missing.output


def test_a_setup_record_checks_its_fields() -> None:
    with pytest.raises(SetupError, match=r"sphere_diameters_m\[1\]: .* listed twice"):
        Setup.from_dict({**RIG, "sphere_diameters_m": [D, D * 1.001]})
    with pytest.raises(SetupError, match="revision: is set by the service"):
        Setup.from_dict({**RIG, "revision": 3}, inputs_only=True)
    with pytest.raises(SetupError, match=r"chain_calibration\.arr_factor"):
        Setup.from_dict({**RIG, "chain_calibration": {"arr_factor": -1}})
    two = Setup.from_dict({**RIG, "sphere_diameters_m": [D, 19.05e-3]})
    with pytest.raises(SetupError, match="mounts several sizes"):
        two.apply([{}], lambda i, k: k)
    assert two.apply([{"sphere_diameter": 19.05e-3}], lambda i, k: k)[0]["table"] == \
        "default_table"


def test_a_change_based_on_an_older_revision_is_refused(client: TestClient) -> None:
    """Two changes sent at once: the second, based on a revision that is no longer the
    newest, is a 409 and writes nothing (a calibration never drops a revision, nor the
    reverse)."""
    from solitonde.instrument.service import setup_book
    from solitonde.instrument.service.store import SetupConflict

    assert client.post("/v1/setups", json=RIG).status_code == 201
    store = client.app.state.service.store
    first = Setup.from_dict(RIG)
    setup_book.add_revision(store, first, based_on=1)  # another client's change: revision 2
    with pytest.raises(SetupConflict, match="has revision 2 now; this change was based on "
                                            "revision 1"):
        setup_book.add_revision(store, first, based_on=1)
    with pytest.raises(SetupConflict, match="exists"):
        setup_book.add_revision(store, first, based_on=0)
    assert [v["revision"] for v in client.get(RIG_URL).json()["revisions"]] == [1, 2]


def test_ids_a_route_would_read_and_stale_writes_are_refused(client: TestClient,
                                                             tmp_path: Path) -> None:
    for bad in ("lab/calibration", "a/revisions/2", "calibration"):
        r = client.post("/v1/setups", json={**RIG, "id": bad})
        assert r.status_code == 422 and r.json()["field"] == "id", (bad, r.text)
    from solitonde.instrument.service.store import SetupConflict, SetupGone, ShotRecord
    from solitonde.signal import io as signal_io

    store = client.app.state.service.store
    wave = signal_io.read(SAMPLE)[0]
    shot = ShotRecord(wave.t0, wave.dt, wave.samples, "N", None, {}, {})
    with pytest.raises(SetupGone, match="no longer stored"):
        store.add([shot], {}, "test", setup=("nobody", 1))
    assert client.get("/v1/measurements").json()["items"] == []
    assert client.post("/v1/setups", json=RIG).status_code == 201
    client.put(RIG_URL, json=RIG)  # revision 2
    new_id, _ = store.add([shot], {"n": 2}, "test", setup=("lab/rig 1", 2))
    with pytest.raises(SetupConflict, match="newer than 1"):
        store.replace_result(new_id, {"n": 1}, [{}], setup=("lab/rig 1", 1))
    assert store.get(new_id).result == {"n": 2} and store.earlier_results(new_id) == []


def test_a_setup_without_calibration_keeps_a_files_calibration() -> None:
    """Offline (a report from recordings), a set-up without a chain calibration and a
    calibration file: the file's is applied, and the provenance names it."""
    from solitonde.instrument.inference.calibration import Calibration
    from solitonde.instrument.inference.table_set import TableSet
    from solitonde.instrument.service.ingest import apply_setup, compute_result
    from solitonde.signal import io as signal_io

    tables = TableSet([TABLE], warm_up=False)
    setup = Setup.from_dict(RIG)
    waves = apply_setup(signal_io.read(SAMPLE), setup, "shots")
    cal = Calibration.from_any(CALIBRATION)
    _, with_file = compute_result(waves, tables, "shots", setup=setup, calibration=cal)
    _, without = compute_result(waves, tables, "shots", setup=setup)
    assert with_file["provenance"]["chain_calibration"]["arr_factor"] == 0.97
    assert without["provenance"]["chain_calibration"] is None
    assert with_file["estimate"]["thickness_m"] != without["estimate"]["thickness_m"]
