"""The likelihood's Gaussian terms over every fine cell in one compiled pass, with Woodbury's
correction for the material's spread.

A term (a sphere size's TOF or ARR): its variance, residual, chi^2 share, the variances'
product and, with a material spread, its share of Woodbury's ``U^T D^-1 U`` and ``U^T D^-1 r``
(:mod:`.likelihood`). As numpy operations the same arithmetic walks the 114,000-cell grid about
twenty times per term and allocates as many temporaries; here every term is added in one pass,
row by row of the grid. (Tried and slower: the terms inside each cell's loop, which does not
vectorise; their arrays a tuple, which numba indexes through a branch per access.) The
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


@njit(cache=True, error_model="numpy", inline="always")
def _woodbury_row(m3: np.ndarray, ur: np.ndarray, penalty: np.ndarray, misfit: np.ndarray,
                  m_det: np.ndarray, i: int) -> None:
    """The material's rank-2 covariance applied to row ``i`` (:func:`.woodbury.solve2`'s closed
    form, in its order): ``misfit`` less ``b^T (I + M)^-1 b`` and ``m_det`` set to
    ``det (I + M)`` where the cell has features (``penalty`` finite), 1 elsewhere; the caller
    adds ``log(m_det)`` (numpy's log, as the numpy path takes it)."""
    for j in range(misfit.shape[1]):
        if not np.isfinite(penalty[i, j]):
            m_det[i, j] = 1.0
            continue
        a00 = m3[0, i, j] + 1.0
        a01 = m3[1, i, j]
        a11 = m3[2, i, j] + 1.0
        d = a00 * a11 - a01 * a01
        b0 = ur[0, i, j]
        b1 = ur[1, i, j]
        misfit[i, j] -= (a11 * b0 * b0 - 2.0 * a01 * b0 * b1 + a00 * b1 * b1) / d
        m_det[i, j] = d


@njit(cache=True, error_model="numpy", nogil=True)
def add_terms(models: np.ndarray, model_vars: np.ndarray, us: np.ndarray, obs: np.ndarray,
              scale: np.ndarray, s2: np.ndarray, rel2: np.ndarray, unscaled: np.ndarray,
              has_rel: np.ndarray, has_u: bool, fresh: bool, misfit: np.ndarray,
              det: np.ndarray, m3: np.ndarray, ur: np.ndarray, penalty: np.ndarray,
              m_det: np.ndarray, finish: bool, start: int, stop: int) -> None:
    """Add K terms to ``misfit`` (chi^2), ``det`` (the variances' product) and, where
    ``has_u``, to ``m3`` (``U^T D^-1 U``'s upper entries) and ``ur`` (``U^T D^-1 r``), on the
    thickness rows ``start..stop-1`` only (:mod:`.grid_threads` runs bands of rows at once);
    with ``fresh``, the sums start here (0, and 1 for the product: the arrays need no filling).
    With ``finish`` and ``has_u`` (the last terms), each row then gets Woodbury's correction
    (:func:`_woodbury_row`, into ``m_det``) while it is still in the cache.

    The per-term arrays are stacked along a first axis of length K: ``models``, ``model_vars``
    (K, n_t, n_l), the model's value and (float32) variance per cell; ``us`` (K, 2, n_t, n_l,
    float32: the values are single-precision ones, widened exactly as they are read) the
    material's columns before the calibration's scale (read only where ``has_u``). Per distance
    column, rows (K, n_l): ``obs`` the measured value, ``scale`` the calibration's factor,
    ``s2`` the scatter's and calibration's variance, ``rel2`` a relative variance on the model.
    Flags (K,): ``unscaled``, the scale is 1 everywhere (the model enters as it is);
    ``has_rel``, some ``rel2`` is not 0.

    Thickness row by thickness row: a row's sums stay in the cache while every term is added
    to them, so they cross memory once instead of once per term, and the loop over a row's
    cells, its flags fixed, vectorises. One division per cell and term, its reciprocal
    multiplied."""
    n_k = models.shape[0]
    n_l = misfit.shape[1]
    for i in range(start, stop):
        if fresh:
            misfit[i] = 0.0
            det[i] = 1.0
            if has_u:
                m3[:, i] = 0.0
                ur[:, i] = 0.0
        for k in range(n_k):
            model, model_var = models[k, i], model_vars[k, i]
            ob, sc_k, s2_k, rel2_k = obs[k], scale[k], s2[k], rel2[k]
            plain, rel = unscaled[k], has_rel[k]
            mis, prod = misfit[i], det[i]
            for j in range(n_l):
                m = model[j]
                if plain:
                    v = model_var[j] + s2_k[j]
                    r = ob[j] - m
                else:
                    sc = sc_k[j]
                    v = model_var[j] * (sc * sc)
                    v += s2_k[j]
                    r = m * -sc
                    r += ob[j]
                if rel:
                    v += (m * m) * rel2_k[j]
                iv = 1.0 / v  # one division: three would bound the pass
                if has_u:
                    u0 = us[k, 0, i, j]
                    u1 = us[k, 1, i, j]
                    if not plain:
                        u0 = u0 * sc_k[j]
                        u1 = u1 * sc_k[j]
                    c0 = u0 * iv
                    c1 = u1 * iv
                    ur[0, i, j] += c0 * r
                    ur[1, i, j] += c1 * r
                    m3[0, i, j] += c0 * u0
                    m3[1, i, j] += c0 * u1
                    m3[2, i, j] += c1 * u1
                mis[j] += (r * r) * iv
                prod[j] *= v
        if finish and has_u:
            _woodbury_row(m3, ur, penalty, misfit, m_det, i)


def warm() -> None:
    """Load (on a fresh install: compile) the kernels, on one cell with the argument types the
    likelihood passes."""
    rows, flags = np.ones((1, 1)), np.ones(1, dtype=np.bool_)  # flags as numpy bools
    single = np.float32
    add_terms(np.ones((1, 1, 1)), np.ones((1, 1, 1), dtype=single),
              np.zeros((1, 2, 1, 1), dtype=single), rows, rows, rows,
              rows, flags, flags, True, True, np.zeros((1, 1)), np.ones((1, 1)),
              np.zeros((3, 1, 1)), np.zeros((2, 1, 1)), np.zeros((1, 1)), np.ones((1, 1)), True,
              0, 1)
