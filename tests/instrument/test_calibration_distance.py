"""A calibration whose TOF offset and ARR factor follow the distance to the support.

Next to a clamped support the model's mismatch is not the one far away (a TOF offset of +6 us
next to the clamp against +3.5 us far from it, here): references at two distances give a size's
factor and offset per distance (``by_distance``), read piecewise linear in 1/L between them and
constant beyond, and the inversion applies them at each cell's distance. A calibration without
``by_distance`` reads as before.

The synthetic chain here is the bundled table read at a Kuwabara-Kono damping (the layer's
middle slice), its TOF delayed by ``a + b / L`` (the near-field law that 1/L interpolation
between two references follows exactly): so the truth at a distance no reference saw is known.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app
from solitonde.instrument.inference.calibration import (
    MIN_DISTANCE_M,
    Calibration,
    CalibrationError,
)
from solitonde.instrument.inference.calibration_fit import Reference, fit_calibration
from solitonde.instrument.inference.fine_grid import predict
from solitonde.instrument.inference.inversion import invert
from solitonde.instrument.inference.inversion_inputs import FeatureSummary
from solitonde.instrument.inference.likelihood import cell_likelihood
from solitonde.instrument.tables import bundled
from solitonde.instrument.tables.dissipation import damped
from solitonde.instrument.tables.table import ModelTable

SIZES = (4.76e-3, 9.53e-3)
TAU_S = 1.2e-7
"""The chain's damping: one of the bundled layer's slices."""
NEAR_M, FAR_M = 0.005, 0.457
"""The references' distances: next to the clamp (a table node) and far from it."""
OFFSET_NEAR_S, OFFSET_FAR_S = 6e-6, 3.5e-6
B_S_M = (OFFSET_NEAR_S - OFFSET_FAR_S) / (1 / NEAR_M - 1 / FAR_M)
A_S = OFFSET_FAR_S - B_S_M / FAR_M
# shot scatter of a 40 dB recording, five shots per mean
TOF_STD_S, ARR_STD, SHOTS = 0.3e-6, 0.004, 5
REFERENCE_PLATES_M = (3.142e-3, 5.47e-3)


def true_offset(distance_m: float) -> float:
    """The synthetic chain's TOF offset against the model: ``a + b / L``."""
    return A_S + B_S_M / distance_m


@pytest.fixture(scope="module")
def table() -> ModelTable:
    return ModelTable.load(bundled.default_table())


@pytest.fixture(scope="module")
def chain(table: ModelTable) -> ModelTable:
    """The damped chain's features: the table read at :data:`TAU_S` for every size."""
    n = table.shape[0]
    return damped(table, [TAU_S] * n, [0.0] * n)


def shots(chain: ModelTable, t: float, distance_m: float,
          rng: np.random.Generator | None = None) -> list[FeatureSummary]:
    """One mean per sphere size of the synthetic chain at (t, L): its TOF delayed by the true
    offset there; with ``rng`` the means carry their shot noise."""
    out = []
    for d in SIZES:
        tof, arr = predict(chain, d, t, distance_m)
        tof += true_offset(distance_m)
        if rng is not None:
            tof += TOF_STD_S / math.sqrt(SHOTS) * rng.standard_normal()
            arr += ARR_STD / math.sqrt(SHOTS) * rng.standard_normal()
        out.append(FeatureSummary(d, tof, arr, TOF_STD_S, ARR_STD, SHOTS))
    return out


@pytest.fixture(scope="module")
def references(chain: ModelTable) -> list[Reference]:
    rng = np.random.default_rng(7)
    return [Reference(t, at, s) for at in (NEAR_M, FAR_M) for t in REFERENCE_PLATES_M
            for s in shots(chain, t, at, rng)]


@pytest.fixture(scope="module")
def by_distance(table: ModelTable, references: list[Reference]) -> Calibration:
    return fit_calibration(table, references)


