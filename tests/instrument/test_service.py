"""The instrument service in-process (TestClient): measure, read back, plot, export, errors."""

from __future__ import annotations

import io
import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from fastapi.testclient import TestClient
from service_support import (
    DT,
    INCIDENT_N,
    INCIDENT_S,
    REFLECTED_N,
    REFLECTED_S,
    shot_json,
    shot_samples,
)

from solitonde.instrument.service.app import build_app
from solitonde.instrument.service.settings import Settings

PROBLEM = "application/problem+json"


def make_client(tmp_path: Path, **settings: object) -> TestClient:
    return TestClient(build_app(Settings(store_path=tmp_path / "store.sqlite", **settings)))


@pytest.fixture
def client(service_client) -> TestClient:
    return service_client(max_samples_per_shot=50_000, max_shots_per_request=8)


def stored(client: TestClient) -> int:
    return client.app.state.service.store.count()


def test_health_and_readiness_report_missing_table(client: TestClient) -> None:
    """healthz answers; readyz is ready (store works) and says estimates are off without a table."""
    assert client.get("/healthz").json()["status"] == "ok"
    ready = client.get("/readyz").json()
    assert ready["ready"] is True
    assert ready["table_loaded"] is False and ready["estimates"] is False
    assert "table" in ready["reason"]
    table = client.get("/v1/table").json()
    assert table["loaded"] is False
    assert table["limits"]["max_samples_per_shot"] == 50_000


def test_post_measurement_measures_stores_and_reads_back(client: TestClient) -> None:
    """Three shots: features match the synthetic truth, aggregate counts 3, stored bit for bit."""
    shots = [shot_json(seed=s, shot=s) for s in range(3)]
    r = client.post("/v1/measurements", json={"shots": shots})
    assert r.status_code == 201, r.text
    body = r.json()
    assert r.headers["location"] == f"/v1/measurements/{body['id']}"
    assert body["n_shots"] == 3 and body["plate_id"] == "P1" and body["position"] == "A1"
    for s in body["shots"]:
        f = s["features"]
        # 40 dB SNR, 12 bits: TOF within one sample period, ARR within 2 % (the signal issue's bar).
        assert abs(f["tof_s"] - (REFLECTED_S - INCIDENT_S)) < DT
        assert abs(f["arr"] - REFLECTED_N / INCIDENT_N) < 0.02 * REFLECTED_N / INCIDENT_N
    (agg,) = body["aggregates"]
    assert agg["sphere_diameter"] == pytest.approx(9.53e-3)
    assert agg["tof_s"]["count"] == 3
    assert body["estimate"] is None and "table" in body["estimate_reason"]

    got = client.get(f"/v1/measurements/{body['id']}").json()
    assert got["shots"] == body["shots"] and got["aggregates"] == body["aggregates"]
    for k, sent in enumerate(shots):
        back = client.get(f"/v1/measurements/{body['id']}/shots/{k}").json()
        assert back["samples"] == sent["samples"]  # exact: the store is lossless
        assert back["dt"] == DT and back["metadata"]["shot"] == k
    assert stored(client) == 1


def test_plot_png(client: TestClient) -> None:
    """The plot is a PNG of reasonable size; a missing shot or measurement is a 404 problem."""
    mid = client.post("/v1/measurements", json={"shots": [shot_json()]}).json()["id"]
    r = client.get(f"/v1/measurements/{mid}/plot.png")
    assert r.status_code == 200 and r.headers["content-type"] == "image/png"
    assert r.content[:8] == b"\x89PNG\r\n\x1a\n" and len(r.content) > 10_000
    for url, field in [(f"/v1/measurements/{mid}/plot.png?shot=5", "shot"),
                       ("/v1/measurements/999/plot.png", "id"),
                       ("/v1/measurements/999", "id")]:
        r = client.get(url)
        assert r.status_code == 404 and r.headers["content-type"] == PROBLEM
        assert r.json()["field"] == field


def test_listing_pages_and_filters(client: TestClient) -> None:
    """Paging follows 'next' through every measurement of a plate and only that plate."""
    ids = {}
    for i in range(5):
        plate = "PA" if i % 2 == 0 else "PB"
        r = client.post("/v1/measurements", json={"shots": [shot_json(seed=i, plate_id=plate)]})
        ids[r.json()["id"]] = plate
    seen = []
    url = "/v1/measurements?plate_id=PA&limit=2"
    while url:
        page = client.get(url).json()
        assert len(page["items"]) <= 2
        seen += [item["id"] for item in page["items"]]
        url = page["next"]
    assert seen == sorted(k for k, v in ids.items() if v == "PA")
    assert len(client.get("/v1/measurements?limit=500").json()["items"]) == 5


