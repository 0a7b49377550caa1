"""Uploads with several channels follow analyze's rules (a trigger is never stored as a shot),
and the export gains kind=estimates: one row per measurement, flat columns, ISO 8601 times."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from fastapi.testclient import TestClient
from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

from solitonde.instrument.inference.estimate_rows import ESTIMATE_COLUMNS
from solitonde.signal import io as signal_io

ROOT = Path(__file__).resolve().parents[2]
TABLE = ROOT / "data_samples" / "default_table.h5"
H5 = ROOT / "data_samples" / "waveforms" / "synthetic_D9.53_t3.18_snr30.h5"


def _daq_tdms(path: Path) -> Path:
    """An NI DAQ file: group 'Measured Data', the sensor on Dev1/ai0 (V), a 5 V trigger step on
    Dev1/ai1, both with the waveform properties DAQmx writes."""
    (w,) = signal_io.read(H5)[:1]
    volts = w.force / 20.0
    step = np.where(np.arange(w.n) * w.dt + w.t0 > w.t0 + 50e-6, 5.0, 0.0)
    props = {"wf_start_offset": w.t0, "wf_increment": w.dt, "wf_samples": w.n,
             "unit_string": "V", "NI_UnitDescription": "Volts"}
    with TdmsWriter(str(path)) as tdms:
        tdms.write_segment([RootObject({"name": "run 7"}), GroupObject("Measured Data"),
                            ChannelObject("Measured Data", "Dev1/ai0", volts, properties=props),
                            ChannelObject("Measured Data", "Dev1/ai1", step, properties=props)])
    return path


@pytest.fixture
def client(service_client) -> TestClient:
    return service_client(table_path=TABLE)


def test_a_daq_trigger_channel_is_never_stored_as_a_shot(client: TestClient, tmp_path: Path):
    body = _daq_tdms(tmp_path / "daq.tdms").read_bytes()
    form = {"calibration": "20", "sphere_diameter": "0.00953", "plate_id": "P1"}
    r = client.post("/v1/measurements", files={"file": ("daq.tdms", body)}, data=form)
    assert r.status_code == 201, r.text
    out = r.json()
    assert out["n_shots"] == 1 and out["shots"][0]["metadata"]["channel"] == "Dev1/ai0"
    (skip,) = out["skipped_channels"]
    assert skip["channel"] == "Measured Data/Dev1/ai1" and "step" in skip["reason"]
    stored = client.get(f"/v1/measurements/{out['id']}").json()
    assert stored["n_shots"] == 1
    # named: the sensor by its bare or full name (the same shot: stored once, the stored one
    # answered); the trigger refused; an unknown one listed
    for name in ("Dev1/ai0", "Measured Data/Dev1/ai0"):
        r = client.post("/v1/measurements", files={"file": ("daq.tdms", body)},
                        data={**form, "channel": name})
        assert r.status_code == 200 and r.json()["duplicate_of"] == out["id"], r.text
        assert r.json()["n_shots"] == 1
    r = client.post("/v1/measurements", files={"file": ("daq.tdms", body)},
                    data={**form, "channel": "Dev1/ai1"})
    assert r.status_code == 422 and r.json()["field"] == "channel"
    assert "not a sensor trace" in r.json()["detail"]
    r = client.post("/v1/measurements", files={"file": ("daq.tdms", body)},
                    data={**form, "channel": "Dev1/ai7"})
    assert r.status_code == 422 and r.json()["field"] == "channel"
    assert "Measured Data/Dev1/ai0, Measured Data/Dev1/ai1" in r.json()["detail"]
    count = len(client.get("/v1/measurements").json()["items"])
    assert count == 1  # the refused posts stored nothing, the repeats nothing more


def test_export_of_estimates_one_row_per_measurement(client: TestClient):
    shots = [w.to_dict() for w in signal_io.read(H5)]
    for i, s in enumerate(shots):
        s["metadata"] = {"plate_id": "P9", "position": "A1", "sphere_diameter": 9.53e-3,
                         "shot": i, "x_m": 0.25, "y_m": 0.457}
    r = client.post("/v1/measurements", json={"shots": shots})
    assert r.status_code == 201, r.text
    r = client.get("/v1/measurements/export?kind=estimates&format=csv")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
    frame = pd.read_csv(io.StringIO(r.text))
    assert list(frame.columns) == ["measurement_id", "created_at", *ESTIMATE_COLUMNS]
    row = frame.iloc[0]
    assert (row["plate_id"], row["position"], row["x_m"], row["y_m"]) == ("P9", "A1", 0.25, 0.457)
    assert row["n_shots"] == 3 and row["thickness_m_status"] == "constrained"
    assert row["thickness_m_ci95_low"] <= 3.18e-3 <= row["thickness_m_ci95_high"]
    assert pd.Timestamp(row["created_at"]).tzname() == "UTC"
    assert str(row["created_at"]).endswith("Z")
    parquet = pd.read_parquet(io.BytesIO(
        client.get("/v1/measurements/export?kind=estimates&format=parquet").content))
    assert parquet["n_shots"].dtype.kind == "i" and parquet.iloc[0]["plate_id"] == "P9"
    # the shots export: ISO times, integer shot numbers
    shots_csv = pd.read_csv(io.StringIO(client.get("/v1/measurements/export").text))
    assert str(shots_csv["created_at"][0]).endswith("Z")
    assert shots_csv["shot"].dtype.kind == "i" and shots_csv["shot_index"].dtype.kind == "i"
    # nothing matches: still the columns
    empty = client.get("/v1/measurements/export?kind=estimates&plate_id=nobody").text
    assert empty.splitlines()[0].split(",")[:3] == ["measurement_id", "created_at", "plate_id"]
    assert client.get("/v1/measurements/export?kind=maps").status_code == 422
