"""Hostile and broken uploads (part of the hardening): every archive member sized from its
header, truncated TDMS refused, file metadata held to the JSON limits, spreadsheet formulas
neutralised in CSV exports, a blank or short API key refused at start, no server path shown."""

from __future__ import annotations

import io
import time
import tracemalloc
import zipfile

import numpy as np
import pandas as pd
import pytest
from fastapi.testclient import TestClient
from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter
from service_support import shot_json, shot_samples

from solitonde.instrument.service.app import build_app
from solitonde.instrument.service.settings import Settings, SettingsError


def _count(client: TestClient) -> int:
    return client.app.state.service.store.count()


def test_an_npz_member_without_the_npy_suffix_is_sized_from_its_header(client):
    """numpy reads a member named 'samples' as well as 'samples.npy': a deflated member that
    declares 10^8 float64 is refused from the zip directory, not inflated to 800 MB first."""
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False,
                                                  "shape": (10**8,)})
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        with zf.open("samples", "w", force_zip64=True) as member:
            member.write(header.getvalue())
            zeros = bytes(1 << 20)
            for _ in range(800):
                member.write(zeros)
        zf.writestr("dt", np.float64(5e-7).tobytes())
    body = buf.getvalue()
    assert len(body) < 2_000_000
    inflated = []
    real_read = zipfile.ZipExtFile.read

    def counting_read(self, n=-1):
        data = real_read(self, n)
        inflated.append(len(data))
        return data

    started = time.perf_counter()
    tracemalloc.start()
    try:
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(zipfile.ZipExtFile, "read", counting_read)
            r = client.post("/v1/measurements", files={"file": ("bomb.npz", body)})
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    print(f"\nNPZ bomb: 413 after {time.perf_counter() - started:.3f} s (traced), Python peak "
          f"{peak / 1e6:.1f} MB, {sum(inflated):,} bytes inflated")
    assert r.status_code == 413 and r.json()["field"] == "file", r.text
    assert "8,000,000" in r.json()["detail"]
    # refused from the headers: at most the .npy header of a member is inflated, never the data
    assert sum(inflated) < 64 * 1024, sum(inflated)
    assert peak < 50e6, peak  # the 2 MB body and its copies, not the 800 MB it declares
    assert _count(client) == 0


def test_a_truncated_tdms_is_refused_not_stored_in_part(client, tmp_path):
    path = tmp_path / "two.tdms"
    props = {"wf_increment": 5e-7, "wf_start_offset": 0.0, "wf_samples": 4000,
             "unit_string": "N"}
    with TdmsWriter(str(path)) as tdms:
        for k in range(2):
            tdms.write_segment([RootObject(), GroupObject("shots"),
                                ChannelObject("shots", f"shot_{k}", shot_samples(k),
                                              properties=props)])
    whole = path.read_bytes()
    assert client.post("/v1/measurements", files={"file": ("two.tdms", whole)}).status_code == 201
    r = client.post("/v1/measurements", files={"file": ("cut.tdms", whole[:-8000])})
    assert r.status_code == 422 and r.json()["field"].startswith("file")
    assert "truncated" in r.json()["detail"] and "cut.tdms" in r.json()["detail"]
    assert _count(client) == 1


def test_file_metadata_is_held_to_the_limits_json_metadata_has(client):
    rows = "".join(f"{i * 5e-7:.9g},{v:.6g}\n" for i, v in enumerate(shot_samples()))
    for header, field in ((f"# plate_id: {'P' * 1_000_000}\n", "plate_id"),
                          (f"# operator: {'x' * 5000}\n", "operator")):
        body = (header + "time_s,force_N\n" + rows).encode()
        r = client.post("/v1/measurements", files={"file": ("big.csv", body)})
        assert r.status_code == 422 and r.json()["field"].endswith(field), r.text[:300]
    shot = shot_json()
    shot["metadata"]["extra"] = {"note": "y" * 1_000_000}
    r = client.post("/v1/measurements", json={"shots": [shot]})
    assert r.status_code == 422 and "extra" in r.json()["field"]
    assert _count(client) == 0


def test_formulas_are_neutralised_in_csv_exports_and_kept_in_parquet(client):
    shot = shot_json(plate_id='=HYPERLINK("http://x","y")', position="-A1")
    assert client.post("/v1/measurements", json={"shots": [shot]}).status_code == 201
    for kind in ("shots", "estimates"):
        text = client.get(f"/v1/measurements/export?kind={kind}").text
        frame = pd.read_csv(io.StringIO(text))
        assert frame["plate_id"][0] == '\'=HYPERLINK("http://x","y")', kind
        assert frame["position"][0] == "'-A1"
        parquet = pd.read_parquet(io.BytesIO(client.get(
            f"/v1/measurements/export?kind={kind}&format=parquet").content))
        assert parquet["plate_id"][0] == '=HYPERLINK("http://x","y")'
    shots = pd.read_csv(io.StringIO(client.get("/v1/measurements/export").text))
    assert (shots["t0_s"] <= 0).all() or shots["t0_s"].dtype.kind == "f"  # numbers untouched


