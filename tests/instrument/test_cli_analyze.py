"""`solitonde analyze` output paths and inputs: bad `--out`/`--plots` are clean errors (never a
traceback after the analysis), no plot overwrites another, a file named twice counts once."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app

DATA = Path(__file__).resolve().parents[2] / "data_samples" / "waveforms"
CSV = DATA / "synthetic_D9.53_t4.83_snr40.csv"  # two shots, plate and position in its metadata


def _run(*args: str):
    return CliRunner().invoke(build_app(), list(args))


def test_out_a_folder_is_a_usage_error_before_any_work(tmp_path: Path) -> None:
    out = tmp_path / "r.csv"
    out.mkdir()
    res = _run("analyze", str(CSV), "--out", str(out))
    assert res.exit_code == 2 and isinstance(res.exception, SystemExit), res.output
    assert "--out" in res.output and "folder" in res.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.csv"]


def test_plots_a_file_is_a_usage_error(tmp_path: Path) -> None:
    plots = tmp_path / "plots"
    plots.write_text("x")
    res = _run("analyze", str(CSV), "--plots", str(plots))
    assert res.exit_code == 2 and isinstance(res.exception, SystemExit), res.output
    assert "--plots" in res.output


def test_out_that_cannot_be_written_keeps_json_valid_and_exits_1(tmp_path: Path) -> None:
    (tmp_path / "afile").write_text("x")
    res = _run("analyze", str(CSV), "--json", "--out", str(tmp_path / "afile" / "r.csv"))
    assert res.exit_code == 1 and isinstance(res.exception, SystemExit), res.output
    body = json.loads(res.stdout)
    assert len(body["shots"]) == 2
    (err,) = body["errors"]
    assert err["source"] == "--out" and "cannot write" in err["error"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


def test_out_in_a_new_folder_is_created(tmp_path: Path) -> None:
    out = tmp_path / "new" / "sub" / "r.parquet"
    res = _run("analyze", str(CSV), "--out", str(out))
    assert res.exit_code == 0, res.output
    assert out.is_file() and sorted(p.name for p in out.parent.iterdir()) == ["r.parquet"]


def test_plots_of_files_sharing_a_stem_do_not_overwrite_each_other(tmp_path: Path) -> None:
    for sub in ("a", "b"):
        (tmp_path / sub).mkdir()
        shutil.copy(CSV, tmp_path / sub / "x.csv")
    shutil.copy(DATA / "synthetic_D9.53_t2.29_snr40.npy", tmp_path / "a" / "x.npy")
    plots = tmp_path / "plots"
    res = _run("analyze", str(tmp_path / "a"), str(tmp_path / "b"), "--plots", str(plots),
               "--json")
    assert res.exit_code == 0, res.output
    n_shots = len(json.loads(res.stdout)["shots"])
    assert n_shots == 6
    assert len(list(plots.glob("*.png"))) == n_shots
    assert not list(plots.glob(".*"))


def test_a_file_named_twice_is_analysed_once(tmp_path: Path) -> None:
    (tmp_path / "d").mkdir()
    shutil.copy(CSV, tmp_path / "d" / "x.csv")
    res = _run("analyze", str(tmp_path / "d"), str(tmp_path / "d" / "x.csv"),
               str(tmp_path / "d" / ".." / "d" / "x.csv"), "--json")
    assert res.exit_code == 0, res.output
    body = json.loads(res.stdout)
    assert len(body["shots"]) == 2
    (agg,) = body["aggregates"]
    assert agg["n_shots"] == 2


def _with_diameter(tmp_path: Path, value: str) -> Path:
    path = tmp_path / f"d_{value}.csv"
    path.write_text(CSV.read_text().replace("sphere_diameter: 0.00953",
                                            f"sphere_diameter: {value}"))
    return path


def test_invert_that_fails_for_a_position_is_an_error_and_exit_1(tmp_path: Path) -> None:
    """A sphere size the table lacks: the estimate fails, so the run did not all succeed. (10.5
    mm: the file's 9.53 mm pulses are still plausibly that chain's; 6 mm would be flagged
    ``implausible_units``, its solitary wave 1.9 times narrower.)"""
    res = _run("analyze", str(_with_diameter(tmp_path, "0.0105")), "--invert", "--json")
    assert res.exit_code == 1, res.output
    body = json.loads(res.stdout)
    (err,) = body["errors"]
    assert "diameter_m" in err["error"] and "synthetic-t4.83mm" in err["source"]
    assert body["estimates"][0]["estimate"] is None


def test_a_non_numeric_diameter_fails_that_file_not_every_estimate(tmp_path: Path) -> None:
    """A file whose sphere size is no number is metadata the service refuses (a 422 naming
    ``file.shots.0.metadata.sphere_diameter``): `analyze` refuses that file too, naming the key,
    and the other file's estimate stands."""
    bad = _with_diameter(tmp_path, "abc")
    res = _run("analyze", str(bad), str(CSV), "--invert", "--json")
    assert res.exit_code == 1, res.output
    body = json.loads(res.stdout)
    (err,) = body["errors"]
    assert err["source"] == str(bad)
    assert err["error"].startswith("metadata.sphere_diameter: 'abc' is not a sphere diameter")
    (row,) = body["estimates"]  # the other file: plate synthetic-t4.83mm at position 0.457
    assert row["estimate"]["thickness_m"]["status"] == "constrained"
    assert row["skipped"] == []
    assert {s["source"] for s in body["shots"]} == {str(CSV)}


def test_an_unreadable_calibration_file_is_named_as_the_source(tmp_path: Path) -> None:
    cal = tmp_path / "cal.json"
    cal.write_text("{")
    res = _run("analyze", str(CSV), "--invert", "--json", "--calibration-file", str(cal))
    assert res.exit_code == 1
    (err,) = json.loads(res.stdout)["errors"]
    assert err["source"] == str(cal) and err["error"].startswith("calibration")
