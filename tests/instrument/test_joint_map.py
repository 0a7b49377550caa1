"""The scan as one unknown (instrument.inference.joint_map) and the next position
(instrument.inference.suggest), on scans whose shots are the bundled table's own features with
noise: fast, and the truth is known exactly.

A scan here is a 3.0 mm plate of the paper's family whose clamped edge is a tilted line in the
scan's frame; each position's TOF and ARR are the table's at its distance from the nearer
support, with the per-shot scatter of a 40 dB recording over 5 shots.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from solitonde.instrument.inference import joint_map
from solitonde.instrument.inference.calibration import Calibration
from solitonde.instrument.inference.fine_grid import predict
from solitonde.instrument.inference.inversion import invert
from solitonde.instrument.inference.inversion_inputs import FeatureSummary
from solitonde.instrument.inference.suggest import check_request, suggest
from solitonde.instrument.tables.table import ModelTable

ROOT = Path(__file__).resolve().parents[2]
TABLE = ROOT / "data_samples" / "default_table.h5"
D = 9.53e-3
TOF_STD, ARR_STD, SHOTS = 60e-9, 0.004, 5


@pytest.fixture(scope="module")
def table() -> ModelTable:
    return ModelTable.load(TABLE)


class Edge:
    """A clamped edge x cos(theta) + y sin(theta) = offset, the opposite one a plate length
    further."""

    def __init__(self, angle_deg: float, offset_m: float, width_m: float = 0.914) -> None:
        self.theta = math.radians(angle_deg)
        self.offset = offset_m
        self.width = width_m
        self.n = np.array([math.cos(self.theta), math.sin(self.theta)])
        self.along = np.array([-self.n[1], self.n[0]])

    def point(self, distance_m: float, along_m: float) -> tuple[float, float]:
        p = self.offset * self.n + along_m * self.along + distance_m * self.n
        return float(p[0]), float(p[1])

    def distance(self, x: float, y: float) -> float:
        d = float(np.array([x, y]) @ self.n - self.offset)
        return min(d, self.width - d)


def measured(table: ModelTable, thickness: float, distance: float,
             rng: np.random.Generator) -> list[FeatureSummary]:
    """The table's features at (t, L) with the noise of 5 shots at 40 dB."""
    tof, arr = predict(table, D, thickness, distance)
    return [FeatureSummary(D, tof + TOF_STD / math.sqrt(SHOTS) * rng.standard_normal(),
                           arr + ARR_STD / math.sqrt(SHOTS) * rng.standard_normal(),
                           TOF_STD, ARR_STD, SHOTS)]


def scan(table: ModelTable, edge: Edge, placed: list[tuple[float, float]], thickness: float,
         seed: int = 0) -> list[joint_map.ScanPosition]:
    rng = np.random.default_rng(seed)
    out = []
    for k, (dist, along) in enumerate(placed):
        x, y = edge.point(dist, along)
        out.append(joint_map.ScanPosition(f"P{k + 1}", x, y,
                                          measured(table, thickness, dist, rng)))
    return out


NEAR = [(0.006, 0.10), (0.012, 0.55), (0.018, 0.30), (0.025, 0.75), (0.04, 0.20), (0.15, 0.45)]