def without_rows(cal: Calibration) -> Calibration:
    """The same calibration without ``by_distance``: one factor and offset per size, the
    combination over all its references."""
    data = cal.to_dict()
    for entry in data["per_diameter"]:
        entry.pop("by_distance", None)
    out = Calibration.from_any(data)
    assert out is not None
    return out


OLD_FILE = {
    "arr_factor": 0.9, "tof_offset_s": 2e-6,
    "per_diameter": [
        {"diameter_m": 4.76e-3, "arr_factor": 0.93, "arr_factor_std": 0.02,
         "tof_offset_s": 3e-6, "tof_offset_std_s": 0.5e-6, "n_references": 2},
        {"diameter_m": 9.53e-3, "arr_factor": 0.95, "arr_factor_std": 0.01,
         "tof_offset_s": 4e-6, "tof_offset_std_s": 0.4e-6, "damping_s": 1e-7,
         "damping_std_s": 1e-8}],
    "reference": None,
}


# Format -------------------------------------------------------------------------------------


def test_an_old_file_reads_back_as_it_was_and_inverts_as_its_scalars(
        tmp_path: Path, table: ModelTable, chain: ModelTable) -> None:
    path = tmp_path / "old.json"
    path.write_text(json.dumps(OLD_FILE))
    cal = Calibration.load(path)
    assert not cal.has_by_distance
    assert cal.to_dict() == OLD_FILE  # nothing added, nothing lost
    assert "by_distance" not in Calibration.load(cal.save(tmp_path / "again.json")).to_dict()[
        "per_diameter"][0]
    # no rows: the size's plain numbers at every distance, as floats
    for d in SIZES:
        got = cal.along(d, np.array([0.0, 0.01, 0.457]))
        assert got == (*cal.for_diameter(d), *cal.uncertainty_for(d))
        assert all(isinstance(v, float) for v in got)
    # rows that all state the entry's own numbers read as the plain numbers: the array path
    # over the grid's distances gives the scalar path's posterior (to rounding)
    data = json.loads(json.dumps(OLD_FILE))
    for e in data["per_diameter"]:
        e["by_distance"] = [{"distance_m": at, **{k: e[k] for k in (
            "arr_factor", "tof_offset_s", "arr_factor_std", "tof_offset_std_s")}}
            for at in (NEAR_M, 0.05, FAR_M)]
    rows = Calibration.from_any(data)
    assert rows is not None and rows.has_by_distance
    m = shots(chain, 3.0e-3, 0.0075)
    plain_est, rows_est = invert(table, m, cal), invert(table, m, rows)
    for name in ("thickness_m", "distance_m"):
        a, b = getattr(plain_est, name).to_dict(), getattr(rows_est, name).to_dict()
        assert a["status"] == b["status"], (name, a, b)
        for key in ("map", "median", "ci68", "ci95"):
            flat_a = a[key] if isinstance(a[key], list) else [a[key]]
            flat_b = b[key] if isinstance(b[key], list) else [b[key]]
            for x, y in zip(flat_a, flat_b, strict=True):
                assert (x is None) == (y is None), (name, key, a, b)
                assert x is None or x == pytest.approx(y, rel=1e-9), (name, key, a, b)
    assert plain_est.fit["chi2"] == pytest.approx(rows_est.fit["chi2"], rel=1e-9, abs=1e-12)
    # the joint map's shared offset error: the same sd and coefficients
    k_plain = cell_likelihood(table, m, cal, shared_calibration=True)
    k_rows = cell_likelihood(table, m, rows, shared_calibration=True)
    assert k_plain["shared"] == k_rows["shared"]
    ok = np.isfinite(k_plain["deviance"])
    np.testing.assert_array_equal(ok, np.isfinite(k_rows["deviance"]))
    np.testing.assert_allclose(k_rows["deviance"][ok], k_plain["deviance"][ok], rtol=1e-9,
                               atol=1e-9)
    np.testing.assert_allclose(k_rows["shared_b"], k_plain["shared_b"], rtol=1e-9, atol=1e-12)


