"""Sum-factorised stiffness: the same operator as the dense element matrices, to round-off."""

from __future__ import annotations

import numpy as np
import pytest

from solitonde.model.gll import gll_derivative_matrix, gll_weights
from solitonde.model.materials import MATERIALS
from solitonde.model.mesh import plate_mesh
from solitonde.model.sem import build_plate, element_stiffness
from solitonde.model.sem_kernels import (
    SUMFACT_SPECIALISED,
    run_plate_load,
    stiffness_product,
    sumfact_operator,
)

AL = MATERIALS["al_6061"]


def _relative(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).max() / np.abs(b).max())


@pytest.mark.parametrize("order", [(4, 4, 2), (3, 5, 2)])
@pytest.mark.parametrize("symmetry", [False, True])
def test_sumfact_equals_dense_on_graded_refined_mesh(order: tuple, symmetry: bool) -> None:
    """K u by sum factorisation equals the dense element matrices' K u to 1e-12 of max |K u|
    on a graded mesh with contact refinement (many element shapes, clamped edges).

    [4, 4, 2] runs the kernel specialised for that order, [3, 5, 2] the general one.
    """
    mesh = plate_mesh((0.2, 0.15), 4e-3, (5, 4, 2), order, contact_x=0.031, symmetry=symmetry,
                      contact_radius=4e-3, contact_refinement=2)
    plate = build_plate(mesh, AL, "opposite_edges")
    assert len(mesh.shapes[0]) >= 10
    rng = np.random.default_rng(7)
    for _ in range(2):
        u = rng.standard_normal(plate.n_dofs)
        assert _relative(plate.apply_stiffness(u), plate.apply_stiffness_dense(u)) < 1e-12


@pytest.mark.parametrize(("order", "own_kernel"), [
    ((4, 4, 2), True), ((4, 4, 3), True), ((2, 3, 4), False), ((8, 1, 2), False)])
def test_sumfact_rebuilds_the_element_matrix_of_a_non_cubic_box(order: tuple,
                                                                own_kernel: bool) -> None:
    """On one box of 3 x 0.5 x 0.2 mm, K applied to the unit vectors is ``element_stiffness``
    (dof 3 * node + component, local nodes x fastest) entry by entry, to 1e-12 of max |K|;
    both the kernels specialised for one order and the general one."""
    size = (3e-3, 0.5e-3, 0.2e-3)
    px, py, pz = order
    nloc = (px + 1) * (py + 1) * (pz + 1)
    geom = np.array([[2.0 / size[0], 2.0 / size[1], 2.0 / size[2], np.prod(size) / 8.0]])
    w3 = np.kron(gll_weights(pz), np.kron(gll_weights(py), gll_weights(px)))
    op = sumfact_operator(np.arange(nloc)[None, :], geom, gll_derivative_matrix(px),
                          gll_derivative_matrix(py), gll_derivative_matrix(pz), w3,
                          np.array([AL.lame_lambda, AL.shear_modulus]))
    assert (order in SUMFACT_SPECIALISED) == own_kernel
    eye = np.eye(3 * nloc)
    k = np.empty_like(eye)
    for col in range(3 * nloc):
        stiffness_product(op, eye[col], k[:, col])
    dense = element_stiffness(size, order, AL)
    assert _relative(k, dense) < 1e-12
    assert _relative(k, k.T) < 1e-12


def test_time_loop_gives_the_same_run_with_either_operator() -> None:
    """run_plate_load compiled for the sum-factorised and for the dense operator: the same
    displacement history to round-off growth over 300 steps of 0.9 of the stable step (about
    2e-13 of the peak here)."""
    mesh = plate_mesh((0.12, 0.1), 3e-3, (4, 3, 1), (4, 4, 2), contact_x=0.05,
                      contact_radius=3e-3, contact_refinement=1)
    plate = build_plate(mesh, AL, "opposite_edges")
    dt = 0.9 * 2.0 / np.sqrt(plate.element_bound)
    force = np.sin(np.linspace(0.0, np.pi, 300)) ** 2
    rec = np.array([plate.contact_dof, 7, plate.n_dofs - 5], dtype=np.int64)
    runs = [run_plate_load(force, plate.load_dofs, plate.load_weights, dt, plate.inv_mass, op, rec)
            for op in (plate.operator, plate.dense_operator())]
    (w_sf, rec_sf), (w_dense, rec_dense) = runs
    assert np.abs(w_dense).max() > 0.0
    assert _relative(w_sf, w_dense) < 1e-11
    assert _relative(rec_sf, rec_dense) < 1e-11


def test_bad_operators_are_refused() -> None:
    """Mismatched operator arrays and foreign tuples raise, naming what does not fit."""
    d = gll_derivative_matrix(2)
    w3 = np.ones(27)
    with pytest.raises(ValueError, match="do not fit"):
        sumfact_operator(np.zeros((1, 26), dtype=np.int64), np.ones((1, 4)), d, d, d, w3,
                         np.ones(2))
    with pytest.raises(TypeError, match="tuple of 3 items"):
        stiffness_product((1, 2, 3), np.zeros(3), np.zeros(3))
