"""GLL points, weights and derivative matrices against exact polynomial calculus."""

from __future__ import annotations

import numpy as np
import pytest

from solitonde.model.gll import (
    gll_derivative_matrix,
    gll_points,
    gll_weights,
    lagrange_basis,
)


def test_known_points() -> None:
    """Order 2 is (-1, 0, 1); order 4 has +-sqrt(3/7) inside; weights of order 2 are 1/3, 4/3."""
    assert np.allclose(gll_points(2), [-1.0, 0.0, 1.0])
    assert np.allclose(gll_weights(2), [1 / 3, 4 / 3, 1 / 3])
    assert np.allclose(gll_points(4), [-1.0, -np.sqrt(3 / 7), 0.0, np.sqrt(3 / 7), 1.0])
    assert np.allclose(gll_weights(4), [0.1, 49 / 90, 32 / 45, 49 / 90, 0.1])


@pytest.mark.parametrize("order", [1, 2, 3, 4, 5, 8, 12, 16])
def test_quadrature_exact_to_degree_2p_minus_1(order: int) -> None:
    """sum w x^k equals the integral for every k <= 2 order - 1, but not for 2 order."""
    x, w = gll_points(order), gll_weights(order)
    for k in range(2 * order):
        exact = (1 - (-1) ** (k + 1)) / (k + 1)
        assert np.isclose(np.dot(w, x**k), exact, atol=1e-13), k
    k = 2 * order
    assert abs(np.dot(w, x**k) - 2 / (k + 1)) > 1e-12  # degree 2p is no longer exact


@pytest.mark.parametrize("order", [1, 2, 4, 7, 10])
def test_derivative_exact_for_polynomials(order: int) -> None:
    """D applied to nodal values of x^k gives k x^(k-1) for k <= order; rows sum to 0."""
    x = gll_points(order)
    d = gll_derivative_matrix(order)
    assert np.allclose(d.sum(axis=1), 0.0, atol=1e-11)
    for k in range(order + 1):
        expect = k * x ** (k - 1) if k > 0 else np.zeros_like(x)
        assert np.allclose(d @ x**k, expect, atol=1e-10 * max(1, order**2)), k


def test_lagrange_basis_is_cardinal() -> None:
    """l_j(x_i) = delta_ij and the basis sums to one anywhere."""
    x = gll_points(5)
    assert np.allclose(lagrange_basis(x, x), np.eye(6), atol=1e-13)
    assert np.allclose(lagrange_basis(x, np.linspace(-1, 1, 17)).sum(axis=1), 1.0)