def test_export_csv_and_parquet(client: TestClient) -> None:
    """One row per shot with the features as columns, in both formats, filtered by plate."""
    client.post("/v1/measurements", json={"shots": [shot_json(seed=1), shot_json(seed=2)]})
    client.post("/v1/measurements", json={"shots": [shot_json(seed=3, plate_id="other")]})
    r = client.get("/v1/measurements/export?format=csv&plate_id=P1")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
    frame = pd.read_csv(io.StringIO(r.text))
    assert len(frame) == 2 and set(frame["plate_id"]) == {"P1"}
    assert np.allclose(frame["tof_s"], REFLECTED_S - INCIDENT_S, atol=DT)
    r = client.get("/v1/measurements/export?format=parquet")
    frame = pd.read_parquet(io.BytesIO(r.content))
    assert len(frame) == 3 and {"tof_s", "arr", "snr_db", "flags"} <= set(frame.columns)
    assert client.get("/v1/measurements/export?format=xlsx").status_code == 422
    # an export that matches nothing still has the columns (it was an empty file)
    full = list(pd.read_csv(io.StringIO(client.get("/v1/measurements/export").text)).columns)
    r = client.get("/v1/measurements/export?format=csv&plate_id=nobody")
    assert r.status_code == 200 and r.text.splitlines()[0].split(",") == full
    r = client.get("/v1/measurements/export?format=parquet&plate_id=nobody")
    assert list(pd.read_parquet(io.BytesIO(r.content)).columns) == full


def test_export_above_its_row_limit_is_refused_not_cut(tmp_path: Path) -> None:
    """Three shots against a limit of two: 422 naming the limit (it was a 200 with two rows);
    one plate's two shots still export."""
    with make_client(tmp_path, export_rows_max=2) as client:
        client.post("/v1/measurements", json={"shots": [shot_json(seed=1), shot_json(seed=2)]})
        client.post("/v1/measurements", json={"shots": [shot_json(seed=3, plate_id="other")]})
        r = client.get("/v1/measurements/export?format=csv")
        assert r.status_code == 422 and r.headers["content-type"] == PROBLEM
        assert r.json()["field"] == "plate_id" and "2" in r.json()["detail"]
        r = client.get("/v1/measurements/export?format=csv&plate_id=P1")
        assert r.status_code == 200 and len(pd.read_csv(io.StringIO(r.text))) == 2


def _raw(client: TestClient, body: bytes | str, ctype: str | None = "application/json",
         url: str = "/v1/measurements"):
    headers = {"content-type": ctype} if ctype else {}
    return client.post(url, content=body, headers=headers)


def _body(**shot_changes: object) -> str:
    shot = shot_json()
    shot.update(shot_changes)
    return json.dumps({"shots": [shot]})


def _with_nan() -> str:
    shot = shot_json()
    shot["samples"][100] = math.nan
    return json.dumps({"shots": [shot]})  # Python writes the non-standard literal NaN


def _with_huge() -> str:
    shot = shot_json()
    shot["samples"][100] = 1e305  # finite, but its running sums overflowed the kernel (crash)
    return json.dumps({"shots": [shot]})


def _with_meta(**meta: object) -> str:
    shot = shot_json()
    shot["metadata"].update(meta)
    return json.dumps({"shots": [shot]})