def test_a_file_with_rows_round_trips(tmp_path: Path, by_distance: Calibration) -> None:
    back = Calibration.load(by_distance.save(tmp_path / "cal.json"))
    assert back.to_dict() == json.loads(json.dumps(by_distance.to_dict()))
    for d in SIZES:
        at = np.array([0.003, 0.0075, 0.05, 0.457])
        for a, b in zip(back.along(d, at), by_distance.along(d, at), strict=True):
            np.testing.assert_array_equal(a, b)


# Interpolation ------------------------------------------------------------------------------

ROWS = [
    {"distance_m": 0.005, "arr_factor": 0.90, "tof_offset_s": 6e-6, "arr_factor_std": 0.02,
     "tof_offset_std_s": 0.3e-6},
    {"distance_m": 0.020, "arr_factor": 0.96, "tof_offset_s": 4e-6, "arr_factor_std": 0.01,
     "tof_offset_std_s": 0.2e-6},
    {"distance_m": 0.457, "arr_factor": 0.98, "tof_offset_s": 3.5e-6},
]
D = 9.53e-3


@pytest.fixture(scope="module")
def rows_cal() -> Calibration:
    cal = Calibration.from_any({"per_diameter": [
        {"diameter_m": D, "arr_factor": 0.95, "tof_offset_s": 4.5e-6, "by_distance": ROWS}]})
    assert cal is not None
    return cal


def test_the_rows_are_read_at_their_distances(rows_cal: Calibration) -> None:
    f, o, f_sd, o_sd = rows_cal.along(D, np.array([r["distance_m"] for r in ROWS]))
    np.testing.assert_allclose(f, [r["arr_factor"] for r in ROWS], rtol=1e-14)
    np.testing.assert_allclose(o, [r["tof_offset_s"] for r in ROWS], rtol=1e-14)
    np.testing.assert_allclose(f_sd, [0.02, 0.01, 0.0], rtol=1e-14)  # not stated: 0
    np.testing.assert_allclose(o_sd, [0.3e-6, 0.2e-6, 0.0], rtol=1e-14)
    # a size without rows, or not listed: the plain numbers, whatever the distance
    assert rows_cal.along(4.76e-3, np.array([0.005, 0.2])) == (1.0, 0.0, 0.0, 0.0)


def test_between_rows_linear_in_inverse_distance(rows_cal: Calibration) -> None:
    # the midpoint in 1/L of 5 and 20 mm is 8 mm (not 12.5 mm): there the mean of the two rows
    mid = 2.0 / (1 / 0.005 + 1 / 0.020)
    assert mid == pytest.approx(0.008)
    f, o, _, o_sd = rows_cal.along(D, np.array([mid, 0.0125]))
    assert f[0] == pytest.approx(0.93, rel=1e-12)
    assert o[0] == pytest.approx(5e-6, rel=1e-12)
    assert o_sd[0] == pytest.approx(0.25e-6, rel=1e-12)
    # 12.5 mm: w = (1/0.0125 - 1/0.02) / (1/0.005 - 1/0.02) = 0.2 of the way to the near row
    assert o[1] == pytest.approx(4e-6 + 0.2 * 2e-6, rel=1e-12)
    assert o[1] < 0.5 * (6e-6 + 4e-6)  # linear in L would give the mean there
    # 100 mm, between the far rows
    w = (1 / 0.1 - 1 / 0.457) / (1 / 0.02 - 1 / 0.457)
    assert rows_cal.along(D, 0.1)[1] == pytest.approx(3.5e-6 + w * 0.5e-6, rel=1e-12)


