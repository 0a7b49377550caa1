"""Plate maps: a simulated scan near a clamped edge, posted through the API, locates the edge
within 10 mm of the truth at every position; the map's JSON and PNG, the CLI's map from the
estimates analyze writes and from the store, deletion, and bad coordinates.

The scan is data_samples/scan (``solitonde samples --scan``): 8 positions of a 3.0 mm plate of
the paper's set-up at known distances x from its clamped edge x = 0, the Green's-function tier,
3 shots each at 40 dB, plain files plus campaign.csv.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app as build_cli
from solitonde.instrument.inference.edge_fit import locate
from solitonde.instrument.service.app import build_app
from solitonde.instrument.service.settings import Settings

ROOT = Path(__file__).resolve().parents[2]
SCAN = ROOT / "data_samples" / "scan"
TABLE = ROOT / "data_samples" / "default_table.h5"
TOLERANCE_M = 10e-3


def _truth() -> dict[str, dict[str, str]]:
    with (SCAN / "truth.tsv").open() as fh:
        return {row["position"]: row for row in csv.DictReader(fh, delimiter="\t")}


def _manifest() -> list[dict[str, str]]:
    with (SCAN / "campaign.csv").open() as fh:
        return list(csv.DictReader(fh))


# --- the fit on its own ---------------------------------------------------------------------


def _answer(d: float, half: float = 2e-3) -> dict:
    return {"median": d, "ci68": [d - half, d + half], "ci95": [d - 2 * half, d + 2 * half],
            "status": "constrained"}


@pytest.mark.parametrize(("angle", "offset"), [(0.0, 0.0), (30.0, 0.1), (200.0, -0.3),
                                               (90.0, 0.05)])
def test_a_line_at_any_angle_is_found_from_constrained_intervals(angle, offset):
    t = math.radians(angle)
    rng = np.random.default_rng(int(angle))
    pts = rng.uniform(-0.4, 0.4, (7, 2))
    positions = []
    for x, y in pts:  # positions 5..40 mm from the line, on its positive side
        d = rng.uniform(0.005, 0.04)
        foot = x * math.cos(t) + y * math.sin(t) - offset
        x, y = x + (d - foot) * math.cos(t), y + (d - foot) * math.sin(t)
        positions.append({"x_m": x, "y_m": y, "distance_m": _answer(d + rng.normal(0, 1e-3))})
    fit, reason = locate(positions)
    assert reason is None
    for p in positions:
        true_d = p["x_m"] * math.cos(t) + p["y_m"] * math.sin(t) - offset
        assert abs(fit.distance(p["x_m"], p["y_m"]) - true_d) < 3e-3
    lo, hi = fit.ci95_offset_m
    assert lo <= fit.offset_m <= hi


def test_one_sided_answers_only_push_the_line_away():
    """A position that says 'at least 30 mm' pulls nothing: the same line as without it, unless
    the line came closer than its bound."""
    near = [{"x_m": x, "y_m": y, "distance_m": _answer(x)} for x, y in
            ((0.01, 0.1), (0.02, 0.5), (0.015, 0.8))]
    far = {"x_m": 0.3, "y_m": 0.4, "distance_m": {"median": None, "ci68": [0.03, 0.457],
                                                  "ci95": [0.028, 0.457],
                                                  "status": "lower_bound_only"}}
    a, _ = locate(near)
    b, _ = locate([*near, far])
    assert abs(a.offset_m - b.offset_m) < 1e-4
    assert abs(a.normal_angle_deg - b.normal_angle_deg) < 0.05


def test_the_positions_cannot_tell_and_say_why():
    far = {"median": None, "ci68": [0.03, 0.457], "ci95": [0.028, 0.457],
           "status": "lower_bound_only"}
    cases = {
        "at least three": [{"x_m": 0.01, "y_m": 0.1, "distance_m": _answer(0.01)}],
        "far from any support": [{"x_m": 0.3, "y_m": y, "distance_m": far}
                                 for y in (0.1, 0.4, 0.7)],
        "one line": [{"x_m": 0.01 * k, "y_m": 0.5, "distance_m": _answer(0.01 * k)}
                     for k in (1, 2, 3, 4)],
        "which side": [{"x_m": x, "y_m": y, "distance_m": _answer(0.02)}
                       for x, y in ((0.020, 0.1), (0.021, 0.3), (0.019, 0.5), (0.0205, 0.7))],
    }
    for words, positions in cases.items():
        fit, reason = locate(positions)
        assert fit is None and words in reason, (words, reason)


# --- through the API --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def scanned(tmp_path_factory):
    """The bundled scan posted file by file with the manifest's fields, as an acquisition PC
    would."""
    store = tmp_path_factory.mktemp("store") / "store.sqlite"
    with TestClient(build_app(Settings(store_path=store, table_path=TABLE))) as client:
        for row in _manifest():
            form = {"plate_id": row["plate_id"], "position": row["position"],
                    "x_m": row["x_m"], "y_m": row["y_m"],
                    "sphere_diameter": row["sphere_diameter_m"]}
            for path in sorted(SCAN.glob(row["file"])):
                r = client.post("/v1/measurements", files={"file": (path.name, path.read_bytes())},
                                data=form)
                assert r.status_code == 201, r.text
        yield client, store


def test_the_scan_locates_the_clamped_edge_within_10_mm_at_every_position(scanned):
    client, _ = scanned
    plates = client.get("/v1/plates").json()["items"]
    assert [(p["plate_id"], p["n_positions"], p["n_shots"]) for p in plates] == [("SCAN-A", 8, 24)]
    assert plates[0]["last_activity"].endswith("Z")
    plate_map = client.get("/v1/plates/SCAN-A/map").json()
    support = plate_map["support"]
    assert support is not None, plate_map["support_reason"]
    assert support["n_positions"] >= 6
    truth = _truth()
    for p in plate_map["positions"]:
        assert p["n_shots"] == 3 and len(p["measurement_ids"]) == 3
        error = abs(p["distance_to_located_support_m"] - float(truth[p["position"]]["x_m"]))
        assert error < TOLERANCE_M, (p["position"], error)
        t = p["thickness_m"]
        if t["status"] == "constrained":
            assert t["ci95"][0] <= 3.0e-3 <= t["ci95"][1], (p["position"], t)
    png = client.get("/v1/plates/SCAN-A/map.png")
    assert png.status_code == 200 and png.content[:8] == b"\x89PNG\r\n\x1a\n"
    assert client.get("/v1/plates/NOPE/map").status_code == 404
    assert client.get("/v1/plates/NOPE/map.png").json()["field"] == "plate_id"


def test_bad_coordinates_are_refused_naming_the_field(scanned):
    client, _ = scanned
    path = next(SCAN.glob("scan_P01_*.csv"))
    for value, _words in (("nan", "finite"), ("2.0", "0..0.914"), ("-0.1", "0..0.914"),
                         ("abc", "number")):
        r = client.post("/v1/measurements", files={"file": (path.name, path.read_bytes())},
                        data={"plate_id": "BAD", "x_m": value, "y_m": "0.1"})
        assert r.status_code == 422, (value, r.text)
        assert "x_m" in r.json()["field"], r.json()
    shot = {"t0": 0.0, "dt": 5e-7, "samples": [0.0] * 64,
            "metadata": {"plate_id": "BAD", "x_m": 0.5, "y_m": 1.5}}
    r = client.post("/v1/measurements", json={"shots": [shot]})
    assert r.status_code == 422 and r.json()["field"] == "shots.0.metadata.y_m"
    assert "BAD" not in [p["plate_id"] for p in client.get("/v1/plates").json()["items"]]


def test_delete_removes_a_measurement_and_the_map_follows(tmp_path):
    with TestClient(build_app(Settings(store_path=tmp_path / "s.sqlite", table_path=TABLE))) as c:
        ids = []
        for row in _manifest()[:3]:
            path = sorted(SCAN.glob(row["file"]))[0]
            r = c.post("/v1/measurements", files={"file": (path.name, path.read_bytes())},
                       data={"plate_id": "D1", "position": row["position"], "x_m": row["x_m"],
                             "y_m": row["y_m"], "sphere_diameter": row["sphere_diameter_m"]})
            ids.append(r.json()["id"])
        assert c.get("/v1/plates/D1/map").json()["n_positions"] == 3
        assert c.delete(f"/v1/measurements/{ids[0]}").status_code == 204
        assert c.get(f"/v1/measurements/{ids[0]}").status_code == 404
        assert c.delete(f"/v1/measurements/{ids[0]}").status_code == 404
        plate_map = c.get("/v1/plates/D1/map").json()
        assert plate_map["n_positions"] == 2 and plate_map["support"] is None
        assert "at least three" in plate_map["support_reason"]
        for i in ids[1:]:
            assert c.delete(f"/v1/measurements/{i}").status_code == 204
        assert c.get("/v1/plates/D1/map").status_code == 404
        assert c.get("/v1/plates").json()["items"] == []


# --- the command line ------------------------------------------------------------------------


def test_analyze_then_map_from_the_estimates_file(tmp_path):
    est, png = tmp_path / "est.csv", tmp_path / "map.png"
    run = CliRunner().invoke
    res = run(build_cli(), ["analyze", "--manifest", str(SCAN / "campaign.csv"),
                            "--estimates-out", str(est), "--json"])
    assert res.exit_code == 0, res.output
    res = run(build_cli(), ["map", str(est), "--plate-id", "SCAN-A", "--out", str(png), "--json"])
    assert res.exit_code == 0, res.output
    plate_map = json.loads(res.stdout)
    truth = _truth()
    for p in plate_map["positions"]:
        assert abs(p["distance_to_located_support_m"] - float(truth[p["position"]]["x_m"])) \
            < TOLERANCE_M
        # every position's own answer holds the plate: the scan runs on the 3-D plate, the table
        # on the 2-D one next to the clamp, whose error the table's budget must carry (without
        # it, on the 20-distance table, P02 read 2.82-2.97 mm and P03 3.11-3.23 mm)
        thickness = float(truth[p["position"]]["thickness_m"])
        lo, hi = p["thickness_m"].get("ci95") or (None, None)
        assert p["thickness_m"]["status"] != "inconsistent", p
        assert (lo is None or lo <= thickness) and (hi is None or thickness <= hi), p
    assert png.read_bytes()[:4] == b"\x89PNG"
    res = run(build_cli(), ["map", str(est), "--plate-id", "OTHER"])
    assert res.exit_code == 2 and "SCAN-A" in res.stderr


def test_map_from_the_services_store(scanned, tmp_path):
    _, store = scanned
    res = CliRunner().invoke(build_cli(), ["map", str(store), "--plate-id", "SCAN-A", "--json"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["support"]["n_positions"] >= 6


@pytest.mark.slow
def test_a_freshly_simulated_scan_locates_the_edge_within_10_mm(tmp_path):
    """The scan simulated anew (about a minute): the bundled files are what this produces."""
    from solitonde.instrument.cli.cmd_samples import make_scan

    truth = {row["position"]: row for row in make_scan(tmp_path / "scan", seed=7)}
    est = tmp_path / "est.csv"
    run = CliRunner().invoke
    res = run(build_cli(), ["analyze", "--manifest", str(tmp_path / "scan" / "campaign.csv"),
                            "--estimates-out", str(est)])
    assert res.exit_code == 0, res.output
    res = run(build_cli(), ["map", str(est), "--plate-id", "SCAN-A", "--json"])
    plate_map = json.loads(res.stdout)
    assert plate_map["support"] is not None, plate_map["support_reason"]
    for p in plate_map["positions"]:
        assert abs(p["distance_to_located_support_m"] - truth[p["position"]]["x_m"]) < TOLERANCE_M


# --- the scan as one unknown: --joint, ?joint=true, suggestions -------------------------------


def _joint_checks(plate_map: dict) -> None:
    """The joint map of the bundled scan: today's shape plus the joint answer."""
    assert plate_map["joint"] is True
    support = plate_map["support"]
    assert support["model"] == "opposite_edges" and support["status"] == "located"
    assert support["second_offset_m"] == pytest.approx(support["offset_m"] + 0.914)
    assert {"chi2", "dof", "p_value"} <= set(plate_map["fit"])
    assert plate_map["fit"]["p_value"] > 1e-3
    assert isinstance(plate_map["warnings"], list)
    assert plate_map["thickness_prior"]["kind"] == "free"
    truth = _truth()
    narrower = 0
    for p in plate_map["positions"]:
        assert {"thickness_m", "distance_m", "per_position"} <= set(p)
        error = abs(p["distance_to_located_support_m"] - float(truth[p["position"]]["x_m"]))
        assert error < TOLERANCE_M, (p["position"], error)
        t, alone = p["thickness_m"], p["per_position"]["thickness_m"]
        if t["status"] == "constrained":
            assert t["ci95"][0] <= 3.0e-3 <= t["ci95"][1], p
            if alone["status"] == "constrained":
                narrower += (t["ci95"][1] - t["ci95"][0]) < (alone["ci95"][1] - alone["ci95"][0])
    assert narrower >= 4  # P02..P06 near the edge, P07 and P08 as sharp as alone


