"""`solitonde analyze` and `solitonde samples`: rows, aggregates, per-file errors, exit codes."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app
from solitonde.signal import io
from solitonde.signal.synth import degrade, pulse_train
from solitonde.signal.waveform import Waveform

DATA = Path(__file__).resolve().parents[2] / "data_samples" / "waveforms"


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


def _tof_bound_samples(row: dict) -> float:
    """The Cramer-Rao bound on a shot's TOF, in samples: the model's clean trace for the row's
    scene and the row's SNR (signal.accuracy.cramer_rao)."""
    from solitonde.model.scene import load_scene
    from solitonde.model.simulate import simulate
    from solitonde.signal.accuracy import Truth, cramer_rao

    scene = load_scene(None, [f"chain.diameter={row['sphere_diameter_m']}",
                              f"plate.thickness={row['plate_thickness_m']}",
                              f"striker.drop_height={row['drop_height_m']}",
                              "effects.plate_model=infinite", "output.duration=auto"])
    sim = simulate(scene)
    t = sim.truth
    truth = Truth.from_peaks(sim.samples, sim.dt, sim.t0, t)
    sigma = truth.incident_peak_N / 10 ** (float(row["snr_db"]) / 20)
    return cramer_rao(sim.samples, sim.dt, truth, 1.0 / sim.dt, sigma, sim.t0)["tof_samples"]


def test_data_samples_match_their_truth():
    """The shipped synthetic samples analyse to their truth: TOF within 2 samples, or within 4
    standard deviations of the Cramer-Rao bound where the data cannot do better (D = 19.05 mm
    at 30 dB: the reflection, ARR 0.12, is 11 dB above the noise and the bound 2.5 samples);
    ARR within 0.02."""
    truth = {(r["file"], int(r["shot"])): r
             for r in csv.DictReader((DATA / "truth.tsv").open(), delimiter="\t")}
    result = CliRunner().invoke(build_app(), ["analyze", str(DATA), "--json"])
    assert result.exit_code == 0, result.output
    shots = json.loads(result.stdout)["shots"]
    assert len(shots) == len(truth)
    for s in shots:
        t = truth[(Path(s["source"]).name, s["shot"])]
        dt = 1.0 / float(t["sample_rate_hz"])
        error = abs(s["tof_s"] - float(t["tof_s"])) / dt
        assert error < 2 or error < 4 * _tof_bound_samples(t), (s["source"], s["shot"], error)
        assert abs(s["arr"] - float(t["arr"])) < 0.02


def _pulses(amplitude: float = 30.0) -> np.ndarray:
    return pulse_train(1800, 5e-7, [(150e-6, amplitude, 80e-6), (650e-6, amplitude / 2, 85e-6)])


def test_any_broken_file_is_its_own_error(tmp_path):
    """Files that made readers leak TypeError, pandas or JSON errors are each reported; the
    good file is still analysed; exit 1."""
    import h5py

    root = _files(tmp_path)
    np.savez(root / "meta.npz", samples=_pulses(), dt=5e-7, metadata=json.dumps([1]))
    with h5py.File(root / "attr.h5", "w") as fh:
        fh["x"] = _pulses()
        fh["x"].attrs["dt"] = [5e-7, 5e-7]
    (root / "bom.csv").write_bytes(b"\xef\xbb\xbf# a: 1\n\xef\xbb\xbftime_s,force_N\n1,2\n")
    (root / "j.json").write_text("{")
    (root / "lat.csv").write_bytes(b"# op: J\xfcrgen\ntime_s,force_N\n0,1\n")
    names = ["meta.npz", "attr.h5", "bom.csv", "j.json", "lat.csv"]
    result = CliRunner().invoke(build_app(), ["analyze", str(root / "a.csv"),
                                              *(str(root / n) for n in names), "--json"])
    assert result.exit_code == 1, result.output
    body = json.loads(result.stdout)
    assert len(body["shots"]) == 3
    failed = {Path(e["source"]).name for e in body["errors"]}
    assert failed == set(names)


