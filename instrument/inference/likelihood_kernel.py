"""A Gaussian term of the likelihood over every fine cell in one compiled pass; and Woodbury's
correction for the material's spread.

A term (a sphere size's TOF or ARR): its variance, residual, chi^2 share, the variances'
product and, with a material spread, its share of Woodbury's ``U^T D^-1 U`` and ``U^T D^-1 r``
(:mod:`.likelihood`). As numpy operations the same arithmetic walks the 114,000-cell grid about
twenty times per term and allocates as many temporaries; here it walks it once. (Tried and
slower: one pass over all terms, their arrays a tuple, which numba indexes through a branch per
access; one pass over a size's two terms, ten times slower as numba compiled it.) The
operations and their order per cell are numpy's (``_variance_residual``,
``Deviance.add_material``, ``Deviance.add_term`` in :mod:`.likelihood`), so the numbers are the
same to the bit; division follows numpy's rules (``error_model="numpy"``: a zero variance gives
inf, not an exception).

The kernels call nothing outside this module, so numba's own check of this file's timestamp
keeps their cache true (the package-wide cache key of :mod:`solitonde.model.jit_cache` is for
the kernels that inline across modules).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def add_term(model: np.ndarray, model_var: np.ndarray, u: np.ndarray, obs: np.ndarray,
             scale: np.ndarray, s2: np.ndarray, rel2: np.ndarray, unscaled: bool, has_rel: bool,
             has_u: bool, misfit: np.ndarray, det: np.ndarray, m3: np.ndarray, ur: np.ndarray
             ) -> None:
    """Add one term to ``misfit`` (chi^2), ``det`` (the variances' product) and, where
    ``has_u``, to ``m3`` (``U^T D^-1 U``'s upper entries) and ``ur`` (``U^T D^-1 r``).

    ``model``, ``model_var`` (n_t, n_l): the model's value and variance per cell; ``u``
    (2, n_t, n_l): the material's columns before the calibration's scale; per distance column
    (n_l): ``obs`` the measured value, ``scale`` the calibration's factor, ``s2`` the scatter's
    and calibration's variance, ``rel2`` a relative variance on the model; ``unscaled``: the
    scale is 1 everywhere (the model enters as it is); ``has_rel``: some ``rel2`` is not 0."""
    n_t, n_l = misfit.shape
    for i in range(n_t):
        for j in range(n_l):
            m = model[i, j]
            if unscaled:
                v = model_var[i, j] + s2[j]
                r = obs[j] - m
            else:
                sc = scale[j]
                v = model_var[i, j] * (sc * sc)
                v += s2[j]
                r = m * -sc
                r += obs[j]
            if has_rel:
                v += (m * m) * rel2[j]
            if has_u:
                u0 = u[0, i, j]
                u1 = u[1, i, j]
                if not unscaled:
                    u0 = u0 * scale[j]
                    u1 = u1 * scale[j]
                c0 = u0 / v
                c1 = u1 / v
                ur[0, i, j] += c0 * r
                ur[1, i, j] += c1 * r
                m3[0, i, j] += c0 * u0
                m3[1, i, j] += c0 * u1
                m3[2, i, j] += c1 * u1
            misfit[i, j] += (r * r) / v
            det[i, j] *= v


@njit(cache=True, error_model="numpy")
def woodbury(m3: np.ndarray, ur: np.ndarray, penalty: np.ndarray, misfit: np.ndarray,
             det: np.ndarray) -> None:
    """The material's rank-2 covariance applied per cell (:func:`.woodbury.solve2`'s closed
    form, in its order): ``misfit`` less ``b^T (I + M)^-1 b`` and ``det`` set to
    ``det (I + M)`` where the cell has features (``penalty`` finite), 1 elsewhere; the caller
    adds ``log(det)`` (numpy's log, as the numpy path takes it)."""
    n_t, n_l = misfit.shape
    for i in range(n_t):
        for j in range(n_l):
            if not np.isfinite(penalty[i, j]):
                det[i, j] = 1.0
                continue
            a00 = m3[0, i, j] + 1.0
            a01 = m3[1, i, j]
            a11 = m3[2, i, j] + 1.0
            d = a00 * a11 - a01 * a01
            b0 = ur[0, i, j]
            b1 = ur[1, i, j]
            misfit[i, j] -= (a11 * b0 * b0 - 2.0 * a01 * b0 * b1 + a00 * b1 * b1) / d
            det[i, j] = d


def warm() -> None:
    """Load (on a fresh install: compile) both kernels, on one cell with the argument types the
    likelihood passes."""
    one, three = np.ones((1, 1)), np.zeros((3, 1, 1))
    row = np.ones(1)
    add_term(one, one, np.zeros((2, 1, 1)), row, row, row, row, True, False, True, np.zeros((1, 1)),
             np.ones((1, 1)), three, np.zeros((2, 1, 1)))
    woodbury(three, np.zeros((2, 1, 1)), np.zeros((1, 1)), np.zeros((1, 1)), np.ones((1, 1)))
