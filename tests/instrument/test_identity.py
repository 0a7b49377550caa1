"""What the store keeps and serves under a name: any printable plate id, and a measurement once.

A plate id such as ``P7/A 1`` is stored and its map served (the route takes a ``/`` inside an
id, every link is percent-encoded); a blank id or one holding a control character is a 422 naming
the field. A file whose shots' samples are a stored measurement's, in order, is not stored again
under another name: the answer is 200 with the stored measurement, ``duplicate_of`` and what its
metadata says otherwise, unless the request says ``allow_duplicate``.
"""

from __future__ import annotations

from pathlib import Path
from urllib.parse import quote

import numpy as np
import pytest
from fastapi.testclient import TestClient

from solitonde.instrument.service.app import build_app
from solitonde.instrument.service.settings import Settings

ROOT = Path(__file__).resolve().parents[2]
SCAN = ROOT / "data_samples" / "scan"
DEFAULT_TABLE = ROOT / "data_samples" / "default_table.h5"


@pytest.fixture()
def client(tmp_path: Path) -> TestClient:
    settings = Settings(store_path=tmp_path / "s.sqlite", table_path=DEFAULT_TABLE)
    with TestClient(build_app(settings)) as c:
        yield c


def _upload(client: TestClient, name: str, data: bytes, **fields: str) -> object:
    return client.post("/v1/measurements", files={"file": (name, data)},
                       data={"sphere_diameter": "9.53e-3", **fields})


def test_a_plate_id_with_a_slash_and_a_space_is_stored_and_its_map_served(
        client: TestClient) -> None:
    data = (SCAN / "scan_P06_shot0.csv").read_bytes()
    r = _upload(client, "a.csv", data, plate_id="P7/A 1", position="P06", x_m="0.025",
                y_m="0.2")
    assert r.status_code == 201, r.text
    (plate,) = client.get("/v1/plates").json()["items"]
    assert plate["plate_id"] == "P7/A 1"
    assert plate["links"]["map"] == f"/v1/plates/{quote('P7/A 1', safe='')}/map"
    assert "P7%2FA%201" in plate["links"]["map"]
    for link in plate["links"].values():
        got = client.get(link)
        assert got.status_code == 200, (link, got.text)
    assert client.get(plate["links"]["map"]).json()["plate_id"] == "P7/A 1"
    assert client.get("/v1/plates/P7%2FB/map").status_code == 404


@pytest.mark.parametrize(("value", "words"), [("   ", "is blank"),
                                              ("P\x07", "control character")])
def test_a_blank_id_or_a_control_character_is_refused_naming_the_field(
        client: TestClient, value: str, words: str) -> None:
    shot = {"t0": 0.0, "dt": 1e-6, "samples": [0.0] * 64 + [1.0] * 64, "units": "N",
            "metadata": {"plate_id": value}}
    r = client.post("/v1/measurements", json={"shots": [shot]})
    assert r.status_code == 422, r.text
    assert r.json()["field"] == "shots.0.metadata.plate_id"
    assert words in r.json()["detail"]
    r = client.post("/v1/measurements", files={"file": ("x.csv", (
        SCAN / "scan_P06_shot0.csv").read_bytes())}, data={"position": value})
    assert r.status_code == 422 and r.json()["field"] == "file.shots.0.metadata.position"
    assert client.get("/v1/measurements").json()["items"] == []  # nothing was stored


def test_the_same_file_under_another_name_is_not_stored_twice(client: TestClient) -> None:
    data = (SCAN / "scan_P06_shot0.csv").read_bytes()
    first = _upload(client, "shot.csv", data, plate_id="A")
    assert first.status_code == 201, first.text
    again = _upload(client, "copy of shot.csv", data, plate_id="A")
    assert again.status_code == 200, again.text
    body = again.json()
    assert body["id"] == body["duplicate_of"] == first.json()["id"]
    assert {"shot": 0, "key": "source", "stored": "shot.csv", "sent": "copy of shot.csv"} in \
        body["metadata_differences"]
    assert len(client.get("/v1/measurements").json()["items"]) == 1
    forced = _upload(client, "shot.csv", data, plate_id="A", allow_duplicate="true")
    assert forced.status_code == 201 and forced.json()["id"] != first.json()["id"]
    assert "duplicate_of" not in forced.json()