BAD_INPUTS = [
    # (case, body, content type, status, field)
    ("nan sample", _with_nan(), "application/json", 422, "shots.0.samples.100"),
    ("huge sample", _with_huge(), "application/json", 422, "shots.0.samples"),
    ("infinite dt", _body().replace('"dt": 5e-07', '"dt": Infinity'), "application/json", 422,
     "shots.0.dt"),
    ("empty samples", _body(samples=[]), "application/json", 422, "shots.0.samples"),
    ("too few samples", _body(samples=[0.0] * 10), "application/json", 422, "shots.0.samples"),
    ("too many samples", _body(samples=[0.0] * 50_001), "application/json", 422,
     "shots.0.samples"),
    ("no shots", json.dumps({"shots": []}), "application/json", 422, "shots"),
    ("too many shots", json.dumps({"shots": [shot_json(n=64)] * 9}), "application/json", 422,
     "shots"),
    ("empty body", "", "application/json", 422, "body"),
    ("empty object", "{}", "application/json", 422, "shots"),
    ("not json", "{shots: [", "application/json", 422, "body"),
    ("unknown top-level field", json.dumps({"shots": [shot_json()], "plate": "x"}),
     "application/json", 422, "plate"),
    ("unknown shot field", _body(gain=2.0), "application/json", 422, "shots.0.gain"),
    ("unknown metadata field", _with_meta(operator="bob"), "application/json", 422,
     "shots.0.metadata.operator"),
    ("negative dt", _body(dt=-5e-7), "application/json", 422, "shots.0.dt"),
    ("zero dt", _body(dt=0), "application/json", 422, "shots.0.dt"),
    ("dt as boolean", _body(dt=True), "application/json", 422, "shots.0.dt"),
    ("samples as text", _body(samples="1,2,3"), "application/json", 422, "shots.0.samples"),
    ("unknown units", _body(units="mV"), "application/json", 422, "shots.0.units"),
    ("volts without calibration", _body(units="V"), "application/json", 422,
     "shots.0.calibration"),
    ("zero calibration", _body(calibration=0.0), "application/json", 422,
     "shots.0.calibration"),
    ("negative sphere diameter", _with_meta(sphere_diameter=-0.01), "application/json", 422,
     "shots.0.metadata.sphere_diameter"),
    # metadata.extra may not stand in for a validated field (it bypassed the checks)
    ("extra sphere diameter as text", _with_meta(extra={"sphere_diameter": "abc"}),
     "application/json", 422, "shots.0.metadata.extra.sphere_diameter"),
    ("extra negative sphere diameter", _with_meta(extra={"sphere_diameter": -5.0}),
     "application/json", 422, "shots.0.metadata.extra.sphere_diameter"),
    ("extra null plate_id", _with_meta(extra={"plate_id": None}), "application/json", 422,
     "shots.0.metadata.extra.plate_id"),
    ("extra shot", _with_meta(extra={"shot": "x"}), "application/json", 422,
     "shots.0.metadata.extra.shot"),
    ("extra source", _with_meta(extra={"source": "x.h5"}), "application/json", 422,
     "shots.0.metadata.extra.source"),
    ("top-level extra position",
     json.dumps({"shots": [shot_json()], "metadata": {"extra": {"position": "B7"}}}),
     "application/json", 422, "metadata.extra.position"),
    ("noise only, no pulse", _body(samples=np.random.default_rng(0).normal(0, 1, 4000).tolist()),
     "application/json", 422, "shots.0.samples"),
    ("two positions in one request",
     json.dumps({"shots": [shot_json(), shot_json(position="B7")]}), "application/json", 422,
     "shots.1.metadata.position"),
    ("text/plain", _body(), "text/plain", 415, "content-type"),
    ("xml", "<shots/>", "application/xml", 415, "content-type"),
    ("form-urlencoded", "shots=1", "application/x-www-form-urlencoded", 415, "content-type"),
    ("no content type", _body(), None, 415, "content-type"),
]


@pytest.mark.parametrize(("case", "body", "ctype", "status", "field"), BAD_INPUTS,
                         ids=[c[0] for c in BAD_INPUTS])
def test_bad_input_gets_a_problem_and_stores_nothing(client: TestClient, case: str, body: str,
                                                     ctype: str | None, status: int,
                                                     field: str) -> None:
    """Each bad input: its 4xx, problem+json naming the field, a readable detail, store empty."""
    r = _raw(client, body, ctype)
    assert r.status_code == status, r.text
    assert r.headers["content-type"] == PROBLEM
    problem = r.json()
    assert problem["status"] == status and problem["field"] == field
    assert problem["detail"].startswith(field) and len(problem["detail"]) > len(field) + 5
    assert problem["type"].startswith("urn:solitonde:problem:")
    assert stored(client) == 0


def test_hundred_million_samples_rejected_before_reading(tmp_path: Path) -> None:
    """10^8 samples: the declared body size (>= 100 MB in any encoding) is refused with 413
    before a byte of it is read; the streamed case (no Content-Length) is cut off at the limit."""
    with make_client(tmp_path, max_body_bytes=1_000_000) as client:
        claimed = str(10**8 * 8)
        r = client.post("/v1/measurements", content=b"{}", headers={
            "content-type": "application/json", "content-length": claimed})
        assert r.status_code == 413 and r.json()["field"] == "body"
        assert "at most 1,000,000 bytes" in r.json()["detail"]

        def stream():
            yield b'{"shots": [{"dt": 5e-7, "samples": [0'
            for _ in range(100):  # 10^6 more samples, in chunks, with no declared length
                yield b",0" * 10_000
            yield b"]}]}"

        r = client.post("/v1/measurements", content=stream(),
                        headers={"content-type": "application/json"})
        assert r.status_code == 413 and r.headers["content-type"] == PROBLEM
        assert client.app.state.service.store.count() == 0


def test_compressed_upload_declaring_1e8_samples_is_refused(tmp_path: Path) -> None:
    """A 100 kB NPZ that inflates to 10^8 samples is sized from its header and refused (413)."""
    buf = io.BytesIO()
    np.savez_compressed(buf, samples=np.zeros(10**8, dtype=np.int8))
    assert buf.tell() < 1_000_000
    with make_client(tmp_path) as client:
        r = client.post("/v1/measurements", files={"file": ("shots.npz", buf.getvalue())},
                        data={"plate_id": "P1"})
        assert r.status_code == 413, r.text
        assert r.json()["field"] == "file" and "100,000,000" in r.json()["detail"]
        assert client.app.state.service.store.count() == 0


