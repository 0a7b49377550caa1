"""The compiled likelihood and posterior passes against the numpy expressions they stand for, to
the bit: every term's chi^2, variance product and material sums, Woodbury's correction, the strict
chi^2 mask and p_D, with and without a calibration that follows the distance, with and without the
material's spread, for one and for three sphere sizes. (A process without numba loaded takes the
numpy expressions: the answer must not depend on which.)"""

from __future__ import annotations

import numpy as np
import pytest

import solitonde.instrument.inference.likelihood as lk
from solitonde.instrument.inference.fine_grid import predict
from solitonde.instrument.inference.inversion import invert
from solitonde.instrument.inference.inversion_inputs import FeatureSummary
from solitonde.instrument.inference.material_spread import spread_of
from solitonde.instrument.tables import bundled
from solitonde.instrument.tables.table import ModelTable

CALIBRATION = {
    "arr_factor": 0.97, "tof_offset_s": 2e-6,
    "per_diameter": [{
        "diameter_m": 9.53e-3, "arr_factor": 0.96, "tof_offset_s": 3e-6, "arr_factor_std": 0.01,
        "tof_offset_std_s": 4e-7,
        "by_distance": [
            {"distance_m": 0.005, "arr_factor": 0.95, "tof_offset_s": 5e-6,
             "arr_factor_std": 0.02, "tof_offset_std_s": 6e-7},
            {"distance_m": 0.457, "arr_factor": 0.97, "tof_offset_s": 3e-6,
             "arr_factor_std": 0.01, "tof_offset_std_s": 3e-7}]}]}


@pytest.fixture(scope="module")
def table() -> ModelTable:
    return ModelTable.load(bundled.default_table())


def _inputs(table: ModelTable, sizes: tuple[float, ...], t: float, at: float
            ) -> list[FeatureSummary]:
    out = []
    for k, d in enumerate(sizes):
        tof, arr = predict(table, d, t, at)
        out.append(FeatureSummary(d, tof * (1 + 2e-3 * (k - 1)), arr * 0.97, 3e-7, 0.004, 5))
    return out