@pytest.mark.parametrize("key", ["", "   ", "short-key"])
def test_a_blank_or_short_api_key_is_refused_at_start(key):
    with pytest.raises(SettingsError) as err:
        Settings.from_env({"SOLITONDE_API_KEY": key})
    assert err.value.field == "api_key" and "16" in str(err.value)


def test_readiness_does_not_show_where_the_store_is(client, tmp_path):
    ready = client.get("/readyz").json()
    assert ready["store"] == "store.sqlite" and str(tmp_path) not in str(ready)


def test_serving_another_address_without_a_key_needs_insecure(tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from solitonde.instrument.cli.main import build_app as build_cli

    monkeypatch.delenv("SOLITONDE_API_KEY", raising=False)
    res = CliRunner().invoke(build_cli(), ["serve", "--host", "0.0.0.0", "--store",
                                           str(tmp_path / "s.sqlite")])
    assert res.exit_code == 2 and "--insecure" in res.stderr
    monkeypatch.setenv("SOLITONDE_API_KEY", " " * 20)
    res = CliRunner().invoke(build_cli(), ["serve", "--store", str(tmp_path / "s.sqlite")])
    assert res.exit_code == 2 and "api_key" in res.stderr


def test_a_text_shot_label_from_a_file_exports_as_text(client):
    rows = "".join(f"{i * 5e-7:.9g},{v:.6g}\n" for i, v in enumerate(shot_samples()))
    body = ("# shot: A3\n# plate_id: P\ntime_s,force_N\n" + rows).encode()
    assert client.post("/v1/measurements", files={"file": ("a.csv", body)}).status_code == 201
    frame = pd.read_csv(io.StringIO(client.get("/v1/measurements/export").text))
    assert frame["shot"][0] == "A3"


def test_a_retry_with_the_same_idempotency_key_returns_the_first_answer(client):
    """A measurement committed while the client saw a reset is not stored twice on retry: the
    same key and body give the same id; the same key with another body is a 422; for an upload
    the content counts, not the multipart boundary."""
    body = {"shots": [shot_json(seed=3)]}
    first = client.post("/v1/measurements", json=body, headers={"Idempotency-Key": "k-1"})
    again = client.post("/v1/measurements", json=body, headers={"Idempotency-Key": "k-1"})
    assert first.status_code == again.status_code == 201
    assert again.json()["id"] == first.json()["id"]
    assert again.headers["idempotent-replayed"] == "true"
    assert _count(client) == 1
    other = client.post("/v1/measurements", json={"shots": [shot_json(seed=4)]},
                        headers={"Idempotency-Key": "k-1"})
    assert other.status_code == 422 and other.json()["field"] == "Idempotency-Key"
    rows = "".join(f"{i * 5e-7:.9g},{v:.6g}\n" for i, v in enumerate(shot_samples()))
    csv_body = ("time_s,force_N\n" + rows).encode()
    ids = {client.post("/v1/measurements", files={"file": ("a.csv", csv_body)},
                       data={"plate_id": "P"}, headers={"Idempotency-Key": "up-7"}).json()["id"]
           for _ in range(2)}
    assert len(ids) == 1 and _count(client) == 2
    bad = client.post("/v1/measurements", json=body, headers={"Idempotency-Key": "x" * 300})
    assert bad.status_code == 422 and bad.json()["field"] == "Idempotency-Key"
    # deleting the measurement frees its key: a later post with it stores anew
    assert client.delete(f"/v1/measurements/{first.json()['id']}").status_code == 204
    anew = client.post("/v1/measurements", json=body, headers={"Idempotency-Key": "k-1"})
    assert anew.status_code == 201 and anew.json()["id"] != first.json()["id"]


def test_failed_key_attempts_are_logged_sparingly_and_then_refused(tmp_path, caplog):
    from solitonde.instrument.service.authentication import FAILED_KEYS, FailedKeys

    key = "k" * 20
    caplog.set_level("WARNING", logger="solitonde.instrument")
    with TestClient(build_app(Settings(store_path=tmp_path / "s.sqlite", api_key=key))) as c:
        FAILED_KEYS.__init__()  # a fresh count for this client
        codes = [c.get("/v1/measurements", headers={"X-API-Key": f"guess-{i}"}).status_code
                 for i in range(FailedKeys.LIMIT + 3)]
        assert codes[:FailedKeys.LIMIT] == [401] * FailedKeys.LIMIT
        assert codes[FailedKeys.LIMIT:] == [429] * 3
        refused = c.get("/v1/measurements", headers={"X-API-Key": key})
        assert refused.status_code == 429 and int(refused.headers["retry-after"]) > 0
        lines = [r for r in caplog.records if "failed attempt" in r.getMessage()]
        assert len(lines) == 1  # one line for the burst, with its count
        FAILED_KEYS.__init__()
        assert c.get("/v1/measurements", headers={"X-API-Key": key}).status_code == 200


def test_options_lists_every_method_a_path_takes(client):
    for path, allow in (("/v1/measurements", "GET, OPTIONS, POST"),
                        ("/v1/measurements/7", "DELETE, GET, OPTIONS"),
                        ("/v1/plates/P/map.png", "GET, OPTIONS"), ("/v1/invert", "OPTIONS, POST")):
        r = client.options(path)
        assert r.status_code == 204 and r.headers["allow"] == allow, (path, r.headers)
    assert client.options("/v1/nothing").status_code == 404


def test_a_large_upload_is_parsed_in_a_lane_of_its_own(client):
    """One large file at a time, and never in the lane ordinary uploads take."""
    from solitonde.instrument.service.state import LARGE_UPLOAD_BYTES

    svc = client.app.state.service
    assert svc.lane_for(1000) is svc.upload_lane
    assert svc.lane_for(None) is svc.upload_lane
    big = svc.lane_for(LARGE_UPLOAD_BYTES + 1)
    assert big is svc.large_upload_lane and big is not svc.upload_lane
    assert big.total_tokens == 1


def test_a_json_body_of_more_values_than_allowed_is_refused_before_parsing(client):
    """64 MiB of "0," would be 33 million Python floats (about 3 GB) if parsed: it is counted
    first and refused with 413, fast."""
    limit = client.app.state.service.settings.max_samples_per_request
    n = limit + 20_000
    body = b'{"shots": [{"dt": 5e-7, "samples": [' + b"0," * (n - 1) + b"0]}]}"
    svc = client.app.state.service
    parsed = []

    class Watching:  # the request model, recording any attempt to parse the body
        @staticmethod
        def model_validate_json(data):
            parsed.append(len(data))
            return real.model_validate_json(data)

    real, svc.measurement_model = svc.measurement_model, Watching
    try:
        r = client.post("/v1/measurements", content=body,
                        headers={"content-type": "application/json"})
    finally:
        svc.measurement_model = real
    assert r.status_code == 413 and r.json()["field"] == "body", r.text[:300]
    assert f"{limit:,}" in r.json()["detail"]
    assert not parsed, "the body was parsed before it was refused"


@pytest.mark.parametrize("suffix", [".csv", ".npy", ".npz", ".h5", ".json", ".tdms"])
def test_a_file_cut_short_in_any_format_is_refused_and_nothing_is_stored(client, tmp_path,
                                                                           suffix):
    """An upload that stopped part way (a dropped link, a full disk on the scope) is a 422 that
    names the file, never a 500 and never the shots that happened to arrive."""
    from solitonde.signal import io as signal_io
    from solitonde.signal.waveform import Waveform

    shots = [Waveform(samples=shot_samples(k), t0=0.0, dt=5e-7, units="N",
                      metadata={"plate_id": "P1", "position": "A1", "sphere_diameter": 9.53e-3})
             for k in range(3)]
    path = signal_io.write(tmp_path / f"three{suffix}", shots)
    whole = path.read_bytes()
    assert client.post("/v1/measurements",
                       files={"file": (path.name, whole)}).status_code == 201
    for keep in (0.4, 0.7, 0.95):
        cut = whole[:int(len(whole) * keep)]
        r = client.post("/v1/measurements", files={"file": (f"cut{suffix}", cut)})
        assert r.status_code == 422, (suffix, keep, r.status_code, r.text[:300])
        assert r.json()["field"].startswith("file"), r.text[:300]
        assert f"cut{suffix}" in r.json()["detail"], r.text[:300]
    assert _count(client) == 1


def test_a_plot_whose_client_left_while_it_waited_is_not_drawn(client, monkeypatch):
    """Eleven browser tabs closed while their plots queued kept the CPU busy for minutes: now a
    plot's turn comes, the client is checked, and a gone client's plot is skipped (499 logged)."""
    import anyio

    from solitonde.instrument import plotting

    drawn = []
    real = plotting.trace_png
    monkeypatch.setattr(plotting, "trace_png", lambda *a, **k: drawn.append(1) or real(*a, **k))
    r = client.post("/v1/measurements", json={"shots": [shot_json()]})
    path = f"/v1/measurements/{r.json()['id']}/plot.png"
    assert client.get(path).status_code == 200 and len(drawn) == 1

    async def gone_client() -> int:
        sent = []

        async def receive():
            return {"type": "http.disconnect"}

        async def send(message):
            sent.append(message)

        scope = {"type": "http", "asgi": {"version": "3.0"}, "http_version": "1.1",
                 "method": "GET", "scheme": "http", "path": path, "raw_path": path.encode(),
                 "query_string": b"", "headers": [(b"host", b"testserver")],
                 "client": ("127.0.0.1", 5000), "server": ("testserver", 80),
                 "app": client.app, "state": {}}
        await client.app(scope, receive, send)
        return sent[0]["status"]

    assert anyio.run(gone_client) == 499
    assert len(drawn) == 1, "the gone client's plot was drawn"