def test_global_options_only_where_they_fit(tmp_path):
    """--sample-rate and --calibration do not break files that carry their own time axis or are
    in newtons (TDMS, JSON, CSV, HDF5); --calibration converts the files in volts; --units
    contradicting a file's own units is that file's error; a calibration no file used is
    reported."""
    root = _files(tmp_path)
    io.write(root / "t.tdms", io.read(root / "a.csv"))
    io.write(root / "j.json", io.read(root / "a.csv"))
    np.savez(root / "volts.npz", samples=_pulses(0.15), dt=5e-7, units="V")  # x 200 N/V = 30 N
    np.save(root / "raw.npy", _pulses())  # newtons, no time axis
    args = ["analyze", str(root), "--sample-rate", "2e6", "--calibration", "200", "--json"]
    result = CliRunner().invoke(build_app(), args)
    assert result.exit_code == 0, result.output
    body = json.loads(result.stdout)
    assert len(body["shots"]) == 14 and body["errors"] == []
    volts = [s for s in body["shots"] if s["source"].endswith("volts.npz")]
    assert abs(volts[0]["incident_peak_N"] - 30.0) < 2.0
    body = json.loads(CliRunner().invoke(build_app(), [*args, "--units", "V"]).stdout)
    assert {Path(e["source"]).name for e in body["errors"]} == {"a.csv", "b.h5", "t.tdms",
                                                                "j.json"}
    assert all("units" in e["error"] for e in body["errors"])  # they say N, --units says V
    result = CliRunner().invoke(build_app(), ["analyze", str(root / "a.csv"), "--calibration",
                                              "200", "--json"])
    assert result.exit_code == 1
    assert json.loads(result.stdout)["errors"][0]["source"] == "--calibration"


def test_files_without_position_are_not_pooled(tmp_path):
    """Two files that name neither plate nor position aggregate apart; identifiers keep their
    digits (007 vs 7 are two plates)."""
    for name, amp in (("plateA.npy", 30.0), ("plateB.npy", 60.0)):
        t = 5e-7 * np.arange(1800)
        np.save(tmp_path / name, np.column_stack([t, _pulses(amp), _pulses(amp)]))
    result = CliRunner().invoke(build_app(), ["analyze", str(tmp_path), "--json"])
    assert result.exit_code == 0, result.output
    aggs = json.loads(result.stdout)["aggregates"]
    assert len(aggs) == 2 and {Path(a["source"]).name for a in aggs} == {"plateA.npy",
                                                                          "plateB.npy"}
    assert all(a["n_shots"] == 2 for a in aggs)
    ids = tmp_path / "ids"
    ids.mkdir()
    w = io.read(tmp_path / "plateA.npy")[0]
    io.write(ids / "a.csv", [w.with_metadata(plate_id="007", position="1.50")])
    io.write(ids / "b.csv", [w.with_metadata(plate_id="7", position="1.5")])
    aggs = json.loads(CliRunner().invoke(build_app(), ["analyze", str(ids), "--json"]).stdout)[
        "aggregates"]
    assert sorted((a["plate_id"], a["position"]) for a in aggs) == [("007", "1.50"), ("7", "1.5")]


def test_format_takes_every_file_and_empty_selection_is_named(tmp_path):
    """With --format, a folder's .txt files are read; a folder with nothing to read is an error
    that names it."""
    shots = io.read(_files(tmp_path) / "a.csv")
    txt = tmp_path / "txt"
    txt.mkdir()
    io.write(txt / "s.txt", shots, format="csv")
    result = CliRunner().invoke(build_app(), ["analyze", str(txt), "--format", "csv", "--json"])
    assert result.exit_code == 0, result.output
    assert len(json.loads(result.stdout)["shots"]) == 3
    empty = tmp_path / "empty"
    empty.mkdir()
    result = CliRunner().invoke(build_app(), ["analyze", str(empty), "--json"])
    assert result.exit_code == 2  # a usage error: nothing to analyse where the user pointed
    assert str(empty) in result.stderr and "no files" in result.stderr


def test_analyze_names_an_outlier_it_leaves_out(tmp_path):
    """Four good shots and one whose reflection was read 100 us late, at one position: the
    aggregate keeps four, and the text names the fifth shot, its TOF and the level it crossed;
    the same shots without the late one lose none (the level is set for four shots)."""
    rng = np.random.default_rng(3)

    def shot(reflection_s: float) -> Waveform:
        trace = pulse_train(1800, 5e-7, [(150e-6, 30.0, 80e-6), (reflection_s, 15.0, 85e-6)])
        return Waveform(0.0, 5e-7, degrade(trace, 40.0, rng, 30.0),
                        metadata={"plate_id": "P1", "position": "A"})

    io.write(tmp_path / "good.csv", [shot(650e-6) for _ in range(4)])
    io.write(tmp_path / "late.csv", [shot(750e-6)])
    result = CliRunner().invoke(build_app(), ["analyze", str(tmp_path)])
    assert result.exit_code == 0, result.output
    lines = [line for line in result.output.splitlines() if line.startswith("outlier left out")]
    assert len(lines) == 1, result.output
    assert lines[0].startswith("outlier left out: late.csv shot 0 (P1, A): TOF 600")
    assert lines[0].endswith("(the level 1 % of sets of 5 good shots cross)")
    (tmp_path / "late.csv").unlink()
    again = CliRunner().invoke(build_app(), ["analyze", str(tmp_path), "--json"])
    assert json.loads(again.stdout)["aggregates"][0]["rejected"] == []