@pytest.mark.parametrize("sizes", [(9.53e-3,), (4.76e-3, 9.53e-3, 19.05e-3)])
@pytest.mark.parametrize("calibration", [None, CALIBRATION], ids=["plain", "by_distance"])
@pytest.mark.parametrize("spread", [True, False], ids=["material", "exact"])
def test_the_compiled_deviance_is_numpys_to_the_bit(table: ModelTable, sizes: tuple[float, ...],
                                                    calibration: dict | None, spread: bool,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    from solitonde.instrument.inference.calibration import Calibration

    cal = Calibration.from_any(calibration)
    material = spread_of(table) if spread else None
    for t, at in ((3.1e-3, 0.012), (4.4e-3, 0.3)):
        items = _inputs(table, sizes, t, at)
        assert lk.use_compiled()  # numba is loaded in the test process
        compiled = lk.deviance(table, items, cal, material)
        with monkeypatch.context() as m:
            m.setattr(lk, "use_compiled", lambda: False)
            reference = lk.deviance(table, items, cal, material)
        for name in ("misfit", "logdet", "det", "penalty"):
            assert np.array_equal(getattr(compiled, name), getattr(reference, name)), name
        if spread:
            assert np.array_equal(compiled.m_sum, reference.m_sum)  # type: ignore[arg-type]
            assert np.array_equal(compiled.ur_sum, reference.ur_sum)  # type: ignore[arg-type]


def test_an_answer_is_the_same_to_the_bit_either_way(table: ModelTable,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """The whole answer, p_D and the strict share included, on answers that rest on floor cells
    (a 19.05 mm sphere on a 2 mm plate) with a calibration that follows the distance: the
    compiled passes give what the numpy expressions give."""
    import solitonde.instrument.inference.posterior as posterior
    from solitonde.instrument.inference.calibration import Calibration

    cal = Calibration.from_any(CALIBRATION)
    for t, at in ((2.0e-3, 0.2), (2.1e-3, 0.35)):
        items = _inputs(table, (9.53e-3, 19.05e-3), t, at)
        compiled = invert(table, items, cal, return_posterior=True)
        with monkeypatch.context() as m:
            m.setattr(lk, "use_compiled", lambda: False)
            m.setattr(posterior, "use_compiled", lambda: False)
            reference = invert(table, items, cal, return_posterior=True)
        assert compiled.extra["strict_explained"], "the 19.05 mm size rests on floor cells"
        assert compiled.extra == reference.extra
        assert compiled.to_dict() == reference.to_dict()
        assert np.array_equal(compiled.posterior["density"],  # type: ignore[index]
                              reference.posterior["density"])  # type: ignore[index]


@pytest.mark.parametrize("batch", [1, 4, 5])
def test_terms_split_at_the_logs_batches_are_numpys_to_the_bit(
        table: ModelTable, batch: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """Six terms (three sizes) with the variances' product logged every 1, 4 or 5 terms: the
    compiled pass takes them in chunks that end where a log is taken, as the numpy path does."""
    material = spread_of(table)
    items = _inputs(table, (4.76e-3, 9.53e-3, 19.05e-3), 3.1e-3, 0.012)
    monkeypatch.setattr(lk, "LOG_BATCH", batch)
    compiled = lk.deviance(table, items, None, material)
    with monkeypatch.context() as m:
        m.setattr(lk, "use_compiled", lambda: False)
        reference = lk.deviance(table, items, None, material)
    for name in ("misfit", "logdet", "det", "m_sum", "ur_sum"):
        assert np.array_equal(getattr(compiled, name), getattr(reference, name)), name


def test_a_tables_stacked_terms_are_kept_for_a_few_sets_of_sizes(table: ModelTable) -> None:
    """The stacked arrays of a set of sizes are made once and reused while the set is among the
    last few asked for; an older set is dropped (the cache stays bounded)."""
    material = spread_of(table)
    stacks = lk.StackCache.of(table)
    sets = [(4.76e-3,), (9.53e-3,), (19.05e-3,), (4.76e-3, 9.53e-3), (9.53e-3, 19.05e-3)]
    first = lk.deviance(table, _inputs(table, sets[0], 3.1e-3, 0.3), None, material)
    kept = next(reversed(stacks.kept.values()))[1]
    again = lk.deviance(table, _inputs(table, sets[0], 3.1e-3, 0.3), None, material)
    assert next(reversed(stacks.kept.values()))[1] is kept  # reused, not stacked again
    assert np.array_equal(first.misfit, again.misfit)
    for sizes in sets[1:]:
        lk.deviance(table, _inputs(table, sizes, 3.1e-3, 0.3), None, material)
    assert len(stacks.kept) == lk.STACKS_KEPT
    assert all(entry[1] is not kept for entry in stacks.kept.values())


def test_an_inversion_makes_no_blas_call(table: ModelTable, monkeypatch: pytest.MonkeyPatch
                                         ) -> None:
    """Once its fine grids are built, an inversion (material spread on, floor cells in the
    posterior) calls no ``np.dot``: OpenBLAS would hand a product over the grid to its worker
    threads, whose wake-up on a machine with busy cores (a table build beside the service) cost
    an inversion 10-30 ms instead of a few. The sums it needs are taken on its own thread, to
    the same value within rounding."""
    from solitonde.instrument.inference.woodbury import weighted_sum

    items = _inputs(table, (9.53e-3, 19.05e-3), 2.0e-3, 0.2)
    expected = invert(table, items)  # builds and caches the grids (their products use BLAS)

    def no_blas(*args: object, **kwargs: object) -> None:
        raise AssertionError("np.dot called during an inversion")

    with monkeypatch.context() as m:
        m.setattr(np, "dot", no_blas)
        again = invert(table, items)
    assert again.to_dict() == expected.to_dict()
    assert again.extra["floor_mass"] == expected.extra["floor_mass"]
    assert expected.extra["floor_mass"][19.05e-3] > 0.1, "the 19.05 mm size rests on floor cells"
    rng = np.random.default_rng(0)
    w, a = rng.random((481, 238)), rng.random((481, 238))
    assert weighted_sum(w, a) == pytest.approx(float(np.dot(w.ravel(), a.ravel())), rel=1e-12)


def test_exp_is_exactly_zero_below_the_compiled_posteriors_cut() -> None:
    """The compiled posterior hands numpy's exp only the exponents from ``EXP_ZERO`` up and
    writes 0 for the others: numpy's exp must give exactly 0 there."""
    from solitonde.instrument.inference.cell_posterior import EXP_ZERO

    below = np.concatenate([np.linspace(EXP_ZERO - 100.0, EXP_ZERO, 100_001)[:-1],
                            [np.nextafter(EXP_ZERO, -np.inf), -1e300, -np.inf]])
    assert not np.exp(below).any()


def test_the_compiled_best_cell_is_numpys() -> None:
    """``total_and_best`` sums the deviance's parts in ``Deviance.total``'s order and picks the
    cell ``np.argmin`` picks: the first of equal minima, the first NaN where there is one."""
    from solitonde.instrument.inference.posterior_kernel import total_and_best

    rng = np.random.default_rng(1)
    parts = [rng.random((7, 5)) for _ in range(4)]
    parts[0][2, 3] = parts[0][4, 1] = -1.0  # two equal minima (the others' parts equal too)
    for p in parts[1:]:
        p[2, 3] = p[4, 1] = 0.25
    parts[2][0, 0] = np.inf
    for nan_at in (None, (3, 2), (6, 4)):
        if nan_at is not None:
            parts[1][nan_at] = np.nan
        out, row_min = np.empty((7, 5)), np.empty(7)
        at = total_and_best(*parts, out, row_min, 0, 7)
        expected = parts[0] + parts[1] + parts[2] + parts[3]
        assert np.array_equal(out, expected, equal_nan=True)
        assert np.array_equal(row_min, expected.min(axis=1), equal_nan=True)
        assert at == int(np.argmin(expected))
        assert np.array_equal(out.flat[at], expected.min(), equal_nan=True)


def test_the_fits_p_value_is_scipys_chi2_sf() -> None:
    """The adequacy check's p-value calls ``chdtrc`` itself: what ``chi2.sf`` gives, to the
    bit, at and below 0 and over the range a fit reaches."""
    from scipy.stats import chi2

    from solitonde.instrument.inference.adequacy import _chi2_sf

    for dof in (1.0, 1.7, 4.0, 5.93, 12.0):
        for x in (-1e-12, 0.0, 1e-300, 0.3, 1.0, 4.2, 33.0, 1e3, 1e5, 1e300):
            assert _chi2_sf(x, dof) == float(chi2.sf(x, dof)), (x, dof)


def test_a_term_not_in_single_precision_is_refused(table: ModelTable) -> None:
    """The pass streams the variances and material columns as float32; a value float32 does not
    hold exactly (one not rounded where it was made) is refused, not silently rounded, so the
    compiled and numpy paths cannot part."""
    from solitonde.instrument.inference.fine_grid import fine_grid

    g = fine_grid(table, 0)
    assert np.array_equal(g.model_tof_var.astype(np.float32), g.model_tof_var)
    term = (g.tof_s, g.model_tof_var * (1.0 + 1e-12), 1.0, 1.0, 0.0, 0.0, None)
    with pytest.raises(ValueError, match="single-precision"):
        lk.StackCache().get([term])


def test_the_adequacy_sums_over_the_carrying_cells_are_the_whole_posteriors(
        table: ModelTable, monkeypatch: pytest.MonkeyPatch) -> None:
    """The floor share and the strict share are summed over the cells with at least CARRYING of
    the peak's weight: against every cell with weight (CARRYING 0) they differ by less than
    1e-10, on answers resting on floor cells."""
    import solitonde.instrument.inference.cell_posterior as cell_posterior

    for t, at in ((2.0e-3, 0.2), (2.1e-3, 0.35)):
        items = _inputs(table, (9.53e-3, 19.05e-3), t, at)
        est = invert(table, items)
        with monkeypatch.context() as m:
            m.setattr(cell_posterior, "CARRYING", 0.0)
            every = invert(table, items)
        assert est.extra["floor_mass"][19.05e-3] > 0.1 and est.extra["strict_explained"]
        for key in ("floor_mass", "strict_explained"):
            assert est.extra[key].keys() == every.extra[key].keys()
            for d, value in est.extra[key].items():
                assert abs(value - every.extra[key][d]) < 1e-10, (key, d)