def test_map_joint_from_the_estimates_file_and_its_errors(tmp_path):
    """analyze --estimates-out keeps each position's per-size summaries: map --joint works from
    the file; bad flags exit 1 naming the flag and what is allowed."""
    est = tmp_path / "est.csv"
    run = CliRunner().invoke
    res = run(build_cli(), ["analyze", "--manifest", str(SCAN / "campaign.csv"),
                            "--estimates-out", str(est)])
    assert res.exit_code == 0, res.output
    with est.open() as fh:
        rows = list(csv.DictReader(fh))
    sizes = json.loads(rows[0]["size_summaries"])
    assert sizes[0]["diameter_m"] == pytest.approx(9.53e-3) and sizes[0]["n_shots"] == 3
    assert {"tof_s", "tof_std_s", "arr", "arr_std"} <= set(sizes[0])
    assert rows[0]["table"] == "default_table"
    png = tmp_path / "joint.png"
    res = run(build_cli(), ["map", str(est), "--plate-id", "SCAN-A", "--joint", "--suggest", "2",
                            "--json", "--out", str(png)])
    assert res.exit_code == 0, res.output
    plate_map = json.loads(res.stdout)
    _joint_checks(plate_map)
    assert len(plate_map["suggestions"]) == 2
    assert plate_map["suggestions_basis"]["objective"] == "edge"
    assert png.read_bytes()[:4] == b"\x89PNG"
    res = run(build_cli(), ["map", str(est), "--plate-id", "SCAN-A", "--joint"])
    assert res.exit_code == 0 and "joint: thickness free" in res.stdout
    assert "P02: thickness" in res.stdout and "(alone: thickness" in res.stdout
    for args, words in ((["--suggest", "21"], "--suggest: 21 (allowed: an integer 0..20)"),
                        (["--suggest", "two"], "--suggest: 'two' is not a whole number"),
                        (["--suggest-for", "corners"], "--suggest-for: 'corners' (allowed: "
                                                       "edge, thickness)"),
                        (["--thickness-prior", "smooth"], "--thickness-prior: 'smooth' "
                                                          "(allowed: free, common)"),
                        (["--thickness-prior", "common", "--thickness-spread", "0"],
                         "--thickness-spread: 0.0 (allowed: 0.001 to 1"),
                        (["--thickness-spread", "0.05"], "--thickness-spread: only with "
                                                         "--thickness-prior common")):
        res = run(build_cli(), ["map", str(est), "--plate-id", "SCAN-A", "--joint", *args])
        assert res.exit_code == 1, (args, res.output)
        assert words in res.stderr, (args, res.stderr)
    old = tmp_path / "old.csv"  # an estimates file from before the summaries were kept
    with est.open() as fh, old.open("w") as out:
        lines = list(csv.reader(fh))
        keep = [i for i, name in enumerate(lines[0]) if name != "size_summaries"]
        csv.writer(out).writerows([[line[i] for i in keep] for line in lines])
    res = run(build_cli(), ["map", str(old), "--plate-id", "SCAN-A", "--joint"])
    assert res.exit_code == 1 and "ESTIMATES_FILE_OR_STORE: position 'P01' has no per-size" \
        in res.stderr, res.stderr


