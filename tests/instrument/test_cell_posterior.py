"""The posterior kept on the cells that may carry weight: the compiled builder gives the numpy
builder's numbers to the bit (NaN, cells without features and rows far from the best included),
the rows it skips hold no such cell, and its sums over those cells are the grid's own sums
within rounding."""

from __future__ import annotations

from types import SimpleNamespace
from typing import cast

import numpy as np
import pytest

from solitonde.instrument.inference.cell_posterior import (
    EXP_ZERO,
    CellPosterior,
    from_deviance,
    from_deviance_compiled,
)
from solitonde.instrument.inference.fine_grid import FineGrid
from solitonde.instrument.inference.likelihood import _first_least
from solitonde.instrument.inference.posterior_kernel import total_and_best

N_T, N_L = 90, 40


def _grid() -> FineGrid:
    """The prior masses a fine grid carries (all the builders read of it)."""
    rng = np.random.default_rng(3)
    return cast(FineGrid, SimpleNamespace(weight_t=rng.uniform(0.5, 1.5, N_T),
                                          weight_l=rng.uniform(0.5, 1.5, N_L)))


def _deviance(nan_at: tuple[int, int] | None = None) -> np.ndarray:
    """A bowl in (t, L) a few hundred deep at its edges and thousands in the far rows (which
    hold no cell with weight), with cells without features (inf) and two equal minima."""
    t = np.linspace(-1.0, 1.0, N_T)[:, None]
    l_axis = np.linspace(-1.0, 1.0, N_L)[None, :]
    chi2 = 40.0 + 900.0 * (t - 0.1) ** 2 * (1.0 + 3.0 * (t > 0.6)) + 60.0 * l_axis**2
    chi2 = chi2 + 4000.0 * (t > 0.85)
    chi2[5, 7] = chi2[8, 30] = np.inf
    chi2[0, :] = np.inf  # a row without features anywhere
    i0 = int(np.argmin(chi2[:, 0]))
    chi2[i0, 3] = chi2[i0, 9] = 10.0  # two equal minima: np.argmin takes the first
    if nan_at is not None:
        chi2[nan_at] = np.nan
    return chi2


def _row_min(chi2: np.ndarray) -> tuple[np.ndarray, int]:
    """``total_and_best``'s row minima and best cell, in two bands as the likelihood's pass
    finds them."""
    parts = [chi2, np.zeros_like(chi2), np.zeros_like(chi2), np.zeros_like(chi2)]
    out, row_min = np.empty_like(chi2), np.empty(chi2.shape[0])
    bests = [total_and_best(*parts, out, row_min, a, b) for a, b in ((0, 37), (37, N_T))]
    assert np.array_equal(out, chi2, equal_nan=True)
    return row_min, _first_least(out, bests)


def _same(a: CellPosterior, b: CellPosterior) -> None:
    for name in ("cells", "rows", "cols", "weight", "over_best", "mass_t", "mass_l",
                 "profile_t", "profile_l", "density"):
        assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True), name


@pytest.mark.parametrize("nan_at", [None, (30, 11)])
def test_the_compiled_cells_are_numpys_to_the_bit(nan_at: tuple[int, int] | None) -> None:
    chi2 = _deviance(nan_at)
    row_min, at = _row_min(chi2)
    assert at == int(np.argmin(chi2))
    best = float(chi2.flat[at])
    g0 = _grid()
    compiled = from_deviance_compiled(chi2, best, row_min, g0)
    if nan_at is not None:
        with np.errstate(invalid="ignore"):
            reference = from_deviance(chi2.copy(), best, g0)
        _same(compiled, reference)
        assert np.isnan(compiled.weight).all()
        return
    _same(compiled, from_deviance(chi2.copy(), best, g0))
    skipped = (row_min - best) * -0.5 < EXP_ZERO
    assert skipped.sum() >= 10 and not np.isin(compiled.rows, np.flatnonzero(skipped)).any()


def test_the_sums_over_the_cells_are_the_grids_within_rounding() -> None:
    """Marginals, profiles and p_D from the cells against the same quantities over the whole
    grid (numpy's own order there, so they agree to rounding, not to the bit)."""
    chi2 = _deviance()
    row_min, at = _row_min(chi2)
    best = float(chi2.flat[at])
    g0 = _grid()
    cp = from_deviance_compiled(chi2, best, row_min, g0)
    over = chi2 - best
    like = np.exp(-0.5 * over)
    post = like * g0.weight_t[:, None] * g0.weight_l[None, :]
    post /= post.sum()
    assert cp.weight.sum() == pytest.approx(1.0, rel=1e-13)
    np.testing.assert_allclose(cp.density, post, rtol=1e-12, atol=0.0)
    np.testing.assert_allclose(cp.mass_t, post.sum(axis=1), rtol=1e-12, atol=1e-300)
    np.testing.assert_allclose(cp.mass_l, post.sum(axis=0), rtol=1e-12, atol=1e-300)
    assert np.array_equal(cp.profile_t, like.max(axis=1))
    assert np.array_equal(cp.profile_l, like.max(axis=0))
    finite = np.isfinite(over)
    p_d = float(np.sum(cp.weight * cp.over_best))
    assert p_d == pytest.approx(float(np.sum(post[finite] * over[finite])), rel=1e-12)
    assert np.count_nonzero(post) <= cp.cells.size == np.count_nonzero(-0.5 * over >= EXP_ZERO)
    assert cp.cells.size < 0.9 * chi2.size


def test_a_row_at_the_cut_is_read() -> None:
    """A row whose least value gives an exponent exactly at ``EXP_ZERO`` is read (its cell is
    kept, with weight 0, as the numpy builder keeps it); one just beyond is skipped."""
    chi2 = np.full((N_T, N_L), np.inf)
    chi2[10, 4] = 0.0
    chi2[20, 6] = -2.0 * EXP_ZERO  # exponent exactly EXP_ZERO
    chi2[30, 8] = np.nextafter(-2.0 * EXP_ZERO, np.inf)
    row_min, at = _row_min(chi2)
    assert at == 10 * N_L + 4
    g0 = _grid()
    cp = from_deviance_compiled(chi2, 0.0, row_min, g0)
    _same(cp, from_deviance(chi2.copy(), 0.0, g0))
    assert cp.cells.tolist() == [10 * N_L + 4, 20 * N_L + 6]
    assert cp.weight.tolist() == [1.0, 0.0]