def test_extra_keeps_free_keys_and_names_the_field_to_use(client: TestClient) -> None:
    """Free-form extra keys are stored as given; a field's own name in extra is refused with a
    detail that says where it belongs, and the stored measurement is unchanged."""
    shot = shot_json()
    shot["metadata"]["extra"] = {"operator": "bob", "gain_db": 20, "note": None}
    r = client.post("/v1/measurements", json={"shots": [shot]})
    assert r.status_code == 201, r.text
    meta = r.json()["shots"][0]["metadata"]
    assert meta["operator"] == "bob" and meta["gain_db"] == 20 and meta["note"] is None
    assert meta["sphere_diameter"] == 9.53e-3 and meta["plate_id"] == "P1"
    shot["metadata"]["extra"] = {"operator": "bob", "sphere_diameter": -5.0}
    r = client.post("/v1/measurements", json={"shots": [shot]})
    assert r.status_code == 422
    assert "must be given as the field shots.0.metadata.sphere_diameter" in r.json()["detail"]
    assert stored(client) == 1
    (item,) = client.get("/v1/measurements").json()["items"]
    assert item["plate_id"] == "P1" and item["aggregates"][0]["sphere_diameter"] == 9.53e-3


@pytest.mark.parametrize("value", ["abc", -5.0, 2.0, True])
def test_upload_file_metadata_sphere_diameter_is_checked(client: TestClient, tmp_path: Path,
                                                         value: object) -> None:
    """A file's own sphere_diameter attribute is metadata like a JSON shot's and gets the same
    check (text was a 500, a negative one was stored); a form field overrides it."""
    import h5py

    path = tmp_path / "shot.h5"
    with h5py.File(path, "w") as fh:
        ds = fh.create_dataset("shot", data=shot_samples(0))
        ds.attrs["dt"] = DT
        ds.attrs["sphere_diameter"] = value
    r = client.post("/v1/measurements", files={"file": ("shot.h5", path.read_bytes())})
    assert r.status_code == 422, r.text
    assert r.json()["field"] == "file.shots.0.metadata.sphere_diameter"
    assert stored(client) == 0
    r = client.post("/v1/measurements", files={"file": ("shot.h5", path.read_bytes())},
                    data={"sphere_diameter": "0.00953"})
    assert r.status_code == 201, r.text
    assert r.json()["shots"][0]["metadata"]["sphere_diameter"] == 0.00953


def _many_hdf5_datasets(path: Path, count: int, n: int) -> None:
    import h5py

    with h5py.File(path, "w") as fh:
        for i in range(count):
            ds = fh.create_dataset(f"s{i}", data=np.zeros(n), compression="gzip")
            ds.attrs["dt"] = DT


def _hdf5_array_elements(path: Path, count: int, n: int) -> None:
    import h5py

    with h5py.File(path, "w") as fh:  # `count` elements, each itself n float64 values
        ds = fh.create_dataset("s", shape=(count,), dtype=np.dtype((np.float64, (n,))),
                               compression="gzip")
        ds.attrs["dt"] = DT


def _npz_long_metadata(path: Path, count: int, n: int) -> None:
    text = "x" * (2 * count * n)  # 4-byte characters: count * n values of 8 bytes
    np.savez_compressed(path, samples=np.zeros(n), dt=np.float64(DT), metadata=np.str_(text))


def _many_tdms_channels(path: Path, count: int, n: int) -> None:
    from nptdms import ChannelObject, TdmsWriter

    with TdmsWriter(str(path)) as writer:
        writer.write_segment([ChannelObject("shots", f"c{i}", np.zeros(n), properties={
            "wf_increment": DT, "wf_start_offset": 0.0}) for i in range(count)])


SIZE_BOMBS = [("hdf5 datasets", "bomb.h5", _many_hdf5_datasets),
              ("hdf5 array elements", "bomb.h5", _hdf5_array_elements),
              ("npz metadata string", "bomb.npz", _npz_long_metadata),
              ("tdms channels", "bomb.tdms", _many_tdms_channels)]


@pytest.mark.parametrize(("case", "name", "build"), SIZE_BOMBS, ids=[c[0] for c in SIZE_BOMBS])
def test_upload_of_many_arrays_is_sized_by_their_sum(tmp_path: Path, monkeypatch, case: str,
                                                     name: str, build) -> None:
    """Five arrays each within the per-shot limit but over the request limit together: 413 from
    the headers, the reader never runs (it decoded everything before); one array is read."""
    from solitonde.instrument.service import routes_measurements

    calls: list[str] = []
    real = routes_measurements.read_file

    def spy(path, fmt, options, client_name=None):
        calls.append(fmt)
        return real(path, fmt, options, client_name)

    monkeypatch.setattr(routes_measurements, "read_file", spy)
    n = 100_000
    bomb, single = tmp_path / name, tmp_path / f"single-{name}"
    build(bomb, 5, n)
    build(single, 1, n)
    with make_client(tmp_path, max_samples_per_shot=n, max_samples_per_request=3 * n) as client:
        r = client.post("/v1/measurements", files={"file": (name, bomb.read_bytes())})
        assert r.status_code == 413, r.text
        problem = r.json()
        assert problem["field"] == "file" and "at most 300,000 per request" in problem["detail"]
        assert calls == [] and stored(client) == 0
        r = client.post("/v1/measurements", files={"file": (name, single.read_bytes())})
        assert r.status_code != 413 and len(calls) == 1, r.text  # zeros: no pulse, a 422
        assert stored(client) == 0