def test_a_duplicate_json_or_raw_shot_is_answered_with_the_stored_one(
        client: TestClient) -> None:
    t = np.arange(2048) * 1e-6
    samples = (30.0 * np.exp(-((t - 3e-4) / 2e-5) ** 2)
               + 20.0 * np.exp(-((t - 8e-4) / 2.4e-5) ** 2)).tolist()
    shot = {"t0": 0.0, "dt": 1e-6, "samples": samples, "units": "N",
            "metadata": {"plate_id": "B", "sphere_diameter": 9.53e-3}}
    first = client.post("/v1/measurements", json={"shots": [shot]})
    assert first.status_code == 201, first.text
    moved = {**shot, "metadata": {**shot["metadata"], "position": "P2"}}
    again = client.post("/v1/measurements", json={"shots": [moved]})
    assert again.status_code == 200 and again.json()["duplicate_of"] == first.json()["id"]
    assert again.json()["metadata_differences"] == [
        {"shot": 0, "key": "position", "stored": None, "sent": "P2"}]
    allowed = client.post("/v1/measurements", json={"shots": [shot], "allow_duplicate": True})
    assert allowed.status_code == 201
    body = np.asarray(samples, "<f8").tobytes()
    raw = client.post("/v1/measurements/raw?dtype=float64&dt=1e-6&plate_id=B&units=N"
                      "&sphere_diameter=9.53e-3", content=body,
                      headers={"content-type": "application/octet-stream"})
    assert raw.status_code == 200 and raw.json()["duplicate_of"] == first.json()["id"]
    raw = client.post("/v1/measurements/raw?dtype=float64&dt=1e-6&plate_id=B&units=N"
                      "&sphere_diameter=9.53e-3&allow_duplicate=true", content=body,
                      headers={"content-type": "application/octet-stream"})
    assert raw.status_code == 201


def test_an_idempotent_replay_stays_a_201_replay(client: TestClient) -> None:
    data = (SCAN / "scan_P06_shot0.csv").read_bytes()
    headers = {"Idempotency-Key": "k-1"}
    first = client.post("/v1/measurements", files={"file": ("s.csv", data)},
                        data={"sphere_diameter": "9.53e-3"}, headers=headers)
    replay = client.post("/v1/measurements", files={"file": ("s.csv", data)},
                         data={"sphere_diameter": "9.53e-3"}, headers=headers)
    assert first.status_code == replay.status_code == 201
    assert replay.headers.get("Idempotent-Replayed") == "true"
    assert replay.json()["id"] == first.json()["id"]


def test_the_raw_route_takes_the_table_and_the_plate_material(client: TestClient) -> None:
    """The binary route names the table (by id) or the plate's family as the other doors do; an
    unknown table or another family is a 422 naming the field."""
    wave = (SCAN / "scan_P06_shot0.csv")
    from solitonde.signal import io as signal_io

    samples = signal_io.read(wave)[0].samples
    body = np.asarray(samples, "<f8").tobytes()
    base = "/v1/measurements/raw?dtype=float64&dt=5e-7&units=N&sphere_diameter=9.53e-3"
    headers = {"content-type": "application/octet-stream"}
    r = client.post(base + "&table=default_table", content=body, headers=headers)
    assert r.status_code == 201, r.text
    assert r.json()["table"] == "default_table"
    r = client.post(base + "&table=nope&allow_duplicate=true", content=body, headers=headers)
    assert r.status_code == 422 and r.json()["field"] == "table", r.text
    r = client.post(base + "&plate_material=al_6061&allow_duplicate=true", content=body,
                    headers=headers)
    assert r.status_code == 201, r.text
    r = client.post(base + "&plate_material=steel_structural&allow_duplicate=true",
                    content=body, headers=headers)
    assert r.status_code == 422 and r.json()["field"] == "plate_material", r.text


def test_post_takes_the_table_by_id_and_stores_a_duplicate_only_when_asked(tmp_path: Path
                                                                           ) -> None:
    """`post --table ID` sends the table's id with the file; an unknown one is refused by the
    server, naming the field (exit 1). The same file for another plate is a duplicate (exit 0,
    nothing stored) unless `--allow-duplicate`."""
    import json
    import os
    import subprocess
    import sys

    sys.path.insert(0, str(ROOT / "tests" / "support"))
    from service_support import start_uvicorn, stop_group

    proc, url = start_uvicorn(tmp_path / "s.sqlite", env={"SOLITONDE_TABLE": str(DEFAULT_TABLE)})
    try:
        def post(*args: str) -> subprocess.CompletedProcess[str]:
            return subprocess.run([sys.executable, "-m", "solitonde.instrument.cli.main", "post",
                                   str(SCAN / "scan_P06_shot0.csv"), "--server", url,
                                   "--sphere-diameter", "9.53e-3", "--json", *args],
                                  capture_output=True, text=True, timeout=120, cwd=ROOT,
                                  env={k: v for k, v in os.environ.items()
                                       if not k.startswith("SOLITONDE_")})

        run = post("--table", "default_table")
        assert run.returncode == 0, run.stdout + run.stderr
        assert json.loads(run.stdout)["state"] == "stored"
        # the same file for another plate: the service holds its shots already
        run = post("--table", "default_table", "--plate-id", "Y")
        assert run.returncode == 0 and json.loads(run.stdout)["state"] == "duplicate"
        run = post("--table", "default_table", "--plate-id", "Y", "--allow-duplicate")
        assert run.returncode == 0, run.stdout + run.stderr
        assert json.loads(run.stdout)["state"] == "stored"
        run = post("--table", "nope", "--plate-id", "X")
        assert run.returncode == 1
        out = json.loads(run.stdout)
        assert out["state"] == "refused" and "table" in out["error"]
    finally:
        stop_group(proc)
