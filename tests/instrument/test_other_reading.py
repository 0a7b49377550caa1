"""Another reading near a support: an answer never leaves out a thickness the data fit as well.

Next to a clamp a thinner plate nearer to it can give the features of a thicker one farther out.
The marginal posterior weighs the two by how much of the table's distance range fits each, so a
plate 30 mm from the clamp read a few percent thick with a narrow interval that missed it
(5.47-5.79 mm for 5.39). The answer now reaches over what the profile likelihood holds (one group:
a wider interval that says why) or, where the data fit separate groups, is ``ambiguous`` with a
reading per group (instrument.inference.ridge). The two cases below are `solitonde validate --n 200
--seed 0 --diameters 9.53e-3 --exact-material` plates (5.392 mm at 30.2 mm and 4.783 mm at 30.5 mm
from the clamp, simulated on the Mindlin plate with contact damping at 1e-7 s, five shots at 40
dB): their measured summaries and the run's calibration, fitted on its two reference plates, are
copied here. The truth must be inside the interval, or inside one of the readings.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from solitonde.instrument.inference import ridge
from solitonde.instrument.inference.inversion import invert
from solitonde.instrument.inference.inversion_inputs import FeatureSummary
from solitonde.instrument.inference.marginals import LR_LEVELS, ParameterEstimate
from solitonde.instrument.tables.table import ModelTable

DEFAULT_TABLE = Path(__file__).resolve().parents[2] / "data_samples" / "default_table.h5"
D = 9.53e-3
CALIBRATION = {"per_diameter": [{
    "diameter_m": D, "arr_factor": 1.0001179170044248, "arr_factor_std": 0.0,
    "arr_factor_transfer_std": 0.0, "tof_offset_s": 4.558358455853684e-08,
    "tof_offset_std_s": 2.7744363556927e-07, "tof_offset_transfer_std_s": 2.3673435720267744e-07,
    "n_references": 2, "damping_s": 9.85e-08, "damping_std_s": 3.75e-09}]}
NEAR_CLAMP = [  # truth (t, L) and the measured summary
    ((5.392114412697102e-3, 30.199701002902157e-3),
     FeatureSummary(D, 5.176375248375769e-4, 0.5879628816886797, 4.3836736952711556e-08,
                    0.0010318017550152423, 5)),
    ((4.782608309065217e-3, 30.477334006565344e-3),
     FeatureSummary(D, 5.241692601549293e-4, 0.5176715274875654, 5.384702538060575e-08,
                    0.0007284505770788305, 5)),
]
FAR = FeatureSummary(D, 5.174950925361148e-4, 0.5786411391240239, 2.1511470142049927e-08,
                     0.0018777097190138127, 4)
"""The same run's reference plate: 5.5 mm, 457 mm from the clamp."""


@pytest.fixture(scope="module")
def table() -> ModelTable:
    return ModelTable.load(DEFAULT_TABLE)


def _covers(ci: object, truth: float) -> bool:
    lo, hi = ci  # type: ignore[misc]
    return (lo is None or lo <= truth) and (hi is None or truth <= hi)


@pytest.mark.parametrize("case", NEAR_CLAMP, ids=["5.39 mm at 30 mm", "4.78 mm at 30 mm"])
def test_a_thickness_that_fits_as_well_next_to_a_clamp_is_not_left_out(
        table: ModelTable, case: tuple[tuple[float, float], FeatureSummary]) -> None:
    (t_true, _), summary = case
    est = invert(table, [summary], CALIBRATION)
    assert not est.inconsistent
    if est.thickness_m.status == "ambiguous":
        assert any(_covers(r.thickness_m.ci95, t_true) for r in est.readings)
    else:
        assert est.thickness_m.status == "constrained"
        assert _covers(est.thickness_m.ci95, t_true), est.to_dict()
        # reached below the marginal's interval and says why: the 5.39 mm plate's marginal
        # misses it; the 4.78 mm plate's, read with the Mindlin nodes at the dashpot's level,
        # holds it by 15 um
        widened = est.extra["ridge_widened"]
        assert t_true >= widened["ci95"][0]
        assert (widened["marginal_ci95"][0] > t_true) == (t_true > 5e-3)
    warning = next(w for w in est.warnings if w.startswith("another reading fits as well"))
    lo, hi = est.thickness_m.ci95
    assert f"{lo * 1e3:.3g}-{hi * 1e3:.3g} mm" in warning