def test_constant_beyond_the_rows_and_at_the_clamp(rows_cal: Calibration) -> None:
    f, o, _, _ = rows_cal.along(D, np.array([[0.0, -0.01, 0.002, 0.005],
                                             [0.457, 0.6, 1.0, 5.0]]))
    assert f.shape == o.shape == (2, 4)
    np.testing.assert_allclose(o[0], 6e-6, rtol=1e-14)
    np.testing.assert_allclose(o[1], 3.5e-6, rtol=1e-14)
    np.testing.assert_allclose(f[1], 0.98, rtol=1e-14)
    # a row at the clamp itself (L = 0) is read at MIN_DISTANCE_M, and so are 0 and below
    cal = Calibration.from_any({"per_diameter": [{"diameter_m": D, "by_distance": [
        {"distance_m": 0.0, "arr_factor": 0.9, "tof_offset_s": 7e-6},
        {"distance_m": 0.01, "arr_factor": 1.0, "tof_offset_s": 5e-6}]}]})
    assert cal is not None
    _, o, _, _ = cal.along(D, np.array([-1.0, 0.0, MIN_DISTANCE_M, 0.002, 0.01]))
    assert np.all(np.isfinite(o))
    np.testing.assert_allclose(o[:3], 7e-6, rtol=1e-14)
    w = (1 / 0.002 - 1 / 0.01) / (1 / MIN_DISTANCE_M - 1 / 0.01)
    assert o[3] == pytest.approx(5e-6 + w * 2e-6, rel=1e-12)


# Fit and use --------------------------------------------------------------------------------


def test_references_at_two_distances_give_the_offset_at_each(by_distance: Calibration) -> None:
    for d in SIZES:
        entry = by_distance.per_diameter[d]
        near, far = entry["by_distance"]
        assert near["distance_m"] == pytest.approx(NEAR_M)
        assert far["distance_m"] == pytest.approx(FAR_M)
        assert near["n_references"] == far["n_references"] == len(REFERENCE_PLATES_M)
        for row, truth in ((near, OFFSET_NEAR_S), (far, OFFSET_FAR_S)):
            # the stated sd: the shots' and the table's interpolation error, and the plates'
            # disagreement
            assert 0 < row["tof_offset_std_s"] < 0.5e-6, row
            assert abs(row["tof_offset_s"] - truth) <= 3 * row["tof_offset_std_s"], (
                d, row["tof_offset_s"], truth, row["tof_offset_std_s"])
        # the two distances told apart by many sds
        gap = near["tof_offset_s"] - far["tof_offset_s"]
        assert gap > 5 * math.hypot(near["tof_offset_std_s"], far["tof_offset_std_s"]), (d, gap)
        # the entry's own numbers stay the combination over all four references, whose
        # near-far disagreement shows as a transfer sd
        assert entry["n_references"] == 2 * len(REFERENCE_PLATES_M)
        assert far["tof_offset_s"] < entry["tof_offset_s"] < near["tof_offset_s"]
        assert entry["tof_offset_transfer_std_s"] > 0.5e-6, entry
        assert "damping_s" in entry  # one damping, fitted on all of them


def test_references_at_one_distance_give_no_rows(table: ModelTable,
                                                 references: list[Reference]) -> None:
    far = [r for r in references if r.distance_m == FAR_M]
    cal = fit_calibration(table, far)
    assert not cal.has_by_distance
    # within a millimetre is one distance
    nudged = far + [Reference(r.thickness_m, FAR_M - 0.0009, r.summary) for r in far]
    assert not fit_calibration(table, nudged).has_by_distance
    alone = fit_calibration(table, far[:len(SIZES)])  # one reference per size, as before
    assert all(e["n_references"] == 1 for e in alone.per_diameter.values())