def test_hdf5_upload_with_dataset_is_sized_by_that_dataset(tmp_path: Path) -> None:
    """``dataset=`` reads one dataset of a file: the size check counts that one (it counted the
    whole file and refused a small selection from a large file with 413); a file holding more than
    the request limit is still refused without ``dataset=``, and a selection over it too."""
    n = 100_000
    path = tmp_path / "many.h5"
    _many_hdf5_datasets(path, 5, n)
    with make_client(tmp_path, max_samples_per_shot=n, max_samples_per_request=3 * n) as client:
        body = path.read_bytes()
        r = client.post("/v1/measurements", files={"file": ("many.h5", body)})
        assert r.status_code == 413, r.text
        r = client.post("/v1/measurements", files={"file": ("many.h5", body)},
                        data={"dataset": "s3"})
        assert r.status_code == 422 and "no pulse" in r.text, r.text  # zeros: read, no pulse
        r = client.post("/v1/measurements", files={"file": ("many.h5", body)},
                        data={"dataset": "nope"})
        assert r.status_code == 422 and r.json()["field"] == "file.dataset", r.text
        assert "no 'nope' in many.h5" in r.json()["detail"]  # the client's name, not the server's
        assert stored(client) == 0


def test_upload_problems_name_the_field(client: TestClient) -> None:
    """Uploads: missing file, unknown format, unknown form field, garbage content: 422, no store."""
    cases = [
        ({"data": {"plate_id": "P1"}, "files": {"other": ("x.csv", b"1,2")}}, "file"),
        ({"files": {"file": ("shot.xyz", b"123")}}, "format"),
        ({"files": {"file": ("shot.csv", b"123")}, "data": {"format": "wav"}}, "format"),
        ({"files": {"file": ("shot.csv", b"1\n2\n")}, "data": {"colour": "red"}}, "colour"),
        ({"files": {"file": ("shot.npy", b"not an npy file")}}, "file"),
        ({"files": {"file": ("shot.h5", b"\x89HDF garbage")}}, "file"),
    ]
    for kwargs, field in cases:
        r = client.post("/v1/measurements", **kwargs)
        assert r.status_code == 422, (field, r.text)
        assert r.json()["field"].startswith(field), r.json()
    assert stored(client) == 0


def test_api_key_guards_writes_and_stored_data(tmp_path: Path) -> None:
    """With a key set: no key or a wrong key is a 401 (nothing stored); header or bearer works;
    health and docs stay open."""
    key = "s3cret-key-0123456789"
    with make_client(tmp_path, api_key=key) as client:
        body = {"shots": [shot_json()]}
        r = client.post("/v1/measurements", json=body)
        assert r.status_code == 401 and r.json()["field"] == "api_key"
        assert r.headers["www-authenticate"].startswith("Bearer")
        r = client.post("/v1/measurements", json=body, headers={"X-API-Key": "wrong"})
        assert r.status_code == 401
        assert client.app.state.service.store.count() == 0
        for url in ["/v1/measurements", "/v1/measurements/1", "/v1/measurements/1/plot.png",
                    "/v1/plates", "/v1/plates/P1/map", "/v1/tables",
                    "/v1/measurements/export", "/v1/measurements/1/shots/0", "/v1/table"]:
            assert client.get(url).status_code == 401, url
        r = client.post("/v1/measurements", json=body, headers={"X-API-Key": key})
        assert r.status_code == 201
        mid = r.json()["id"]
        r = client.get(f"/v1/measurements/{mid}",
                       headers={"Authorization": f"Bearer {key}"})
        assert r.status_code == 200 and r.json()["id"] == mid
        assert client.get("/healthz").status_code == 200
        assert client.get("/readyz").status_code == 200
        assert client.get("/docs").status_code == 200


def test_invert_without_table_is_503_and_validates_first(client: TestClient) -> None:
    """No table: a valid request gets 503 naming the table; an invalid one its 422."""
    good = {"inputs": [{"diameter_m": 9.53e-3, "tof_s": 5e-4, "arr": 0.6}]}
    r = client.post("/v1/invert", json=good)
    assert r.status_code == 503 and r.json()["field"] == "table"
    r = client.post("/v1/invert", json={"inputs": [{"diameter_m": 9.53e-3, "tof_s": -1,
                                                    "arr": 0.6}]})
    assert r.status_code == 422 and r.json()["field"] == "inputs.0.tof_s"
    r = _raw(client, json.dumps(good), "text/plain", "/v1/invert")
    assert r.status_code == 415


