"""One shot at a time, near a support: each answer covers the truth or says it cannot tell.

The bundled scan (``data_samples/scan``) is a 3.0 mm aluminium plate simulated on the 3-D plate,
D 9.53 mm, three shots at each of eight positions 4 to 200 mm from the clamped edge. Read one file
at a time, as a lab reading one shot does, every answer must hold 3.0 mm: in its interval (one-
or two-sided), in one of an ``ambiguous`` answer's readings, or by saying the data cannot bound
it (``unconstrained``, next to the clamp, where TOF and ARR no longer depend on the plate). Before
the thickness-distance ridge was read (instrument.inference.ridge), 5 of the 24 answered
confidently and wrong: "at least 5.58 mm" 12 mm from the clamp, 3.04-3.44 mm at 25 mm.

Also here: the sizes a shot states in millimetres, the shot whose width is another size's, and
the paper's peak reading beside the template's in `analyze`'s rows.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app as build_cli
from solitonde.instrument.service.app import build_app
from solitonde.instrument.service.settings import Settings

ROOT = Path(__file__).resolve().parents[2]
SCAN = ROOT / "data_samples" / "scan"
DEFAULT_TABLE = ROOT / "data_samples" / "default_table.h5"
TRUTH_M = 3.0e-3


def _analyze(*args: str) -> tuple[int, dict]:
    result = CliRunner().invoke(build_cli(), ["analyze", *args, "--json"])
    return result.exit_code, json.loads(result.stdout)


def _covers(ci: list[float | None] | None, truth: float) -> bool:
    if ci is None:
        return False
    lo, hi = ci
    return (lo is None or lo <= truth) and (hi is None or truth <= hi)


@pytest.mark.parametrize("path", sorted(SCAN.glob("scan_P*_shot*.csv")), ids=lambda p: p.stem)
def test_each_single_shot_of_the_scan_covers_the_plate_or_says_it_cannot_tell(path: Path
                                                                              ) -> None:
    code, out = _analyze(str(path), "--invert", "--sphere-diameter", "9.53e-3")
    assert code == 0, out["errors"]
    est = out["estimates"][0]["estimate"]
    t = est["thickness_m"]
    if t["status"] == "ambiguous":
        assert len(est["readings"]) >= 2
        assert any(_covers(r["thickness_m"]["ci95"], TRUTH_M) for r in est["readings"]), est
        assert abs(sum(r["weight"] for r in est["readings"]) - 1.0) < 1e-9
    elif t["status"] == "unconstrained":
        assert t["ci95"] is None and t["median"] is None  # says it cannot tell, no number
    else:
        assert t["status"] in ("constrained", "lower_bound_only", "upper_bound_only")
        assert _covers(t["ci95"], TRUTH_M), est


def test_an_ambiguous_answer_is_printed_reading_by_reading_and_exits_0() -> None:
    """The table's own features of a 4.99 mm plate 19.5 mm from the clamp, as the mean of five
    shots: the data fit a sliver of thinner plate nearer to the clamp apart from the main
    reading. `invert` prints both readings and exits 0 (an honest answer), and one of them holds
    the plate."""
    result = CliRunner().invoke(build_cli(), [
        "invert", "--diameter", "9.53e-3", "--tof", "5.090e-4", "--tof-std", "3e-7",
        "--arr", "0.755", "--arr-std", "0.004", "--shots", "5", "--table", str(DEFAULT_TABLE),
        "--json"])
    assert result.exit_code == 0, result.output
    est = json.loads(result.output)
    assert est["thickness_m"]["status"] == "ambiguous"
    assert len(est["readings"]) == 2
    assert any(_covers(r["thickness_m"]["ci95"], 4.99e-3) for r in est["readings"])
    assert any("another reading fits as well" in w for w in est["warnings"])
    text = CliRunner().invoke(build_cli(), [
        "invert", "--diameter", "9.53e-3", "--tof", "5.090e-4", "--tof-std", "3e-7",
        "--arr", "0.755", "--arr-std", "0.004", "--shots", "5", "--table", str(DEFAULT_TABLE)])
    assert text.exit_code == 0
    assert "thickness: AMBIGUOUS" in text.output
    assert "reading 1 (weight" in text.output and "reading 2 (weight" in text.output


def test_a_size_in_millimetres_is_refused_with_the_metres_it_means(tmp_path: Path) -> None:
    result = CliRunner().invoke(build_cli(), ["analyze", str(SCAN / "scan_P06_shot0.csv"),
                                              "--sphere-diameter", "9.53"])
    assert result.exit_code == 2
    assert "sizes are in metres: 9.53 mm is 9.53e-3" in result.output
    result = CliRunner().invoke(build_cli(), ["invert", "--diameter", "19.05", "--tof", "5e-4",
                                              "--arr", "0.5"])
    assert result.exit_code == 2
    assert "sizes are in metres: 19.05 mm is 19.05e-3" in result.output
    settings = Settings(store_path=tmp_path / "s.sqlite", table_path=DEFAULT_TABLE)
    with TestClient(build_app(settings)) as client:
        r = client.post("/v1/invert", json={"inputs": [
            {"diameter_m": 9.53, "tof_s": 5e-4, "arr": 0.5}]})
        assert r.status_code == 422
        assert "sizes are in metres: 9.53 mm is 9.53e-3" in r.text
        assert r.json()["field"] == "inputs.0.diameter_m"


def test_a_shot_of_another_sphere_size_says_which() -> None:
    """A 9.53 mm shot read as 19.05 mm: its incident is a 9.53 mm solitary wave, and the error
    says so (beside the units, which a wave of that width could equally mean)."""
    code, out = _analyze(str(SCAN / "scan_P06_shot0.csv"), "--sphere-diameter", "19.05e-3")
    assert code == 1
    (error,) = [e["error"] for e in out["errors"]]
    assert error.startswith("implausible_units: the incident pulse is 37")
    assert "a solitary wave of 9.53 mm spheres, not 19.05 mm" in error
    assert "--calibration" in error


def test_analyze_rows_carry_the_papers_peak_reading(tmp_path: Path) -> None:
    path = SCAN / "scan_P08_shot0.csv"
    code, out = _analyze(str(path), "--sphere-diameter", "9.53e-3")
    assert code == 0
    shot = out["shots"][0]
    assert shot["tof_peak_s"] == pytest.approx(shot["tof_s"], rel=0.01)
    assert shot["arr_peak"] == pytest.approx(shot["arr"], rel=0.02)
    rows = tmp_path / "rows.csv"
    result = CliRunner().invoke(build_cli(), ["analyze", str(path), "--sphere-diameter",
                                              "9.53e-3", "--out", str(rows)])
    assert result.exit_code == 0, result.output
    with rows.open() as fh:
        row = next(csv.DictReader(fh))
    assert float(row["tof_peak_s"]) == shot["tof_peak_s"]
    assert float(row["arr_peak"]) == shot["arr_peak"]


def test_the_schema_types_the_shot_features_and_says_which_reading_each_is(
        tmp_path: Path) -> None:
    settings = Settings(store_path=tmp_path / "s.sqlite", table_path=DEFAULT_TABLE)
    with TestClient(build_app(settings)) as client:
        schemas = client.get("/openapi.json").json()["components"]["schemas"]
    props = schemas["ShotFeatures"]["properties"]
    assert "template reading" in props["tof_s"]["description"]
    assert "paper's definition" in props["tof_peak_s"]["description"]
    assert "paper's definition" in props["arr_peak"]["description"]
    assert {"type": "number"} in props["arr"]["anyOf"]


def test_an_ambiguous_answers_readings_travel_through_the_estimates_file_to_the_map() -> None:
    """The estimates file keeps the readings (JSON column); a map made from the file shows them
    at their position."""
    import io

    import pandas as pd

    from solitonde.instrument.inference.estimate_rows import estimate_row, to_bytes
    from solitonde.instrument.inference.plate_map import from_estimate_rows

    reading = {"thickness_m": {"map": 3.0e-3, "median": 3.0e-3, "ci68": [2.9e-3, 3.1e-3],
                               "ci95": [2.8e-3, 3.2e-3], "status": "constrained"},
               "distance_m": {"map": 0.02, "median": 0.02, "ci68": [0.018, 0.022],
                              "ci95": [0.015, 0.025], "status": "constrained"}, "weight": 0.3}
    estimate = {"thickness_m": {"map": None, "median": None, "ci68": None,
                                "ci95": [2.8e-3, 3.6e-3], "status": "ambiguous"},
                "distance_m": {"map": None, "median": None, "ci68": None,
                               "ci95": [0.015, 0.4], "status": "ambiguous"},
                "readings": [reading, {**reading, "weight": 0.7}], "warnings": []}
    row = estimate_row({"plate_id": "P", "position": "A", "x_m": 0.1, "y_m": 0.2}, [9.53e-3], 1,
                       estimate, None)
    frame = pd.read_csv(io.BytesIO(to_bytes([row], "csv")))
    assert frame.loc[0, "thickness_m_status"] == "ambiguous"
    assert json.loads(frame.loc[0, "readings"])[0] == reading
    (position,) = from_estimate_rows(frame.to_dict("records"))
    assert [r["weight"] for r in position["readings"]] == [0.3, 0.7]
    assert position["thickness_m"]["status"] == "ambiguous"


def test_table_info_names_the_material_spread_and_where_it_comes_from() -> None:
    result = CliRunner().invoke(build_cli(), ["table", "info", str(DEFAULT_TABLE), "--json"])
    assert result.exit_code == 0, result.output
    spread = json.loads(result.output)["material_spread"]
    assert spread["source"] == "library" and spread["youngs_modulus_rel_sd"] > 0
    text = CliRunner().invoke(build_cli(), ["table", "info", str(DEFAULT_TABLE)]).output
    assert "plate material spread: E +- 0.85 %" in text and "its grade's" in text