def test_the_edge_and_each_thickness_come_from_one_posterior(table):
    """Six positions near a tilted edge: the located edge lies within 3 mm of the truth at
    every position, every thickness answer holds 3.0 mm, and near the edge the joint interval
    is narrower than the position's own."""
    edge = Edge(33.0, 0.12)
    positions = scan(table, edge, NEAR, 3.0e-3)
    post = joint_map.posterior(table, positions)
    out = joint_map.summary(post)
    s = out["support"]
    assert s["model"] == "opposite_edges" and s["status"] == "located"
    lo, hi = s["ci95_offset_m"]
    assert lo <= edge.offset <= hi, s
    for p, pos in zip(out["positions"], positions, strict=True):
        truth = edge.distance(pos.x_m, pos.y_m)
        assert abs(p["distance_to_located_support_m"] - truth) < 3e-3, (p, truth)
        d_lo, d_hi = p["distance_m"]["ci95"]
        assert d_lo <= truth <= d_hi
        t = p["thickness_m"]
        if t["status"] in ("constrained", "lower_bound_only", "upper_bound_only"):
            t_lo, t_hi = t["ci95"]
            assert (t_lo is None or t_lo <= 3.0e-3) and (t_hi is None or t_hi >= 3.0e-3), p
    narrower = 0
    for p, pos in zip(out["positions"][:4], positions[:4], strict=True):
        alone = invert(table, pos.inputs).thickness_m
        joint = p["thickness_m"]
        if alone.status == "constrained" and joint["status"] == "constrained":
            narrower += (joint["ci95"][1] - joint["ci95"][0]) < (alone.ci95[1] - alone.ci95[0])
    assert narrower >= 2
    assert out["fit"]["p_value"] > 1e-3 and not any(w.startswith("inconsistent")
                                                    for w in out["warnings"])
    assert out["thickness_prior"]["kind"] == "free"


def test_a_position_off_the_line_is_named_and_the_answer_inconsistent(table):
    """Coordinates recorded 40 mm off: the positions no longer agree with one straight edge."""
    edge = Edge(0.0, 0.0)
    placed = [(0.008, 0.10), (0.015, 0.30), (0.020, 0.50), (0.012, 0.70), (0.030, 0.85),
              (0.010, 0.40)]
    positions = scan(table, edge, placed, 3.0e-3, seed=1)
    positions[2] = joint_map.ScanPosition("P3", positions[2].x_m + 0.04, positions[2].y_m,
                                          positions[2].inputs)
    out = joint_map.summary(joint_map.posterior(table, positions))
    assert out["fit"]["p_value"] < 1e-3, out["fit"]
    assert out["warnings"][0].startswith("inconsistent: the positions do not agree with one "
                                         "straight clamped edge")
    assert "P3" in out["warnings"][0]
    assert out["support"]["status"] == "inconsistent"
    assert {p["thickness_m"]["status"] for p in out["positions"]} == {"inconsistent"}


# near the edge and out to 60 mm (beyond it, a 1.8-1.9 mm plate's model shows no reflection)
THIN = [(0.004, 0.05), (0.008, 0.62), (0.0115, 0.21), (0.026, 0.40), (0.06, 0.70), (0.008, 0.35)]


@pytest.mark.parametrize("thickness_m", [1.83e-3, 1.93e-3])
def test_a_thin_plates_scan_counts_its_parameters_and_is_not_flagged(table, thickness_m):
    """Six positions of a 1.8-1.9 mm plate, each the table's own features with noise: a right
    scan. The fit's p_D must come to about its parameters (six thicknesses and the edge's two):
    counted from the deviance, whose log-determinant varies across the posterior with the
    table's stated error (loose for weak reflections), it came to 11 and flagged the scan.
    The misfit's p_D equals the parameter count only for a linear-Gaussian model; the
    near-clamp positions' (t, L) ridges are curved, and on the bundled table it reads 6.4 and
    8.1 here, so one parameter's allowance, a third of the failure's excess."""
    positions = scan(table, Edge(12.0, 0.05), THIN, thickness_m)
    out = joint_map.summary(joint_map.posterior(table, positions))
    p_d = 2 * len(positions) - out["fit"]["dof"]
    assert 0.0 < p_d <= len(positions) + 2 + 1, out["fit"]
    assert out["fit"]["p_value"] > 1e-3, out["fit"]
    assert not any(w.startswith("inconsistent") for w in out["warnings"]), out["warnings"]


