"""Another reading near a support: an answer whose 95 % interval leaves out a thickness the data
fit as well says so.

Next to a clamp a thinner plate nearer to it can give the features of a thicker one farther out.
The marginal posterior weighs the two by how much of the table's distance range fits each, so a
plate 30 mm from the clamp can read a few percent thick with a narrow interval. The two cases
below are `solitonde validate --n 200 --seed 0 --diameters 9.53e-3 --exact-material` plates
(5.392 mm at 30.2 mm and 4.783 mm at 30.5 mm from the clamp, simulated on the Mindlin plate with
contact damping at 1e-7 s, five shots at 40 dB): their measured summaries and the run's
calibration, fitted on its two reference plates, are copied here. Whatever the interval, the
truth must be inside it or inside the other reading the warning names.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from solitonde.instrument.inference.inversion import (
    LR_LEVELS,
    FeatureSummary,
    ParameterEstimate,
    _other_reading,
    invert,
)
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


@pytest.mark.parametrize("case", NEAR_CLAMP, ids=["5.39 mm at 30 mm", "4.78 mm at 30 mm"])
def test_a_thickness_left_out_next_to_a_clamp_is_named_as_another_reading(
        table: ModelTable, case: tuple[tuple[float, float], FeatureSummary]) -> None:
    (t_true, _), summary = case
    est = invert(table, [summary], CALIBRATION)
    assert est.thickness_m.status == "constrained" and not est.inconsistent
    lo, hi = est.thickness_m.ci95
    other = est.to_dict()["other_reading"]
    assert other is not None, est.to_dict()
    o_lo, o_hi = other["thickness_m"]
    assert lo <= t_true <= hi or o_lo <= t_true <= o_hi
    assert o_lo < lo and other["distance_m"] < 0.06  # a thinner plate, nearer the clamp
    warning = next(w for w in est.warnings if w.startswith("another reading fits as well"))
    assert f"{o_lo * 1e3:.3g}-{o_hi * 1e3:.3g} mm" in warning


def test_a_plate_far_from_the_supports_has_one_reading(table: ModelTable) -> None:
    est = invert(table, [FAR], CALIBRATION)
    assert est.thickness_m.status == "constrained"
    assert est.to_dict()["other_reading"] is None
    assert not any(w.startswith("another reading") for w in est.warnings)


def test_other_reading_needs_the_profile_beyond_the_interval_by_a_width() -> None:
    """On a log-uniform axis: a profile that falls as the interval does gives none; one with a
    second ridge two widths below the interval gives it, with its best distance."""
    t = np.geomspace(1.5e-3, 6e-3, 400)
    answer = ParameterEstimate(5.0e-3, 5.0e-3, (4.95e-3, 5.05e-3), (4.9e-3, 5.1e-3),
                               "constrained")
    best = np.where(t < 4.7e-3, 0.02, 0.3)

    def best_l(k: int) -> float:
        return float(best[k])

    one = np.exp(-0.5 * ((t - 5.0e-3) / 0.05e-3) ** 2)
    assert _other_reading(t, one, best_l, answer) is None
    two = np.maximum(one, np.where(np.abs(t - 4.5e-3) < 0.05e-3, 2 * LR_LEVELS[1], 0.0))
    other = _other_reading(t, two, best_l, answer)
    assert other is not None
    assert other["thickness_m"][0] == pytest.approx(4.45e-3, rel=0.01)
    assert other["distance_m"] == 0.02
    near = np.maximum(one, np.where(np.abs(t - 4.75e-3) < 0.01e-3, 2 * LR_LEVELS[1], 0.0))
    assert _other_reading(t, near, best_l, answer) is None  # 0.75 widths: within the reach
    open_answer = ParameterEstimate(None, None, (4.95e-3, None), (4.9e-3, None),
                                    "lower_bound_only")
    assert _other_reading(t, two, best_l, open_answer) is None


def test_the_service_answers_with_the_other_reading(tmp_path: Path) -> None:
    """POST /v1/invert with a near-clamp case and its calibration: the answer carries
    ``other_reading`` and the warning, as the command line's does."""
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
    lo, hi = body["other_reading"]["thickness_m"]
    assert lo <= t_true <= hi
    assert any(w.startswith("another reading fits as well") for w in body["warnings"])