def test_a_plate_near_the_clamp_is_read_with_its_own_offset(
        table: ModelTable, chain: ModelTable, by_distance: Calibration,
        references: list[Reference]) -> None:
    """A 3.0 mm plate 7.5 mm from the clamp, a distance no reference saw (true offset 5.2 us):
    the distance-aware calibration centres on it; one offset from the far references (the
    usual reference, far from the supports) reads it well thinner; the one offset over all
    references covers it only by a wider interval (its transfer sd holds the near-far gap)."""
    t, at = 3.0e-3, 0.0075
    m = shots(chain, t, at)
    aware = invert(table, m, by_distance).thickness_m
    combined = invert(table, m, without_rows(by_distance)).thickness_m
    far_only = invert(table, m, fit_calibration(
        table, [r for r in references if r.distance_m == FAR_M])).thickness_m
    numbers = (f"truth {t * 1e3:.3g} mm; by distance: {aware.status} median {aware.median} "
               f"95 % {aware.ci95}; one offset over all: {combined.status} median "
               f"{combined.median} 95 % {combined.ci95}; far references alone: "
               f"{far_only.status} median {far_only.median} 95 % {far_only.ci95}")
    assert aware.status == "constrained", numbers
    assert aware.ci95[0] <= t <= aware.ci95[1], numbers
    assert abs(aware.median - t) < 0.03 * t, numbers
    # the far references' offset (3.5 us) misses the 5.2 us there: the answer moves away
    assert far_only.median is not None, numbers
    assert abs(far_only.median - t) > max(0.1 * t, 3 * abs(aware.median - t)), numbers
    # one offset over all references: an honest but wider answer
    width = aware.ci95[1] - aware.ci95[0]
    wide = (math.inf if None in combined.ci95 else combined.ci95[1] - combined.ci95[0])
    assert wide > 1.5 * width, numbers


def test_a_plate_at_the_near_reference_distance(table: ModelTable, chain: ModelTable,
                                                by_distance: Calibration,
                                                references: list[Reference]) -> None:
    """2.4 mm at 5 mm from the clamp: the far references' offset leaves the truth out of its
    95 % interval, the distance-aware one holds it."""
    t = 2.4e-3
    m = shots(chain, t, NEAR_M)
    aware = invert(table, m, by_distance).thickness_m
    far_only = invert(table, m, fit_calibration(
        table, [r for r in references if r.distance_m == FAR_M])).thickness_m
    numbers = f"by distance: {aware.status} {aware.ci95}; far alone: {far_only.status} " \
              f"{far_only.ci95}"
    assert aware.ci95[0] <= t <= aware.ci95[1], numbers
    assert far_only.ci95[1] is not None and far_only.ci95[1] < t, numbers


# Validation ---------------------------------------------------------------------------------

GOOD_ROW = {"distance_m": 0.457, "arr_factor": 0.95, "tof_offset_s": 3.5e-6}
NEAR_ROW = {"distance_m": 0.005, "arr_factor": 0.9, "tof_offset_s": 6e-6}
BAD_ROWS = [
    ("near", "per_diameter[0].by_distance"),
    ([NEAR_ROW], "per_diameter[0].by_distance"),
    ([NEAR_ROW, 5], "per_diameter[0].by_distance[1]"),
    ([NEAR_ROW, {**GOOD_ROW, "tof_offset_s": "late"}],
     "per_diameter[0].by_distance[1].tof_offset_s"),
    ([NEAR_ROW, {**GOOD_ROW, "tof_offset_s": math.inf}],
     "per_diameter[0].by_distance[1].tof_offset_s"),
    ([NEAR_ROW, {k: v for k, v in GOOD_ROW.items() if k != "tof_offset_s"}],
     "per_diameter[0].by_distance[1].tof_offset_s"),
    ([NEAR_ROW, {**GOOD_ROW, "arr_factor": 0.0}], "per_diameter[0].by_distance[1].arr_factor"),
    ([NEAR_ROW, {**GOOD_ROW, "tof_offset_std_s": -1e-7}],
     "per_diameter[0].by_distance[1].tof_offset_std_s"),
    ([NEAR_ROW, {**GOOD_ROW, "n_references": 0}],
     "per_diameter[0].by_distance[1].n_references"),
    ([NEAR_ROW, {**GOOD_ROW, "plate": "A"}], "per_diameter[0].by_distance[1].plate"),
    ([{**NEAR_ROW, "distance_m": -0.001}, GOOD_ROW],
     "per_diameter[0].by_distance[0].distance_m"),
    ([GOOD_ROW, NEAR_ROW], "per_diameter[0].by_distance[1].distance_m"),  # not sorted
    ([NEAR_ROW, {**GOOD_ROW, "distance_m": 0.005}], "per_diameter[0].by_distance[1].distance_m"),
    ([{**NEAR_ROW, "distance_m": 0.0}, {**GOOD_ROW, "distance_m": MIN_DISTANCE_M / 2}],
     "per_diameter[0].by_distance[1].distance_m"),  # both read at MIN_DISTANCE_M
]