def test_a_common_mean_ties_the_positions_and_says_so(table):
    edge = Edge(90.0, 0.05)
    positions = scan(table, edge, NEAR, 3.0e-3, seed=2)
    free = joint_map.summary(joint_map.posterior(table, positions))
    tied = joint_map.summary(joint_map.posterior(table, positions,
                                                 joint_map.ThicknessPrior("common", 0.03)))
    prior = tied["thickness_prior"]
    assert prior["kind"] == "common" and prior["spread_rel"] == 0.03
    assert "3 %" in prior["description"]
    lo, hi = prior["mean_m"]["ci95"]
    assert lo <= 3.0e-3 <= hi
    widths = []
    for f, t in zip(free["positions"][:4], tied["positions"][:4], strict=True):
        if t["thickness_m"]["status"] == "constrained":
            t_lo, t_hi = t["thickness_m"]["ci95"]
            assert t_lo <= 3.0e-3 <= t_hi
            f_ci = f["thickness_m"]["ci95"] or [None, None]
            f_w = ((f_ci[1] or 6e-3) - (f_ci[0] or 1.5e-3))
            widths.append((t_hi - t_lo) / f_w)
    assert widths and max(widths) < 1.0


def test_bad_requests_name_the_field_and_what_is_allowed(table):
    for kwargs, field in (({"kind": "smooth"}, "thickness_prior"),
                          ({"kind": "common", "spread_rel": 0.0}, "thickness_spread"),
                          ({"kind": "common", "spread_rel": float("nan")}, "thickness_spread")):
        with pytest.raises(joint_map.JointMapError) as err:
            joint_map.ThicknessPrior(**kwargs)
        assert err.value.field == field and "allowed" in str(err.value)
    for n, objective, field in ((-1, "edge", "suggest"), (21, "edge", "suggest"),
                                (True, "edge", "suggest"), (2, "corners", "suggest_for")):
        with pytest.raises(joint_map.JointMapError) as err:
            check_request(n, objective)
        assert err.value.field == field and "allowed" in str(err.value)
    with pytest.raises(joint_map.JointMapError) as err:
        joint_map.posterior(table, [joint_map.ScanPosition("P1", float("nan"), 0.1, [])])
    assert err.value.field == "x_m"


def test_a_position_the_table_cannot_invert_is_left_out_by_name(table):
    edge = Edge(0.0, 0.0)
    positions = scan(table, edge, NEAR[:4], 3.0e-3, seed=3)
    odd = joint_map.ScanPosition("ODD", 0.3, 0.3, [FeatureSummary(12.7e-3, 5e-4, 0.5)])
    out = joint_map.summary(joint_map.posterior(table, [*positions, odd]))
    assert [e["position"] for e in out["excluded"]] == ["ODD"]
    assert any("ODD" in w and "left out" in w for w in out["warnings"])
    with pytest.raises(joint_map.JointMapError) as err:
        joint_map.posterior(table, [odd])
    assert err.value.field == "positions"


def test_the_suggested_position_teaches_more_than_the_plates_middle(table):
    """Three positions bunched at one end of the edge: measuring at the first suggestion
    (simulated from the table) shrinks the edge's interval more than measuring in the middle of
    the plate, and the suggestions lie on the plate, inside its rectangle."""
    edge = Edge(0.0, 0.0)
    placed = [(0.010, 0.10), (0.020, 0.16), (0.015, 0.22)]
    positions = scan(table, edge, placed, 3.0e-3, seed=4)
    post = joint_map.posterior(table, positions)
    found = suggest(post, 2, plate_size_m=[0.914, 0.914])
    assert len(found["suggestions"]) == 2
    assert found["interval_95_m"] > found["expected_interval_95_m"] > 0
    for s in found["suggestions"]:
        assert 0 <= s["x_m"] <= 0.914 and 0 <= s["y_m"] <= 0.914
        assert s["expected_gain"] >= 0
    first = found["suggestions"][0]
    assert found["suggestions"][0]["expected_gain"] >= found["suggestions"][1]["expected_gain"]

    def interval_after(x: float, y: float) -> float:
        rng = np.random.default_rng(5)
        extra = joint_map.ScanPosition("NEW", x, y, measured(table, 3.0e-3,
                                                               edge.distance(x, y), rng))
        after = joint_map.summary(joint_map.posterior(table, [*positions, extra]))
        lo, hi = after["support"]["ci95_offset_m"]
        return hi - lo

    assert interval_after(first["x_m"], first["y_m"]) < 0.8 * interval_after(0.457, 0.457)


