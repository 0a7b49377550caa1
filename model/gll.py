"""Gauss-Lobatto-Legendre (GLL) points, weights and Lagrange derivative matrices, any order.

Spectral elements put their nodes on the GLL points of each reference interval [-1, 1]; the same
points serve as quadrature, which makes the mass matrix diagonal (the paper's Sec. 3.2).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.polynomial import legendre


@lru_cache(maxsize=64)
def _gll(order: int) -> tuple[np.ndarray, np.ndarray]:
    if order < 1:
        raise ValueError(f"GLL order must be >= 1, got {order}")
    n = order
    if n == 1:
        x = np.array([-1.0, 1.0])
    else:
        # Interior points are the roots of P_n'(x); Newton-polish the companion-matrix roots.
        coeffs = np.zeros(n + 1)
        coeffs[n] = 1.0
        dcoeffs = legendre.legder(coeffs)
        inner = np.sort(legendre.legroots(dcoeffs).real)
        d2coeffs = legendre.legder(dcoeffs)
        for _ in range(3):
            inner -= legendre.legval(inner, dcoeffs) / legendre.legval(inner, d2coeffs)
        x = np.concatenate(([-1.0], inner, [1.0]))
    pn = legendre.legval(x, np.eye(n + 1)[n])
    w = 2.0 / (n * (n + 1) * pn**2)
    x.setflags(write=False)
    w.setflags(write=False)
    return x, w


def gll_points(order: int) -> np.ndarray:
    """The order + 1 GLL points on [-1, 1], ascending (endpoints included)."""
    return _gll(order)[0].copy()


def gll_weights(order: int) -> np.ndarray:
    """Quadrature weights of the GLL points; exact for polynomials of degree <= 2 order - 1."""
    return _gll(order)[1].copy()


def lagrange_derivative_matrix(points: np.ndarray) -> np.ndarray:
    """D[i, j] = l_j'(x_i) for the Lagrange basis l_j on ``points`` (barycentric formula).

    Rows sum to zero (derivative of a constant) and D applied to nodal values of any polynomial of
    degree <= len(points) - 1 gives its exact derivative at the points.
    """
    x = np.asarray(points, dtype=float)
    diff = x[:, None] - x[None, :]
    np.fill_diagonal(diff, 1.0)
    bary = 1.0 / np.prod(diff, axis=1)  # barycentric weights
    d = (bary[None, :] / bary[:, None]) / diff
    np.fill_diagonal(d, 0.0)
    np.fill_diagonal(d, -d.sum(axis=1))
    return d


def gll_derivative_matrix(order: int) -> np.ndarray:
    """Derivative matrix of the Lagrange basis on the GLL points of ``order``."""
    return lagrange_derivative_matrix(_gll(order)[0])


def lagrange_basis(points: np.ndarray, x: np.ndarray) -> np.ndarray:
    """B[k, j] = l_j(x_k): the Lagrange basis on ``points`` evaluated at ``x``."""
    p = np.asarray(points, dtype=float)
    xs = np.atleast_1d(np.asarray(x, dtype=float))
    out = np.ones((xs.size, p.size))
    for j in range(p.size):
        for m in range(p.size):
            if m != j:
                out[:, j] *= (xs - p[m]) / (p[j] - p[m])
    return out
