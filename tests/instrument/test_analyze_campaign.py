"""A day's folder of plain scope files, described on the command line or by a campaign manifest,
goes in; an estimates file per plate and position comes out. And each bad input is one clear
error with its exit code: 2 for usage (a manifest row without a file, an unknown column), 1 for
a file that fails (its metadata contradicting a flag, a channel it does not have)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app
from solitonde.signal import io as signal_io

DATA = Path(__file__).resolve().parents[2] / "data_samples" / "waveforms"
H5 = DATA / "synthetic_D9.53_t3.18_snr30.h5"  # three shots of a 3.18 mm plate, D = 9.53 mm
TRUTH_T = 3.18e-3
CAL = 20.0  # N/V of the pretend sensor


def _run(*args: str):
    return CliRunner().invoke(build_app(), [str(a) for a in args])


def _plain_folder(root: Path) -> Path:
    """The three shots as PicoScope-style CSVs in millivolts: no plate, size or position."""
    day = root / "day1"
    day.mkdir()
    for i, w in enumerate(signal_io.read(H5)):
        mv = w.force / CAL * 1e3
        rows = "".join(f"{t * 1e3:.8f},{v:.5f}\r\n" for t, v in zip(w.times, mv, strict=True))
        (day / f"shot_{i:02d}.csv").write_text(f"Time,Channel A\r\n(ms),(mV)\r\n\r\n{rows}",
                                               newline="")
    return day


def _estimates(path: Path) -> pd.DataFrame:
    frame = pd.read_csv(path) if path.suffix == ".csv" else pd.read_parquet(path)
    return frame


def _covers(row: pd.Series) -> bool:
    return row["thickness_m_ci95_low"] <= TRUTH_T <= row["thickness_m_ci95_high"]


def test_folder_plus_manifest_writes_estimates_that_cover_the_truth(tmp_path: Path) -> None:
    day = _plain_folder(tmp_path)
    manifest = tmp_path / "campaign.csv"
    manifest.write_text("file,plate_id,position,x_m,y_m,sphere_diameter_m,calibration_N_per_V\n"
                        "day1/shot_*.csv,P7,A1,0.120,0.457,0.00953,20\n")
    out = tmp_path / "est.csv"
    res = _run("analyze", "--manifest", manifest, "--estimates-out", out, "--json")
    assert res.exit_code == 0, res.output
    report = json.loads(res.stdout)
    assert len(report["shots"]) == 3 and not report["errors"]
    frame = _estimates(out)
    assert len(frame) == 1
    row = frame.iloc[0]
    assert (row["plate_id"], row["position"], row["x_m"], row["y_m"]) == ("P7", "A1", 0.12, 0.457)
    assert row["n_shots"] == 3 and str(row["sphere_diameters_m"]) == "0.00953"
    assert row["thickness_m_status"] == "constrained" and _covers(row), row.to_dict()
    assert row["thickness_m_ci68_low"] <= row["thickness_m_median"] <= row["thickness_m_ci68_high"]
    # the folder given too: every file in it must have a row, and the answer is the same
    res = _run("analyze", day, "--manifest", manifest, "--estimates-out", out)
    assert res.exit_code == 0, res.output
    assert _estimates(out).iloc[0]["thickness_m_median"] == row["thickness_m_median"]


def test_the_same_with_flags_instead_of_a_manifest(tmp_path: Path) -> None:
    day = _plain_folder(tmp_path)
    out = tmp_path / "est.parquet"
    res = _run("analyze", day, "--sphere-diameter", "0.00953", "--plate-id", "P7", "--position",
               "A1", "--x", "0.12", "--y", "0.457", "--calibration", "20", "--estimates-out", out)
    assert res.exit_code == 0, res.output
    frame = _estimates(out)
    assert len(frame) == 1 and frame["n_shots"].dtype.kind == "i"
    assert _covers(frame.iloc[0]), frame.iloc[0].to_dict()
    assert "estimate for plate P7, position A1 (x 0.12 m, y 0.457 m)" in res.output


def test_without_a_sphere_size_there_is_no_estimate_and_the_file_says_why(tmp_path: Path) -> None:
    """An inversion asked for without a sphere size fails (exit 1) naming the flag that gives
    it; the estimates file still has the position's row, saying why it has no numbers."""
    day = _plain_folder(tmp_path)
    out = tmp_path / "est.csv"
    res = _run("analyze", day, "--calibration", "20", "--plate-id", "P7", "--position", "A1",
               "--estimates-out", out)
    frame = _estimates(out)
    assert len(frame) == 1 and pd.isna(frame.iloc[0]["thickness_m_median"])
    assert "--sphere-diameter:" in frame.iloc[0]["reason"]  # CSV-neutralised: a leading quote
    assert res.exit_code == 1, res.output
    assert "failed: estimate for plate P7, position A1: --sphere-diameter:" in " ".join(
        res.output.split())