def test_suggestions_for_the_thickness_map(table):
    edge = Edge(0.0, 0.0)
    positions = scan(table, edge, NEAR[:4], 3.0e-3, seed=6)
    found = suggest(joint_map.posterior(table, positions), 1, objective="thickness",
                    plate_size_m=[0.914, 0.914])
    assert found["objective"] == "thickness" and len(found["suggestions"]) == 1
    assert found["interval_95_m"] >= found["expected_interval_95_m"]


def test_a_calibration_error_enters_the_deviance_as_its_stated_quadratic(table):
    """``cell_likelihood(..., shared_calibration=True)`` leaves the calibration's uncertainty
    out and keeps how the deviance moves with its errors: at a TOF offset error eta the
    deviance is exactly the one with the offset moved by eta and no uncertainty stated."""
    from solitonde.instrument.inference.likelihood import cell_likelihood

    rng = np.random.default_rng(3)
    inputs = measured(table, 3.0e-3, 0.012, rng)
    stated = {"per_diameter": [{"diameter_m": D, "arr_factor": 1.0, "tof_offset_s": 1e-6,
                                "tof_offset_std_s": 10e-6}]}
    keep = cell_likelihood(table, inputs, stated, shared_calibration=True)
    assert keep["shared"] == [(D, "tof_offset_s", 10e-6)]
    for eta in (-7e-6, 4e-6):
        moved = cell_likelihood(table, inputs, {"per_diameter": [
            {"diameter_m": D, "arr_factor": 1.0, "tof_offset_s": 1e-6 + eta}]})["deviance"]
        quad = keep["deviance"] - 2 * eta * keep["shared_b"][0] + eta**2 * keep["shared_q"][0, 0]
        ok = np.isfinite(moved)
        assert np.array_equal(ok, np.isfinite(quad))
        assert np.allclose(quad[ok], moved[ok], rtol=1e-9, atol=1e-6)


def test_one_calibration_error_for_the_whole_scan(table):
    """A scan whose calibration's TOF offset is off by 8 us at every position (one
    calibration, one plate), with a stated uncertainty of 12 us as the study's calibration has.
    Counted per position, each position's TOF can be off by its own 12 us and the edge's angle
    stays loose; drawn once for the scan, the positions' TOFs agree on one offset, the scan
    says where it lies, and the edge's angle interval is much narrower, still holding the
    truth."""
    edge = Edge(-20.0, 0.05)
    placed = [(0.005, -0.30), (0.012, 0.28), (0.02, -0.05), (0.009, 0.10), (0.16, 0.0),
              (0.3, 0.2)]
    truth_offset = 8e-6
    positions = scan(table, edge, placed, 3.3e-3, seed=4)
    cal = {"per_diameter": [{"diameter_m": D, "arr_factor": 1.0, "tof_offset_s": 0.0,
                             "tof_offset_std_s": 12e-6}]}
    for p in positions:  # the instrument's offset is 8 us; the calibration states 0 +- 12 us
        p.inputs = [FeatureSummary(s.diameter_m, s.tof_s + truth_offset, s.arr, s.tof_std_s,
                                   s.arr_std, s.n_shots) for s in p.inputs]
        p.calibration = Calibration.from_any(cal)
    widths = {}
    for shared in (False, True):
        post = joint_map.posterior(table, positions, shared_calibration=shared)
        out = joint_map.summary(post)
        lo, hi = out["support"]["ci95_normal_angle_deg"]
        width = (hi - lo) % 360.0
        mid = (lo + 0.5 * width) % 360.0
        truth = math.degrees(edge.theta) % 360.0
        assert abs((truth - mid + 180.0) % 360.0 - 180.0) <= 0.5 * width, (shared, lo, hi)
        widths[shared] = width
        if shared:
            (err,) = out["shared_calibration"]
            assert err["quantity"] == "tof_offset_s" and err["stated_sd"] == 12e-6
            assert abs(err["error_mean"] - truth_offset) < 2.5 * err["error_sd"]
            assert err["error_sd"] < 0.3 * 12e-6
        else:
            assert out["shared_calibration"] == []
    assert widths[True] < 0.8 * widths[False], widths
