"""`solitonde analyze` and `solitonde samples`: rows, aggregates, per-file errors, exit codes."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from solitonde.instrument.cli import build_app
from solitonde.signal import io
from solitonde.signal.synth import degrade, pulse_train
from solitonde.signal.waveform import Waveform

DATA = Path(__file__).resolve().parents[1] / "data_samples" / "waveforms"


def _files(tmp_path: Path) -> Path:
    rng = np.random.default_rng(0)
    shots = [Waveform(0.0, 5e-7, degrade(pulse_train(1800, 5e-7, [(150e-6, 30.0, 80e-6),
                                                                  (650e-6, 15.0, 85e-6)]),
                                         40.0, rng, 30.0), metadata={"position": 0.1})
             for _ in range(3)]
    io.write(tmp_path / "a.csv", shots)
    (tmp_path / "sub").mkdir()
    io.write(tmp_path / "sub" / "b.h5", shots)
    return tmp_path


def test_analyze_folder_json(tmp_path):
    """A folder is searched recursively; one row per shot; exit 0 when everything succeeded."""
    root = _files(tmp_path)
    result = CliRunner().invoke(build_app(), ["analyze", str(root), "--json"])
    assert result.exit_code == 0, result.output
    body = json.loads(result.stdout)
    assert len(body["shots"]) == 6 and body["errors"] == []
    row = body["shots"][0]
    for key in ("tof_s", "arr", "incident_time_s", "reflected_time_s", "incident_peak_N",
                "reflected_peak_N", "snr_db", "flags", "source", "shot"):
        assert key in row
    assert abs(row["tof_s"] - 500e-6) < 5e-7
    agg = body["aggregates"][0]
    assert agg["tof_s"]["count"] + len(agg["rejected"]) == 6  # rejected shots are listed


def test_failed_file_does_not_stop_others(tmp_path):
    """A broken file is reported, the others analysed, exit code 1; bad --out is usage (2)."""
    root = _files(tmp_path)
    (root / "bad.csv").write_text("time_s,force_N\n0,1\n")
    out = root / "r.csv"
    result = CliRunner().invoke(build_app(), ["analyze", str(root / "a.csv"), str(root / "bad.csv"),
                                              "--out", str(out)])
    assert result.exit_code == 1
    assert "bad.csv" in result.output
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == 3 and float(rows[0]["arr"]) > 0.4
    usage = CliRunner().invoke(build_app(), ["analyze", str(root), "--out", "r.txt"])
    assert usage.exit_code == 2


def test_parquet_output(tmp_path):
    """--out results.parquet writes the rows as Parquet."""
    import pandas as pd

    root = _files(tmp_path)
    out = tmp_path / "r.parquet"
    result = CliRunner().invoke(build_app(), ["analyze", str(root / "a.csv"), "--out", str(out)])
    assert result.exit_code == 0
    assert len(pd.read_parquet(out)) == 3


def test_data_samples_match_their_truth():
    """The shipped synthetic samples analyse to their truth (TOF within 2 samples)."""
    truth = {(r["file"], int(r["shot"])): r
             for r in csv.DictReader((DATA / "truth.tsv").open(), delimiter="\t")}
    result = CliRunner().invoke(build_app(), ["analyze", str(DATA), "--json"])
    assert result.exit_code == 0, result.output
    shots = json.loads(result.stdout)["shots"]
    assert len(shots) == len(truth)
    for s in shots:
        t = truth[(Path(s["source"]).name, s["shot"])]
        dt = 1.0 / float(t["sample_rate_hz"])
        assert abs(s["tof_s"] - float(t["tof_s"])) < 2 * dt
        assert abs(s["arr"] - float(t["arr"])) < 0.02
