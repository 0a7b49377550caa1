"""The spectral-element plate: isotropic elasticity, diagonal mass, matrix-free stiffness.

Nodes on GLL points and GLL quadrature give a diagonal mass matrix (the paper's Sec. 3.2), so
central differences (Newmark beta = 0, gamma = 1/2) are explicit. The stiffness is never assembled
for time stepping: K u is applied element by element by sum factorisation (1-D GLL derivative
matrices along each axis of the box elements, see ``sem_kernels``); the dense element matrices,
one per distinct element shape, remain the reference operator and give the element bound of the
stable step. Supports clamp all three displacement components on whole edge faces; a symmetry
plane y = Ly/2 (half model) fixes u_y there.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from functools import cache, cached_property

import numpy as np
import scipy.sparse as sp
from threadpoolctl import ThreadpoolController

from .gll import gll_derivative_matrix, gll_weights
from .materials import Material
from .mesh import PlateMesh
from .plate_base import ExplicitPlate, element_bound, support_masks
from .sem_kernels import dense_operator, run_plate_load, stiffness_product, sumfact_operator


@cache
def _blas_pools() -> ThreadpoolController:
    """The process's BLAS thread pools, found once: finding them walks every loaded library
    (0.8 ms, where setting a found pool's limit takes 0.01 ms). scipy's BLAS, which compiled
    code calls through ``np.dot``, is loaded first so that it is among them."""
    import scipy.linalg.cython_blas  # noqa: F401

    return ThreadpoolController()


@contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Run a compiled loop that calls BLAS (the dense reference operator's GEMMs, the Green's
    function convolution's dot products) with one BLAS thread.

    Those calls are small; a second BLAS thread gains little on an idle machine and, when the
    cores are shared, its spin-waiting can make a run several times slower. The sum-factorised
    operator the plate time loops use calls no BLAS, so they run without it.
    """
    with _blas_pools().limit(limits=1, user_api="blas"):
        yield


def element_stiffness(
    size: tuple[float, float, float], order: tuple[int, int, int], material: Material
) -> np.ndarray:
    """Dense stiffness of one box element with GLL quadrature, dofs ordered 3 * node + component.

    K[(a,c),(b,e)] = sum_q w_q |J| (lambda G_qac G_qbe + mu G_qae G_qbc + mu delta_ce G_qad G_qbd)
    with G_qad the x_d-derivative of shape function a at quadrature point q.
    """
    hx, hy, hz = size
    px, py, pz = order
    ix, iy, iz = np.eye(px + 1), np.eye(py + 1), np.eye(pz + 1)
    dx = gll_derivative_matrix(px) * (2.0 / hx)
    dy = gll_derivative_matrix(py) * (2.0 / hy)
    dz = gll_derivative_matrix(pz) * (2.0 / hz)
    g = np.stack(
        (np.kron(iz, np.kron(iy, dx)), np.kron(iz, np.kron(dy, ix)), np.kron(dz, np.kron(iy, ix))),
        axis=-1,
    )  # (q, a, d)
    w = np.kron(gll_weights(pz), np.kron(gll_weights(py), gll_weights(px))) * (hx * hy * hz / 8.0)
    lam, mu = material.lame_lambda, material.shear_modulus
    gw = g * w[:, None, None]
    k = lam * np.einsum("qac,qbe->acbe", gw, g)
    k += mu * np.einsum("qae,qbc->acbe", gw, g)
    lap = np.einsum("qad,qbd->ab", gw, g)
    n = g.shape[1]
    k += mu * np.einsum("ab,ce->acbe", lap, np.eye(3))
    k = k.reshape(3 * n, 3 * n)
    return 0.5 * (k + k.T)


def element_mass(
    size: tuple[float, float, float], order: tuple[int, int, int], rho: float
) -> np.ndarray:
    """Diagonal (nodal-quadrature) mass of one box element, per node."""
    hx, hy, hz = size
    px, py, pz = order
    w = np.kron(gll_weights(pz), np.kron(gll_weights(py), gll_weights(px)))
    return rho * w * (hx * hy * hz / 8.0)


@dataclass(frozen=True)
class ElasticPlate(ExplicitPlate):
    """An assembled-in-spirit (never as a matrix) spectral-element plate ready to time-step.

    Attributes
    ----------
    mesh, material, supports: what it is.
    node_mass: (n_nodes,) diagonal mass, kg (halved automatically on a symmetry plane).
    inv_mass: (n_dofs,) 1/m per dof, 0 on constrained dofs (which then never move).
    edofs: (n_elements, n_edof) element dofs, elements sorted by shape.
    offsets: (n_shapes + 1,) element ranges per shape in ``edofs``.
    kes: (n_shapes, n_edof, n_edof) element matrices (reference operator, element bound).
    operator: the sum-factorised stiffness operator the time loops use
        (:func:`sem_kernels.sumfact_operator`; read only, safe to share between threads).
    load_dofs, load_weights: the contact patch as vertical dofs and weights b (sum = share), see
        :meth:`PlateMesh.contact_load`: a contact force F acts as F b, the deflection under the
        chain is b . u / share.
    """

    mesh: PlateMesh
    material: Material
    supports: str
    node_mass: np.ndarray
    inv_mass: np.ndarray
    edofs: np.ndarray
    offsets: np.ndarray
    kes: np.ndarray
    operator: tuple
    load_dofs: np.ndarray
    load_weights: np.ndarray

    @property
    def contact_dof(self) -> int:
        """Vertical (z) dof of the node under the chain (when the mesh has one there)."""
        return 3 * self.mesh.contact_node + 2

    def dense_operator(self) -> tuple:
        """The dense-element-matrix operator (the reference), with work arrays of its own."""
        return dense_operator(self.edofs, self.offsets, self.kes)

    def apply_stiffness_dense(self, u: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """K u, matrix-free with the dense element matrices (the reference for the above)."""
        if out is None:
            out = np.empty(self.n_dofs)
        stiffness_product(self.dense_operator(), np.ascontiguousarray(u, dtype=float), out)
        return out

    def stiffness_csr(self) -> sp.csr_matrix:
        """The assembled global stiffness (for checks and the benchmark baseline only)."""
        n = self.edofs.shape[1]
        rows, cols, vals = [], [], []
        for s in range(self.offsets.size - 1):
            ed = self.edofs[self.offsets[s]: self.offsets[s + 1]]
            rows.append(np.repeat(ed, n, axis=1).ravel())
            cols.append(np.tile(ed, (1, n)).ravel())
            vals.append(np.broadcast_to(self.kes[s].ravel(), (ed.shape[0], n * n)).ravel())
        k = sp.coo_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
            shape=(self.n_dofs, self.n_dofs),
        ).tocsr()
        k.sum_duplicates()
        return k

    def describe(self) -> dict[str, object]:
        """JSON-ready summary of the mesh."""
        return {"plate_theory": "3d", **self.mesh.describe()}

    @property
    def dof_mass(self) -> np.ndarray:
        """Mass per dof (three per node), kg."""
        return np.repeat(self.node_mass, 3)

    @cached_property
    def element_bound(self) -> float:
        """max over elements of lambda_max(K_e, M_e): an upper bound of ``max_eigenvalue``."""
        sizes, _ = self.mesh.shapes
        return element_bound(self.kes, [
            np.repeat(element_mass(tuple(size), self.mesh.order, self.material.density), 3)
            for size in sizes])

    def run_point_force(self, force: np.ndarray, dt: float, record_dofs: np.ndarray | None = None,
                        dof: int | None = None) -> np.ndarray:
        """Central differences from rest under ``force[n]`` at ``dof`` (default: contact, z).

        Returns the displacement of ``record_dofs`` (default: the contact dof) at steps 0..n.
        """
        dof = self.contact_dof if dof is None else int(dof)
        rec = np.asarray([dof] if record_dofs is None else record_dofs, dtype=np.int64)
        _, out = run_plate_load(np.ascontiguousarray(force, dtype=float),
                                np.asarray([dof], dtype=np.int64), np.ones(1), float(dt),
                                self.inv_mass, self.operator, rec)
        return out


def _sumfact(mesh: PlateMesh, sizes: np.ndarray, material: Material) -> tuple:
    """Sum-factorised stiffness of ``mesh`` with element sizes ``sizes`` (n_elements, 3).

    The sizes are those of the element's shape (as for the dense matrices), so both operators
    see the same geometry.
    """
    px, py, pz = mesh.order
    w3 = np.kron(gll_weights(pz), np.kron(gll_weights(py), gll_weights(px)))
    geom = np.column_stack((2.0 / sizes, np.prod(sizes, axis=1) / 8.0))
    return sumfact_operator(
        mesh.connectivity, geom, gll_derivative_matrix(px), gll_derivative_matrix(py),
        gll_derivative_matrix(pz), w3, np.array([material.lame_lambda, material.shear_modulus]),
    )


def build_plate(
    mesh: PlateMesh, material: Material, supports: str = "opposite_edges"
) -> ElasticPlate:
    """Element matrices, diagonal mass and constraints of a meshed plate."""
    clamped, mirror = support_masks(mesh.nodes[:, 0], mesh.nodes[:, 1], mesh, supports)
    sizes, shape_id = mesh.shapes
    kes = np.stack([element_stiffness(tuple(s), mesh.order, material) for s in sizes])
    order = np.argsort(shape_id, kind="stable")
    conn = mesh.connectivity[order]
    edofs = (3 * conn[:, :, None] + np.arange(3)[None, None, :]).reshape(conn.shape[0], -1)
    offsets = np.searchsorted(shape_id[order], np.arange(len(sizes) + 1)).astype(np.int64)

    node_mass = np.zeros(mesh.n_nodes)
    for s, size in enumerate(sizes):
        me = element_mass(tuple(size), mesh.order, material.density)
        els = mesh.connectivity[shape_id == s]
        np.add.at(node_mass, els.ravel(), np.tile(me, els.shape[0]))

    fixed = np.zeros((mesh.n_nodes, 3), dtype=bool)
    fixed[clamped] = True
    fixed[mirror, 1] = True  # u_y across the mirror plane
    inv_mass = np.repeat(1.0 / node_mass, 3)
    inv_mass[fixed.ravel()] = 0.0
    nodes, weights = mesh.contact_load
    return ElasticPlate(mesh, material, supports, node_mass, inv_mass,
                        np.ascontiguousarray(edofs, dtype=np.int64), offsets, kes,
                        _sumfact(mesh, sizes[shape_id], material),
                        np.ascontiguousarray(3 * nodes + 2, dtype=np.int64),
                        np.ascontiguousarray(weights, dtype=float))