def test_a_manifest_row_that_matches_no_file_is_a_usage_error_naming_the_row(tmp_path):
    _plain_folder(tmp_path)
    manifest = tmp_path / "m.csv"
    manifest.write_text("file,plate_id,sphere_diameter_m\nday1/shot_*.csv,P7,0.00953\n"
                        "day2/*.csv,P8,0.00953\n")
    res = _run("analyze", "--manifest", manifest, "--calibration", "20")
    assert res.exit_code == 2
    assert "m.csv row 3" in res.stderr and "day2/*.csv" in res.stderr


def test_a_file_matched_by_two_rows_is_a_usage_error_naming_both(tmp_path):
    _plain_folder(tmp_path)
    manifest = tmp_path / "m.yaml"
    manifest.write_text("sphere_diameter_m: 0.00953\nfiles:\n  - {file: day1/shot_*.csv, "
                        "position: A}\n  - {file: day1/shot_01.csv, position: B}\n")
    res = _run("analyze", "--manifest", manifest, "--calibration", "20")
    assert res.exit_code == 2
    assert "shot_01.csv" in res.stderr and "entry 1" in res.stderr and "entry 2" in res.stderr


@pytest.mark.parametrize(("text", "says"), [
    ("file,plate,sphere_diameter_m\nday1/*.csv,P7,0.00953\n", "unknown column 'plate'"),
    ("file,sphere_diameter_m\nday1/*.csv,9.53mm\n", "sphere_diameter_m"),
    ("file,sphere_diameter_m\nday1/*.csv,-1\n", "out of range"),
    ("file,x_m\nday1/*.csv,nan\n", "x_m"),
    ("file,plate_id\n,P7\n", "file: missing"),
])
def test_a_bad_manifest_row_names_the_row_and_key(tmp_path, text, says):
    _plain_folder(tmp_path)
    (tmp_path / "m.csv").write_text(text)
    res = _run("analyze", "--manifest", tmp_path / "m.csv", "--calibration", "20")
    assert res.exit_code == 2 and says in res.stderr and "m.csv" in res.stderr, res.stderr


def test_a_files_metadata_contradicting_a_flag_fails_that_file_naming_both(tmp_path):
    res = _run("analyze", DATA / "synthetic_D9.53_t4.83_snr40.csv", "--sphere-diameter", "0.019",
               "--json")
    assert res.exit_code == 1
    (error,) = json.loads(res.stdout)["errors"]
    assert "--sphere-diameter" in error["error"] and "0.00953" in error["error"]
    assert "0.019" in error["error"] and "the file" in error["error"]
    # agreeing values are fine, whatever their spelling
    res = _run("analyze", DATA / "synthetic_D9.53_t4.83_snr40.csv", "--sphere-diameter",
               "9.53e-3", "--position", "0.457")
    assert res.exit_code == 0, res.output


def test_a_missing_file_is_a_usage_error(tmp_path):
    res = _run("analyze", tmp_path / "nope.csv")
    assert res.exit_code == 2 and "nope.csv" in res.stderr


def test_messages_name_flags_not_keyword_arguments(tmp_path):
    """A bare column of numbers needs the sample rate: the message says --sample-rate."""
    path = tmp_path / "bare.csv"
    np.savetxt(path, np.sin(np.arange(200) / 10.0))
    res = _run("analyze", path, "--json")
    assert res.exit_code == 1
    (error,) = json.loads(res.stdout)["errors"]
    assert "--sample-rate" in error["error"] and "sample_rate=" not in error["error"]