def test_simulate_runs_and_prices_scenes(client: TestClient) -> None:
    """A small scene runs and is measured like a recorded shot; an expensive one is refused
    with a 422 that states its cost; a bad scene field is named."""
    scene = {"chain": {"n_particles": 20}, "plate": {"thickness": 3.18e-3}}
    r = client.post("/v1/simulate", json={"scene": scene})
    assert r.status_code == 200, r.text
    out = r.json()
    assert out["n_samples"] == len(out["samples"]) > 100
    truth = out["diagnostics"]["truth"]
    assert out["features"]["tof_s"] == pytest.approx(truth["tof_s"], abs=2 * out["dt"])
    assert out["cost"]["cost"] <= client.app.state.settings.max_simulation_cost

    big = {"chain": {"n_particles": 100_000}, "output": {"duration": 1.0}}
    r = client.post("/v1/simulate", json={"scene": big})
    assert r.status_code == 422 and r.json()["field"] == "scene"
    assert "too expensive" in r.json()["detail"]

    r = client.post("/v1/simulate", json={"scene": {"chain": {"diameter": -1}}})
    assert r.status_code == 422 and r.json()["field"] == "scene.chain.diameter"
    r = client.post("/v1/simulate", json={"scene": {}, "trace": True})
    assert r.status_code == 422 and r.json()["field"] == "trace"


def test_openapi_states_the_limits(tmp_path: Path) -> None:
    """The schema carries the configured limits (maxItems), the JSON and multipart bodies of
    /v1/measurements, and the binary body with its query parameters at /v1/measurements/raw."""
    with make_client(tmp_path, max_samples_per_shot=12_345, max_shots_per_request=7) as client:
        schema = client.get("/openapi.json").json()
    shots = schema["components"]["schemas"]["MeasurementIn"]["properties"]["shots"]
    assert shots["maxItems"] == 7
    shot = schema["components"]["schemas"]["ShotIn"]["properties"]["samples"]
    assert shot["maxItems"] == 12_345
    content = schema["paths"]["/v1/measurements"]["post"]["requestBody"]["content"]
    assert set(content) == {"application/json", "multipart/form-data"}
    assert [p["name"] for p in schema["paths"]["/v1/measurements"]["post"]["parameters"]] == [
        "Idempotency-Key"]  # no query parameters: a JSON or multipart body must not send any
    raw = schema["paths"]["/v1/measurements/raw"]["post"]
    assert set(raw["requestBody"]["content"]) == {"application/octet-stream"}
    params = {p["name"]: p for p in raw["parameters"]}
    assert params["dt"]["required"] and params["dtype"]["required"]
    assert not params["t0"]["required"]
    assert params["dtype"]["schema"]["enum"] == ["float32", "float64"]
    assert "12,345 samples per shot" in schema["info"]["description"]


def test_shots_are_float32_when_exact_else_float64(client: TestClient) -> None:
    """Lossless either way: 12-bit ADC steps fit float32; full float64 noise is kept as float64."""
    from solitonde.instrument.service.store import decode_samples, encode_samples

    adc = np.round(shot_samples(1) * 64) / 64
    wide = shot_samples(1) + 1e-9 * np.random.default_rng(1).normal(size=4000)
    for x, dtype in [(adc, "<f4"), (wide, "<f8")]:
        kind, digest, blob = encode_samples(x)
        assert kind == dtype
        back = decode_samples(kind, blob, x.size, digest)
        assert np.array_equal(back, x)


@pytest.mark.parametrize("fmt", ["csv", "npy", "npz", "hdf5", "tdms", "json"])
def test_upload_each_format(client: TestClient, tmp_path: Path, fmt: str) -> None:
    """A two-shot file in each format, written by the signal writers, measures like JSON."""
    from solitonde.signal import io as signal_io
    from solitonde.signal.waveform import Waveform

    suffix = {"hdf5": ".h5"}.get(fmt, f".{fmt}")
    path = tmp_path / f"two shots{suffix}"
    waves = [Waveform(0.0, DT, shot_samples(seed), metadata={"shot": seed}) for seed in (4, 5)]
    signal_io.write(path, waves, format=fmt)
    r = client.post("/v1/measurements", files={"file": (path.name, path.read_bytes())},
                    data={"plate_id": "P9", "position": "C3", "sphere_diameter": "0.00953"})
    assert r.status_code == 201, r.text
    body = r.json()
    assert body["source"] == f"upload:{fmt}" and body["n_shots"] == 2
    assert body["plate_id"] == "P9" and body["position"] == "C3"
    for s in body["shots"]:
        assert abs(s["features"]["tof_s"] - (REFLECTED_S - INCIDENT_S)) < DT
    back = client.get(f"/v1/measurements/{body['id']}/shots/1").json()
    # binary formats are exact; CSV keeps what its writer prints (%.9g: 5e-9 relative)
    rtol = 1e-8 if fmt == "csv" else 0.0
    assert np.allclose(back["samples"], waves[1].samples, rtol=rtol, atol=0.0)
    # the server wrote the upload under its own name in its private folder, and removed it
    upload_dir = client.app.state.service.uploads.path
    assert upload_dir.stat().st_mode & 0o777 == 0o700
    assert list(upload_dir.iterdir()) == []


