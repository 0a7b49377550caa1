"""The map study (instrument.studies.map_study, `solitonde validate-map`): its random scans are
what it says they are, its scores count what they say; the study itself runs on demand
(`pytest -m slow`), the full one in docs/explanation/joint-map.md."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app as build_cli
from solitonde.instrument.studies import map_metrics, map_study
from solitonde.instrument.tables.table import ModelTable

ROOT = Path(__file__).resolve().parents[2]
TABLE = ROOT / "data_samples" / "default_table.h5"


@pytest.fixture(scope="module")
def table() -> ModelTable:
    return ModelTable.load(TABLE)


def test_a_random_scan_is_a_tilted_edge_with_positions_on_the_plate_near_it(table):
    angles = set()
    for seed in range(12):
        scan = map_study.Scan(table, seed, 9.53e-3)
        # the edge: near one of the rectangle's sides, tilted by at most the stated angle
        nominal = round(math.degrees(scan.theta) / 90.0) * 90.0
        tilt = (math.degrees(scan.theta) - nominal + 180.0) % 360.0 - 180.0
        assert abs(tilt) <= map_study.TILT_DEG + 1e-9
        angles.add(nominal % 360.0)
        assert map_study.POSITIONS[0] <= scan.n_positions <= map_study.POSITIONS[1]
        assert scan.edge_error(scan.theta, scan.offset_m) == pytest.approx(0.0, abs=1e-12)
        assert scan.edge_error(scan.theta, scan.offset_m + 0.004) == pytest.approx(0.004)
        lo_t, hi_t = table.axes["thickness_m"][[0, -1]]
        assert lo_t < scan.thickness_m < hi_t
        for x, y in scan.plate_positions:
            assert 0 <= x <= scan.a and 0 <= y <= scan.b
        for x, y in scan.random_positions:
            assert 0 <= x <= scan.a and 0 <= y <= scan.b
            d = scan.distance(x, y)
            assert map_study.DISTANCE_RANGE_M[0] - 1e-9 <= d <= map_study.DISTANCE_RANGE_M[1]
        # the span's ends lie on the edge and inside the rectangle
        for end in scan.ends:
            assert float(end @ scan.normal) == pytest.approx(scan.offset_m)
    assert len(angles) >= 3  # the clamped side is drawn, not always the same


def test_a_position_is_simulated_where_the_chain_stood_off_its_recorded_coordinates(table):
    """The study's positions keep their recorded coordinates, and their features are simulated
    at the distance of a chain standing off them by the joint map's stated coordinate error
    (1 mm per coordinate): over 200 positions the distance's offset has that sd (within 20 %,
    about 4 of its standard errors) and mean 0; exactly there when the error is 0."""
    scan = map_study.Scan(table, 3, 9.53e-3)
    asked: list[float] = []

    def measure(d: float, t: float, length: float, seed: int) -> list:
        asked.append(length)
        return []

    rng = np.random.default_rng(1)
    xy = [(float(rng.uniform(0.2, 0.7)), float(rng.uniform(0.2, 0.7))) for _ in range(200)]
    scan.coordinate_sd_m = 0.0
    exact = map_study._scan_positions(scan, xy, measure, None)
    assert asked == [scan.distance(x, y) for x, y in xy]
    assert [(p.x_m, p.y_m) for p in exact] == xy
    asked.clear()
    scan.coordinate_sd_m = 1e-3
    off = map_study._scan_positions(scan, xy, measure, None)
    assert [(p.x_m, p.y_m) for p in off] == xy  # the recorded coordinates
    shift = np.array(asked) - np.array([scan.distance(x, y) for x, y in xy])
    assert abs(shift.std() / 1e-3 - 1.0) < 0.2
    assert abs(shift.mean()) < 4 * 1e-3 / math.sqrt(len(xy))


def test_the_measurements_file_keeps_its_scene_and_refuses_another(tmp_path, monkeypatch):
    """Positions are simulated once (in parallel when asked) and kept with the scene they were
    simulated on and the extractor's reading: the same file for truths on another plate theory,
    or read another way, is refused by name, not mixed in."""
    calls: list[tuple] = []

    def fake(base, diameters, t, length, seed):
        calls.append((base.get("sem", {}).get("plate_theory", "auto"), t, length, seed))
        return {"summaries": {diameters[0]: {"diameter_m": diameters[0], "tof_s": 5e-4 + length,
                                             "arr": 0.5, "tof_std_s": 1e-7, "arr_std": 1e-3,
                                             "n_shots": 5}}}

    monkeypatch.setattr(map_study.single, "measure_plate", fake)
    path = tmp_path / "m.json"
    auto = {"sem": {"plate_theory": "auto"}}
    m = map_study.Measurer(auto, path)
    m.prefetch([(9.53e-3, 3e-3, 0.01, 1), (9.53e-3, 3e-3, 0.02, 2)], workers=1)
    m.prefetch([(9.53e-3, 3e-3, 0.02, 2)], workers=1)  # kept: not simulated again
    assert len(calls) == 2 and m.simulated == 2
    assert m(9.53e-3, 3e-3, 0.02, 2)[0].tof_s == pytest.approx(5e-4 + 0.02)
    assert len(calls) == 2
    m.save()
    assert map_study.Measurer(auto, path).cache == m.cache
    with pytest.raises(map_study.StudyInputError, match=r"another scene.*'3d'") as err:
        map_study.Measurer({"sem": {"plate_theory": "3d"}}, path)
    assert err.value.field == "measurements"
    # a file written before the reading was recorded was read with reading 1: refused
    path.write_text(json.dumps({"positions": m.cache}))
    with pytest.raises(map_study.StudyInputError,
                       match=r"read with the extractor's reading 1, this solitonde reads with 2"):
        map_study.Measurer(auto, path)
    # one written before the outlier level depended on the number of shots: refused
    path.write_text(json.dumps({"positions": m.cache, "reading_version": 2, "scene": auto}))
    with pytest.raises(map_study.StudyInputError, match=r"summarised by rule 1 .* by rule 2"):
        map_study.Measurer(auto, path)
    # one written before the scene was recorded holds the table's own tiers
    path.write_text(json.dumps({"positions": m.cache, "reading_version": 2,
                                "aggregate_version": 2}))
    assert map_study.Measurer(auto, path).cache == m.cache
    with pytest.raises(map_study.StudyInputError, match=r"its sem.plate_theory 'auto'"):
        map_study.Measurer({"sem": {"plate_theory": "3d"}}, path)
    # truths on the 3-D plate: kept with their mesh, and a file from before it is refused
    three_d = {"sem": {"plate_theory": "3d"}}
    m3 = map_study.Measurer(three_d, tmp_path / "m3.json")
    m3.prefetch([(9.53e-3, 3e-3, 0.01, 1)], workers=1)
    m3.save()
    assert map_study.Measurer(three_d, tmp_path / "m3.json").cache == m3.cache
    old = json.loads((tmp_path / "m3.json").read_text())
    del old["truth_mesh"]
    (tmp_path / "m3.json").write_text(json.dumps(old))
    with pytest.raises(map_study.StudyInputError, match=r"the 3-D plate's default mesh"):
        map_study.Measurer(three_d, tmp_path / "m3.json")


@pytest.mark.parametrize(("kwargs", "field"), [({"truth_plate_theory": "2d"}, "truth_plate_theory"),
                                               ({"workers": 0}, "workers")])
def test_the_study_refuses_a_truth_plate_theory_or_worker_count_it_does_not_know(table, kwargs,
                                                                                   field):
    with pytest.raises(map_study.StudyInputError) as err:
        map_study.run(table, 1, 0, **kwargs)
    assert err.value.field == field


def test_validate_map_names_the_flag_of_an_unknown_plate_theory(tmp_path):
    res = CliRunner().invoke(build_cli(), ["validate-map", "--scans", "1",
                                           "--truth-plate-theory", "2d"])
    assert res.exit_code == 1
    assert "--truth-plate-theory: must be one of auto, 3d, mindlin, got '2d'" in res.output


def test_an_edges_miss_is_scored_in_the_sds_its_interval_states():
    """A coverage over 30 scans resolves 0.967 from 1.000 and no finer; the rms of each miss
    over the sd its interval states says whether the intervals are as wide as the errors."""
    assert map_study._z(2.0, 1.0, 3.0) == 0.0
    assert map_study._z(3.0, 1.0, 3.0) == pytest.approx(1.96)
    assert map_study._z(0.0, 1.0, 3.0) == pytest.approx(-3.92)
    assert map_metrics._rms([1.0, None, -1.0, math.nan]) == pytest.approx(1.0)
    assert map_metrics._binomial_se([True] * 30) == pytest.approx(1 / 30)
    assert map_metrics._binomial_se([True] * 27 + [False] * 3) == pytest.approx(
        math.sqrt(0.9 * 0.1 / 30))


def test_the_edge_at_the_scan_is_scored_where_its_direction_is_fixed():
    """A scan whose positions do not fix the edge's direction (the joint map warns beyond
    WIDE_ANGLE_DEG) has no meaningful place of the edge at the scan: scored apart."""
    def scan_row(angle_width: float, at_scan_covered: bool, at_scan_z: float) -> dict:
        edge = {"ci95_offset_m": [0.0, 0.01], "covered": True, "error_m": 0.002,
                "fit": {"p_value": 0.5}, "angle_covered": True, "angle_ci95_width_deg":
                angle_width, "at_scan_covered": at_scan_covered, "at_scan_z": at_scan_z,
                "at_scan_ci95_width_m": 0.004, "lever_m": 0.4, "angle_z": 0.5}
        return {"thickness_m": 3e-3, "positions": [], "edge_free": edge, "edge_common": edge,
                "edge_alone": None}

    m = map_study.summarise([scan_row(5.0, True, 0.5), scan_row(10.0, False, 2.5),
                             scan_row(300.0, False, 22.0)])
    e = m["edge_free"]
    assert e["at_scan_coverage_95"] == pytest.approx(1 / 3)
    assert e["direction_fixed_scans"] == 2
    assert e["at_scan_coverage_95_direction_fixed"] == pytest.approx(0.5)
    assert e["at_scan_z_rms_direction_fixed"] == pytest.approx(math.sqrt((0.25 + 6.25) / 2))


def _row(thickness: float, positions: list[tuple[float, dict, dict, dict]],
         edges: dict, sequence: dict | None = None) -> dict:
    row = {"thickness_m": thickness, "positions": [
        {"distance_m": d, "alone": a, "free": f, "common": c} for d, a, f, c in positions]}
    row.update(edges)
    if sequence is not None:
        row["sequence"] = sequence
    return row


def test_the_summary_counts_coverage_widths_and_the_positions_to_the_target():
    ans = {"status": "constrained", "covered": True, "width_m": 1e-3}
    miss = {"status": "constrained", "covered": False, "width_m": 0.5e-3}
    none = {"status": "unconstrained", "covered": None, "width_m": 4.5e-3}
    edge = {"ci95_offset_m": [0.0, 0.004], "covered": True, "error_m": 0.002,
            "fit": {"p_value": 0.5}}
    rows = [
        _row(3e-3, [(0.01, none, ans, ans), (0.05, ans, miss, ans), (0.02, ans, ans, ans)],
             {"edge_alone": edge, "edge_free": edge, "edge_common": edge},
             {"suggested": {"errors_m": [0.02, 0.004, 0.003], "positions_to_target": 4},
              "random_near_edge": {"errors_m": [0.02, 0.01, 0.006], "positions_to_target": None},
              "random_on_plate": {"errors_m": [0.02, 0.02, 0.02], "positions_to_target": None}}),
        _row(2e-3, [(0.2, ans, ans, ans)],
             {"edge_alone": {"reason": "too few"},
              "edge_free": {**edge, "covered": False}, "edge_common": edge},
             {"suggested": {"errors_m": [0.01, 0.01, 0.004], "positions_to_target": 5},
              "random_near_edge": {"errors_m": [0.004, 0.004, 0.004], "positions_to_target": 3},
              "random_on_plate": {"errors_m": [0.004, 0.004, 0.004], "positions_to_target": 3}}),
    ]
    m = map_study.summarise(rows)
    assert m["thickness_alone"]["coverage_95"] == 1.0 and m["thickness_alone"]["answers"] == 3
    assert m["thickness_free"]["coverage_95"] == 0.75
    # within 30 mm: the 10 and 20 mm positions of the first scan (relative to its 3 mm)
    assert m["thickness_alone"]["near_edge_positions"] == 2
    assert m["thickness_alone"]["near_edge_width_median_m"] == pytest.approx(2.75e-3)
    assert m["thickness_free"]["near_edge_width_median_m"] == pytest.approx(1e-3)
    assert m["edge_alone"]["located"] == 1 and m["edge_free"]["coverage_95"] == 0.5
    s, r = m["sequence_suggested"], m["sequence_random_near_edge"]
    assert s["edge_error_median_m_by_positions"]["4"] == pytest.approx(0.007)
    assert s["reached_target"] == 2 and r["reached_target"] == 1
    # a scan that never reached the target counts as needing more than the maximum
    assert r["positions_to_target_median"] == pytest.approx((3 + map_study.MAX_POSITIONS + 1)
                                                            / 2)
    assert m["suggested_fewer_than_random_near_edge"] == 1
    assert m["suggested_more_than_random_near_edge"] == 1
    assert m["sequence_random_on_plate"]["reached_target"] == 1


def test_validate_map_refuses_bad_input_naming_the_flag(tmp_path):
    run = CliRunner().invoke
    res = run(build_cli(), ["validate-map", "--scans", "0"])
    assert res.exit_code == 1 and "--scans: must be an integer >= 1" in res.stderr
    res = run(build_cli(), ["validate-map", "--scans", "1", "--diameter", "0.0127"])
    assert res.exit_code == 1 and "--diameter" in res.stderr
    res = run(build_cli(), ["validate-map", "--out", str(tmp_path)])
    assert res.exit_code == 1 and "--out" in res.stderr
    res = run(build_cli(), ["validate-map", "--width-split", "--scans", "0"])
    assert res.exit_code == 1 and "--scans: must be an integer >= 1" in res.stderr


@pytest.mark.slow
def test_the_study_runs_end_to_end(tmp_path):
    """Two scans with the three ways of adding positions (a few minutes): every figure the docs
    print is there and every edge error is a number, not an error."""
    out = tmp_path / "study.json"
    res = CliRunner().invoke(build_cli(), ["validate-map", "--scans", "2", "--seed", "3",
                                           "--out", str(out), "--measurements",
                                           str(tmp_path / "m.json")])
    assert res.exit_code == 0, res.output
    assert "joint, thickness free: thickness coverage" in res.stdout
    assert "suggested needed fewer positions than random_on_plate" in res.stdout
    assert "the edge as the scan sees it: angle coverage" in res.stdout
    result = json.loads(out.read_text())
    for scan in result["scans"]:
        edge = scan["edge_free"]
        assert isinstance(edge["angle_covered"], bool) and edge["angle_ci95_width_deg"] > 0
        assert isinstance(edge["at_scan_covered"], bool) and edge["at_scan_ci95_width_m"] > 0
        for strategy in map_study.STRATEGIES:
            errors = scan["sequence"][strategy]["errors_m"]
            assert len(errors) == map_study.MAX_POSITIONS - map_study.START_POSITIONS + 1
            assert np.isfinite(errors).all(), (strategy, errors)
    # what a near-edge position's interval is made of, from the same measurements: each step
    # removes a source, so no step is wider than the one before it (a known distance only
    # narrows what the likelihood allows)
    split = map_study.width_split(ModelTable.load(TABLE), 2, 3,
                                  measurements=tmp_path / "m.json")
    if split["positions"]:
        medians = [split[s]["median_width_m"] for s in map_study.SPLIT_STEPS]
        assert medians[1] <= medians[0] + 1e-12 and medians[-1] <= medians[1] + 1e-12
