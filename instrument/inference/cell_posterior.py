"""The normalised posterior on the fine (t, L) grid, kept where it can be non-zero.

The posterior is the likelihood ``exp(-chi^2 / 2)`` (over its best cell) times each cell's prior
mass (uniform in log t and in L). Most cells lie so far below the best that their posterior is
exactly 0 (``exp`` of an exponent under :data:`EXP_ZERO`): on a plate far from a support, where
the features do not depend on L, about a fifth of the 114,000 cells carry any weight, near a
support far fewer. Every sum the answer takes (the marginals, p_D, the material's shift) runs
over those cells only, in C order (the floor's and the strict share over the ones that carry
it, :data:`CARRYING`), and the grid-shaped density is made only where it is asked for (the
ridge's readings, ``return_posterior``).

Two builders give the same numbers to the bit: :func:`from_deviance` with numpy expressions
(a process without numba: ``solitonde invert``) and :func:`from_deviance_compiled` with the
compiled passes of :mod:`.posterior_kernel`. In both, numpy takes every exp and every sum, on
the same arrays.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from solitonde.instrument.inference.fine_grid import FineGrid

CARRYING = 1e-16
"""The share of the peak cell's weight from which a cell counts in the floor and strict shares
(:attr:`CellPosterior.carrying`): each cell left out holds under this share of the posterior
(the peak holds at most all of it), all of them together under 1e-11 on the fine grid, against
the shares' thresholds of 10 and 5 %."""
EXP_ZERO = -746.0
"""An exponent below which ``exp`` is exactly 0: below ln(2^-1075) = -745.13 the result is under
half the smallest subnormal and rounds to 0 (tests/instrument/test_likelihood_kernel.py checks
numpy's exp does)."""


@dataclass
class CellPosterior:
    """The posterior on the cells that may carry weight (every other cell's is exactly 0).

    ``cells`` are flat indices into the (t, L) grid in C order, ``rows`` and ``cols`` their
    thickness and distance indices; ``weight`` the normalised posterior there; ``over_best``
    the deviance over its minimum there (what p_D averages); ``mass_t``, ``mass_l`` the
    posterior mass of each thickness row and distance column (the marginals), summed in C
    order; ``profile_t``, ``profile_l`` the likelihood's maximum per row and per column (the
    profile likelihoods, before the prior; NaN where a cell's is)."""

    shape: tuple[int, int]
    cells: np.ndarray
    rows: np.ndarray
    cols: np.ndarray
    weight: np.ndarray
    over_best: np.ndarray
    mass_t: np.ndarray
    mass_l: np.ndarray
    profile_t: np.ndarray
    profile_l: np.ndarray

    @functools.cached_property
    def density(self) -> np.ndarray:
        """The normalised posterior on the whole grid (0 off :attr:`cells`)."""
        out = np.zeros(self.shape)
        out.ravel()[self.cells] = self.weight
        return out

    @functools.cached_property
    def carrying(self) -> Carrying:
        """The cells whose weight is at least :data:`CARRYING` of the largest: far fewer than
        the cells whose weight is not 0 (a Gaussian's 1e-16 lies at 8.6 standard deviations,
        its underflow at 39)."""
        at = np.flatnonzero(self.weight >= CARRYING * float(self.weight.max()))
        return Carrying(self.cells[at], self.cols[at], self.weight[at])


class Carrying(NamedTuple):
    """The cells that carry a posterior (:attr:`CellPosterior.carrying`): flat indices, distance
    columns and weights."""

    cells: np.ndarray
    cols: np.ndarray
    weight: np.ndarray


def from_deviance(chi2: np.ndarray, best: float, g0: FineGrid) -> CellPosterior:
    """The posterior of the deviance ``chi2`` (its least value ``best``) with numpy
    expressions."""
    over = chi2 - best
    exponent = over * -0.5
    cells = np.flatnonzero(~(exponent < EXP_ZERO))  # NaN kept, as the compiled pass keeps it
    like = np.exp(np.take(exponent, cells))
    rows, cols = np.divmod(cells, chi2.shape[1])
    weight = like * g0.weight_t[rows]  # prior mass of each cell: uniform in log t and in L
    weight *= g0.weight_l[cols]
    profile_t, profile_l = np.zeros(chi2.shape[0]), np.zeros(chi2.shape[1])
    np.maximum.at(profile_t, rows, like)
    np.maximum.at(profile_l, cols, like)
    weight /= np.sum(weight)
    # bincount adds each weight to its bin in the order given, as the compiled pass does
    mass_t = np.bincount(rows, weights=weight, minlength=chi2.shape[0])
    mass_l = np.bincount(cols, weights=weight, minlength=chi2.shape[1])
    return CellPosterior(chi2.shape, cells, rows, cols, weight, np.take(over, cells), mass_t,
                         mass_l, profile_t, profile_l)


def from_deviance_compiled(chi2: np.ndarray, best: float, row_min: np.ndarray, g0: FineGrid
                           ) -> CellPosterior:
    """:func:`from_deviance` to the bit in three compiled passes (:mod:`.posterior_kernel`),
    numpy's exp taken only on the cells where it is not exactly 0 (numpy's exp is the same per
    element whatever array it lies in, and takes a slow path, eight to fifty times its cost,
    where it underflows); the rows whose least value ``row_min`` lies that far above ``best``
    are not read."""
    from solitonde.instrument.inference.posterior_kernel import exponents, masses, weigh

    n_t, n_l = chi2.shape
    cells, rows, cols = (np.empty(chi2.size, dtype=np.intp) for _ in range(3))
    x, over = np.empty(chi2.size), np.empty(chi2.size)
    count = exponents(chi2, best, EXP_ZERO, row_min, cells, rows, cols, x, over)
    cells, rows, cols, over = cells[:count], rows[:count], cols[:count], over[:count]
    like = np.exp(x[:count], out=x[:count])
    weight = np.empty(count)
    profile_t, profile_l = np.empty(n_t), np.empty(n_l)
    weigh(rows, cols, like, g0.weight_t, g0.weight_l, weight, profile_t, profile_l)
    weight /= np.sum(weight)
    mass_t, mass_l = np.empty(n_t), np.empty(n_l)
    masses(rows, cols, weight, mass_t, mass_l)
    return CellPosterior((n_t, n_l), cells, rows, cols, weight, over, mass_t, mass_l, profile_t,
                         profile_l)
