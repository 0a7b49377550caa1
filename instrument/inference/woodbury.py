"""The plate material's rank-2 covariance in the likelihood, per cell in closed form: with the
terms' covariance ``C = D + U U^T`` (D diagonal, U the material's two columns), Woodbury's identity
needs only the 2 x 2 matrix ``I + M``, ``M = U^T D^-1 U``, given by its three upper entries
(:data:`UPPER`, first axis; vectors likewise component first)."""

from __future__ import annotations

import numpy as np

UPPER = ((0, 0), (0, 1), (1, 1))
"""The three distinct entries of a symmetric 2 x 2 matrix, in the order they are stored."""


def solve2(m3: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``b^T (I + M)^-1 b`` and ``log det (I + M)`` per cell, for M symmetric positive
    semi-definite given by its three upper entries, in closed form."""
    a00, a01, a11 = m3
    a00 = a00 + 1.0
    a11 = a11 + 1.0
    det = a00 * a11 - a01 * a01
    b0, b1 = b
    quad = (a11 * b0 * b0 - 2.0 * a01 * b0 * b1 + a00 * b1 * b1) / det
    return quad, np.log(det)


def material_shift(m3: np.ndarray, b: np.ndarray, cells: np.ndarray, post: np.ndarray
                   ) -> list[float]:
    """The posterior mean of the plate material's departure from the table's, in its spread's
    standard deviations along ``(d ln E', d ln rho)``: per cell ``(I + M)^-1 b`` (the Gaussian
    material term's own posterior mean, M and b as in :func:`solve2`), averaged over the
    posterior ``post`` on ``cells`` (flat indices; every other cell's is 0). Two or more in E'
    means the data fit a plate at the edge of the grade's range."""
    # the cells that carry the posterior (a billionth of its peak and up) decide the mean
    kept = np.flatnonzero(post > 1e-9 * float(post.max()))
    at = cells[kept]
    a00, a01, a11 = (np.take(m, at) for m in m3)
    a00 = a00 + 1.0
    a11 = a11 + 1.0
    det = a00 * a11 - a01 * a01
    b0, b1 = (np.take(v, at) for v in b)
    w = post[kept] / det
    return [weighted_sum(w, a11 * b0 - a01 * b1), weighted_sum(w, a00 * b1 - a01 * b0)]


def weighted_sum(w: np.ndarray, a: np.ndarray) -> float:
    """``sum(w * a)`` over every element, on this thread.

    Not ``np.dot``: OpenBLAS hands a product this long to its worker threads, and on a machine
    whose cores are busy (a table build beside the service) waking them cost an inversion 10-30
    ms instead of a few. ``einsum`` without ``optimize`` sums in numpy's own loops."""
    return float(np.einsum("i,i->", w.ravel(), a.ravel()))


def bilinear2(m3: np.ndarray, v: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``v^T (I + M)^-1 w`` per cell, M as in :func:`solve2`."""
    a00, a01, a11 = m3
    a00 = a00 + 1.0
    a11 = a11 + 1.0
    det = a00 * a11 - a01 * a01
    return (a11 * v[0] * w[0] - a01 * (v[0] * w[1] + v[1] * w[0]) + a00 * v[1] * w[1]) / det