def test_the_services_map_jointly_with_suggestions(scanned):
    client, store = scanned
    r = client.get("/v1/plates/SCAN-A/map", params={"joint": "true", "suggest": 2})
    assert r.status_code == 200, r.text
    plate_map = r.json()
    _joint_checks(plate_map)
    assert len(plate_map["suggestions"]) == 2
    for s in plate_map["suggestions"]:
        assert set(s) >= {"x_m", "y_m", "expected_gain"}
        assert 0 <= s["x_m"] <= 0.914 and 0 <= s["y_m"] <= 0.914 and s["expected_gain"] >= 0
    # suggestions without the joint answer: the positions keep their own answers
    plain = client.get("/v1/plates/SCAN-A/map", params={"suggest": 1}).json()
    assert plain["joint"] is False and len(plain["suggestions"]) == 1
    assert "per_position" not in plain["positions"][0]
    png = client.get("/v1/plates/SCAN-A/map.png", params={"joint": "true", "suggest": 2})
    assert png.status_code == 200 and png.content[:8] == b"\x89PNG\r\n\x1a\n"
    tied = client.get("/v1/plates/SCAN-A/map", params={"joint": "true",
                                                       "thickness_prior": "common",
                                                       "thickness_spread": 0.05}).json()
    assert tied["thickness_prior"]["kind"] == "common"
    assert tied["thickness_prior"]["spread_rel"] == 0.05
    for params, field in (({"suggest": 21}, "suggest"), ({"suggest": -1}, "suggest"),
                          ({"suggest": "x"}, "suggest"), ({"suggest_for": "corners"},
                                                          "suggest_for"),
                          ({"thickness_prior": "smooth"}, "thickness_prior"),
                          ({"thickness_spread": 0.05}, "thickness_spread"),
                          ({"thickness_prior": "common", "thickness_spread": 0},
                           "thickness_spread")):
        r = client.get("/v1/plates/SCAN-A/map", params={"joint": "true", **params})
        assert r.status_code == 422, (params, r.text)
        assert r.headers["content-type"].startswith("application/problem+json")
        assert r.json()["field"] == field, (params, r.json())
    res = CliRunner().invoke(build_cli(), ["map", str(store), "--plate-id", "SCAN-A", "--joint",
                                           "--json"])
    assert res.exit_code == 0, res.output
    _joint_checks(json.loads(res.stdout))


def test_an_edge_without_a_residual_prints_instead_of_failing() -> None:
    """A joint edge whose positions have no constrained distance has no rms residual (None):
    the map command says so rather than raising on None * 1e3."""
    from solitonde.instrument.cli.cmd_map import support_line

    edge = {"normal_angle_deg": 0.0, "offset_m": 0.001, "ci95_offset_m": [-0.002, 0.004],
            "n_positions": 3, "residual_m": None}
    assert support_line(edge).endswith("rms residual n/a (no position's distance is constrained)")
    assert support_line({**edge, "residual_m": 0.00022}).endswith("rms residual 0.22 mm")