@pytest.mark.parametrize(("rows", "field"), BAD_ROWS,
                         ids=[f"{i}:{b[1]}" for i, b in enumerate(BAD_ROWS)])
def test_a_bad_row_names_its_field(tmp_path: Path, rows: object, field: str) -> None:
    path = tmp_path / "cal.json"
    path.write_text(json.dumps({"per_diameter": [
        {"diameter_m": D, "arr_factor": 0.95, "tof_offset_s": 4e-6, "by_distance": rows}]},
        allow_nan=True))
    with pytest.raises(CalibrationError) as info:
        Calibration.load(path)
    assert info.value.field == field, str(info.value)


# The command --------------------------------------------------------------------------------

SAMPLE = bundled.sample_waveforms() / "synthetic_D9.53_t4.83_snr40.csv"


def _run(*args: str):
    return CliRunner().invoke(build_app(), list(args))


def test_calibrate_takes_references_at_two_distances(tmp_path: Path) -> None:
    out = tmp_path / "cal.json"
    res = _run("calibrate", "--reference", f"4.83e-3,0.457,{SAMPLE}",
               "--reference", f"4.83e-3,0.01,{SAMPLE}", "--table",
               str(bundled.default_table()), "--out", str(out))
    assert res.exit_code == 0, res.output
    assert "at L = 10 mm" in res.output and "at L = 457 mm" in res.output, res.output
    cal = Calibration.load(out)
    (entry,) = cal.to_dict()["per_diameter"]
    assert [r["distance_m"] for r in entry["by_distance"]] == [0.01, 0.457]
    assert entry["n_references"] == 2
    # the same shots read against the model at 10 mm and at 457 mm: different offsets
    near, far = entry["by_distance"]
    assert abs(near["tof_offset_s"] - far["tof_offset_s"]) > 1e-6, entry
    res = _run("invert", "--table", str(bundled.default_table()), "--diameter", "0.00953",
               "--tof", "5.5e-4", "--arr", "0.3", "--calibration", str(out))
    assert res.exit_code == 0, res.output


@pytest.mark.parametrize(("args", "says"), [
    (["--reference", "4.83e-3,0.457"], "error: --reference:"),
    (["--reference", f"thick,0.457,{SAMPLE}"], "error: --reference:"),
    (["--reference", f"4.83e-3,-1,{SAMPLE}"], "error: --reference:"),
    (["--reference", "4.83e-3,0.457,/no/such/folder"], "error: --reference:"),
    (["--thickness", "4.83e-3", "--distance", "0.457"], "error: --thickness and --distance"),
    ([str(SAMPLE), "--thickness", "4.83e-3"], "error: give the reference plate's --thickness"),
])
def test_calibrate_refuses_a_bad_reference(tmp_path: Path, args: list[str], says: str) -> None:
    out = tmp_path / "cal.json"
    res = _run("calibrate", *args, "--table", str(bundled.default_table()), "--out", str(out))
    assert res.exit_code == 2, res.output
    assert res.output.startswith(says), res.output
    assert not out.exists()