def test_plot_of_a_volt_shot_draws_the_force(client: TestClient) -> None:
    """A shot in volts with a calibration is stored in volts, measured and plotted in newtons:
    its features equal those of the same shot sent in newtons."""
    in_newtons = client.post("/v1/measurements", json={"shots": [shot_json()]}).json()
    shot = shot_json()
    shot["samples"] = (np.asarray(shot["samples"]) / 25.0).tolist()
    shot.update(units="V", calibration=25.0)
    r = client.post("/v1/measurements", json={"shots": [shot]})
    assert r.status_code == 201, r.text
    f, f_n = r.json()["shots"][0]["features"], in_newtons["shots"][0]["features"]
    for key in ("incident_peak_N", "reflected_peak_N", "tof_s", "arr"):
        assert f[key] == pytest.approx(f_n[key], rel=1e-9), key
    back = client.get(f"/v1/measurements/{r.json()['id']}/shots/0").json()
    assert back["units"] == "V" and back["calibration"] == 25.0
    assert back["samples"] == shot["samples"]
    png = client.get(f"/v1/measurements/{r.json()['id']}/plot.png")
    assert png.status_code == 200 and png.content.startswith(b"\x89PNG")


def test_simulate_prices_plate_meshes_before_building_them(client: TestClient) -> None:
    """A spectral-element plate near the support at the default mesh is priced from its stable
    step and refused within the default budget; an absurd mesh is refused from the floor of its
    cost without building it."""
    near = {"plate": {"distance_to_support": 0.05}, "effects": {"plate_model": "sem"}}
    r = client.post("/v1/simulate", json={"scene": near})  # ~4 s of CPU
    assert r.status_code == 422 and "too expensive" in r.json()["detail"]
    short = {"plate": {"thickness": 4.83e-3}, "effects": {"plate_model": "sem"},
             "output": {"duration": 3e-4}}  # ~0.6 s of CPU: within the budget
    r = client.post("/v1/simulate", json={"scene": short})
    assert r.status_code == 200, r.text
    assert r.json()["cost"]["cost"] <= client.app.state.settings.max_simulation_cost
    huge = {"effects": {"plate_model": "sem"}, "sem": {"elements": [1024, 1024, 8]}}
    r = client.post("/v1/simulate", json={"scene": huge})
    assert r.status_code == 422 and "too expensive" in r.json()["detail"]
    dopri_sem = {"effects": {"plate_model": "sem"}, "solver": {"integrator": "dopri5"},
                 "sem": {"elements": [1024, 1024, 8]}}
    r = client.post("/v1/simulate", json={"scene": dopri_sem})
    assert r.status_code == 422 and r.json()["field"] == "scene.solver.integrator"


def test_simulate_dopri5_on_the_dashpot(client: TestClient) -> None:
    """The adaptive integrator runs through the service, priced by verlet's step count."""
    r = client.post("/v1/simulate", json={"scene": {"solver": {"integrator": "dopri5"},
                                                    "effects": {"plate_model": "infinite"}}})
    assert r.status_code == 200, r.text
    out = r.json()
    assert out["features"]["tof_s"] == pytest.approx(out["diagnostics"]["truth"]["tof_s"],
                                                     abs=2 * out["dt"])
    assert out["cost"]["estimate"].startswith("upper bound")


def test_hdf5_upload_that_points_at_server_files_is_refused(client: TestClient,
                                                          tmp_path: Path) -> None:
    """An HDF5 upload whose dataset lives in an external file (a path on the server) or that
    links to another file is refused before anything is read from it."""
    import h5py

    secret = tmp_path / "secret.bin"
    np.arange(4000, dtype="<f8").tofile(secret)
    external = tmp_path / "external.h5"
    with h5py.File(external, "w") as fh:
        d = fh.create_dataset("shot", shape=(4000,), dtype="<f8",
                              external=[(str(secret), 0, 4000 * 8)])
        d.attrs["dt"] = DT
    linked = tmp_path / "linked.h5"
    with h5py.File(linked, "w") as fh:
        fh["shot"] = h5py.ExternalLink(str(secret), "/data")
    for path, words in [(external, "external file"), (linked, "external link")]:
        r = client.post("/v1/measurements", files={"file": (path.name, path.read_bytes())})
        assert r.status_code == 422, r.text
        assert r.json()["field"] == "file" and words in r.json()["detail"]
    assert stored(client) == 0