def test_a_plate_far_from_the_supports_has_one_reading(table: ModelTable) -> None:
    est = invert(table, [FAR], CALIBRATION)
    assert est.thickness_m.status == "constrained"
    assert est.to_dict()["other_reading"] is None and est.readings == []
    assert "ridge_widened" not in est.extra
    assert not any(w.startswith("another reading") for w in est.warnings)


def _ridge_case(profile_of_t: np.ndarray, best_l: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A (t, L) posterior whose profile over L is ``profile_of_t``, reached at ``best_l[i]``
    (one cell per thickness), on uniform prior cells; with its t and L axes and cell widths."""
    t = np.geomspace(1.5e-3, 6e-3, profile_of_t.size)
    l_axis = np.linspace(0.0, 0.4, 161)
    like = np.zeros((t.size, l_axis.size))
    for i, (p, l_best) in enumerate(zip(profile_of_t, best_l, strict=True)):
        like[i] = p * np.exp(-0.5 * ((l_axis - l_best) / 0.004) ** 2)
    w_t, w_l = np.full(t.size, np.log(4.0) / t.size), np.full(l_axis.size, 0.4 / 160)
    post = like * w_t[:, None] * w_l[None, :]
    return t, l_axis, post / post.sum(), w_t, w_l


def test_two_separate_groups_make_an_ambiguous_answer_with_two_readings() -> None:
    """A profile with a second hump below the marginal's interval, the gap between them below
    the 95 % level: two readings, each with its thickness span and the distance it fits at,
    weights summing to 1, the answer's interval their hull."""
    n = 400
    log_t = np.log(np.geomspace(1.5e-3, 6e-3, n))
    main = np.exp(-0.5 * ((log_t - np.log(5.0e-3)) / 0.01) ** 2)
    second = 0.5 * np.exp(-0.5 * ((log_t - np.log(4.0e-3)) / 0.01) ** 2)
    profile = np.maximum(main, second)
    best_l = np.where(log_t < np.log(4.5e-3), 0.02, 0.3)
    t, l_axis, post, w_t, w_l = _ridge_case(profile, best_l)
    answer = ParameterEstimate(5.0e-3, 5.0e-3, (4.95e-3, 5.05e-3), (4.9e-3, 5.1e-3),
                               "constrained")
    distance = ParameterEstimate(0.3, 0.3, (0.29, 0.31), (0.28, 0.32), "constrained")
    got_t, got_l, readings = ridge.resolve(answer, distance, t, l_axis, lambda: post, w_t, w_l,
                                           profile, lower_physical=True)
    assert got_t.status == "ambiguous" and len(readings) == 2
    assert sum(r.weight for r in readings) == pytest.approx(1.0)
    thin = next(r for r in readings if r.thickness_m.median < 4.5e-3)
    assert thin.thickness_m.ci95[0] < 4.0e-3 < thin.thickness_m.ci95[1] < 4.9e-3
    assert abs(thin.distance_m.median - 0.02) < 0.01
    assert got_t.ci95 == (min(r.thickness_m.ci95[0] for r in readings),
                          max(r.thickness_m.ci95[1] for r in readings))
    assert got_l.status == "ambiguous"  # 20 mm and 300 mm share no interval


def test_one_group_reaching_beyond_widens_the_interval_and_a_slight_reach_does_not() -> None:
    """A profile ridge that runs on below the marginal's interval (connected to it above the
    95 % level) widens it down to where the profile crosses that level; a profile barely wider
    than the interval (a cell near the support fitting a little off) leaves it as it is."""
    n = 400
    log_t = np.log(np.geomspace(1.5e-3, 6e-3, n))
    centre, sd = np.log(5.0e-3), 0.01
    answer = ParameterEstimate(5.0e-3, 5.0e-3, (np.exp(centre - sd), np.exp(centre + sd)),
                               (np.exp(centre - 1.96 * sd), np.exp(centre + 1.96 * sd)),
                               "constrained")
    distance = ParameterEstimate(None, None, (0.1, None), (0.05, None), "lower_bound_only")
    ridge_profile = np.where(log_t < centre, np.maximum(
        np.exp(-0.5 * ((log_t - centre) / sd) ** 2), 0.5 * (log_t > centre - 6 * sd)),
        np.exp(-0.5 * ((log_t - centre) / sd) ** 2))
    t, l_axis, post, w_t, w_l = _ridge_case(ridge_profile, np.full(n, 0.3))
    got, _, readings = ridge.resolve(answer, distance, t, l_axis, lambda: post, w_t, w_l,
                                     ridge_profile, lower_physical=True)
    assert readings == [] and got.status == "constrained"
    assert got.ci95[0] == pytest.approx(np.exp(centre - 6 * sd), rel=0.01)
    # above, the run crosses the level where the Gaussian's own 95 % bound is (linear between
    # grid points: within a tenth of a cell)
    assert got.ci95[1] == pytest.approx(answer.ci95[1], rel=3e-4)
    slight = np.exp(-0.5 * ((log_t - centre) / (1.1 * sd)) ** 2)
    got, _, _ = ridge.resolve(answer, distance, t, l_axis, lambda: post, w_t, w_l, slight,
                              lower_physical=True)
    assert got.ci95 == answer.ci95
    assert LR_LEVELS[1] < 0.5  # the ridge's plateau is inside the 95 % set


def test_a_one_sided_bound_moved_by_under_one_percent_is_left_and_a_longer_reach_widens_it(
        ) -> None:
    """An "at most" answer whose profile's 95 % set ends 0.5 % past its bound keeps its bound
    (and gets no "another reading"); one whose profile runs on 5 % past it is widened to there."""
    n = 800
    log_t = np.log(np.geomspace(1.5e-3, 6e-3, n))
    bound = 2.0e-3
    answer = ParameterEstimate(None, None, (None, 1.9e-3), (None, bound), "upper_bound_only")
    distance = ParameterEstimate(None, None, (0.1, None), (0.05, None), "lower_bound_only")
    for past, widened in ((0.005, False), (0.05, True)):
        end = np.log(bound) + past
        profile = np.where(log_t <= end, 1.0, np.exp(-0.5 * ((log_t - end) / 0.002) ** 2))
        t, l_axis, post, w_t, w_l = _ridge_case(profile, np.full(n, 0.3))
        got, _, readings = ridge.resolve(answer, distance, t, l_axis, post.copy, w_t, w_l,
                                         profile, lower_physical=True)
        assert readings == [] and got.status == "upper_bound_only"
        if widened:
            assert got.ci95[1] == pytest.approx(bound * np.exp(past), rel=0.01)
        else:
            assert got.ci95 == answer.ci95


def test_the_service_answers_with_the_reading_that_holds_the_truth(tmp_path: Path) -> None:
    """POST /v1/invert with a near-clamp case and its calibration: the answer holds the truth
    and carries the warning, as the command line's does."""
    from fastapi.testclient import TestClient

    from solitonde.instrument.service.app import build_app
    from solitonde.instrument.service.settings import Settings

    (t_true, _), summary = NEAR_CLAMP[0]
    settings = Settings(store_path=tmp_path / "s.sqlite", table_path=DEFAULT_TABLE)
    with TestClient(build_app(settings)) as client:
        r = client.post("/v1/invert", json={"inputs": [vars(summary)],
                                            "calibration": CALIBRATION})
    assert r.status_code == 200, r.text
    body = r.json()["estimate"]
    spans = [body["thickness_m"]["ci95"]] + [x["thickness_m"]["ci95"] for x in body["readings"]]
    assert any(_covers(ci, t_true) for ci in spans if ci)
    assert any(w.startswith("another reading fits as well") for w in body["warnings"])