BINARY = "application/octet-stream"
QUERY = "dtype=float32&dt=5e-7&plate_id=P1&position=A1&sphere_diameter=0.00953"


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_binary_shot_measures_like_json_and_is_stored_bit_for_bit(client: TestClient,
                                                                 dtype: str) -> None:
    """Raw little-endian samples with dt in the query: the same features as the JSON shot."""
    x = shot_samples(0).astype("<f4" if dtype == "float32" else "<f8")
    r = client.post(f"/v1/measurements?{QUERY.replace('float32', dtype)}&shot=3",
                    content=x.tobytes(), headers={"content-type": BINARY})
    assert r.status_code == 201, r.text
    out = r.json()
    assert out["source"] == "binary" and out["plate_id"] == "P1" and out["position"] == "A1"
    assert out["shots"][0]["metadata"]["shot"] == 3 and out["shots"][0]["n_samples"] == x.size
    as_json = client.post("/v1/measurements", json={"shots": [
        {**shot_json(0), "samples": x.astype(float).tolist()}]}).json()
    assert out["shots"][0]["features"] == as_json["shots"][0]["features"]
    back = client.get(f"/v1/measurements/{out['id']}/shots/0").json()
    assert np.array_equal(np.array(back["samples"]), x.astype(float))
    assert back["dt"] == DT


_F32 = shot_samples(0).astype("<f4").tobytes()
_NAN = np.r_[shot_samples(0)[:100], np.nan, shot_samples(0)[101:]].tobytes()
_HUGE = np.r_[shot_samples(0)[:100], 1e305, shot_samples(0)[101:]].tobytes()
BAD_BINARY = [
    # (case, query, body, field)
    ("no dtype", "dt=5e-7", _F32, "dtype"),
    ("unknown dtype", "dtype=int16&dt=5e-7", _F32, "dtype"),
    ("no dt", "dtype=float32", _F32, "dt"),
    ("negative dt", "dtype=float32&dt=-5e-7", _F32, "dt"),
    ("NaN dt", "dtype=float32&dt=nan", _F32, "dt"),
    ("dt twice", "dtype=float32&dt=5e-7&dt=1e-6", _F32, "dt"),
    ("unknown parameter", "dtype=float32&dt=5e-7&gain=2", _F32, "gain"),
    ("empty body", "dtype=float32&dt=5e-7", b"", "body"),
    ("partial sample", "dtype=float32&dt=5e-7", _F32[:-1], "body"),
    ("NaN sample", "dtype=float64&dt=5e-7", _NAN, "samples"),
    ("huge sample", "dtype=float64&dt=5e-7", _HUGE, "samples"),
    ("too few samples", "dtype=float32&dt=5e-7", _F32[:40], "samples"),
    ("too many samples", "dtype=float64&dt=5e-7", bytes(8 * 50_001), "samples"),
    ("volts without calibration", "dtype=float32&dt=5e-7&units=V", _F32, "calibration"),
    ("zero calibration", "dtype=float32&dt=5e-7&calibration=0", _F32, "calibration"),
    ("negative sphere diameter", "dtype=float32&dt=5e-7&sphere_diameter=-1", _F32,
     "sphere_diameter"),
    ("noise only, no pulse", "dtype=float64&dt=5e-7",
     np.random.default_rng(0).normal(0, 1, 4000).tobytes(), "samples"),
]


@pytest.mark.parametrize(("case", "query", "body", "field"), BAD_BINARY,
                         ids=[c[0] for c in BAD_BINARY])
def test_bad_binary_shot_gets_a_problem_and_stores_nothing(client: TestClient, case: str,
                                                           query: str, body: bytes,
                                                           field: str) -> None:
    """Each bad binary shot: 422 naming the query parameter or the body; the store stays empty."""
    r = client.post(f"/v1/measurements?{query}", content=body, headers={"content-type": BINARY})
    assert r.status_code == 422, r.text
    assert r.headers["content-type"] == PROBLEM
    problem = r.json()
    assert problem["field"] == field and problem["detail"].startswith(field)
    assert stored(client) == 0


def test_query_parameters_with_a_json_body_are_refused(client: TestClient) -> None:
    """Binary-shot query parameters sent with a JSON body would be silently ignored: 422 instead,
    naming the parameter, and nothing stored."""
    body = {"shots": [{"dt": 5e-7, "samples": [0.0] * 200}]}
    r = client.post("/v1/measurements?dt=1e-6", json=body)
    assert r.status_code == 422 and r.json()["field"] == "dt"
    assert stored(client) == 0
