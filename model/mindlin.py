"""The Mindlin-Reissner plate on the spectral-element machinery: a 2-D plate ten times cheaper.

A thin plate answers the chain with its flexural (A0) motion at 1-20 kHz, wavelengths far longer
than its thickness t. The 3-D spectral elements (:mod:`solitonde.model.sem`) resolve the thickness
as well, and pay for it in dofs and in a stable step set by waves across t. Mindlin's plate keeps
what matters for flexure (bending, transverse shear with a correction factor, rotary inertia) in
three fields of the mid-plane: the deflection w (z up) and the rotations theta_x, theta_y of the
normal (in-plane displacement z theta at height z).

    strain energy  1/2 int [ k^T D_b k + kappa G t (grad w + theta)^2 ] dA,
        k = (theta_x,x, theta_y,y, theta_x,y + theta_y,x),
        D_b = D [[1, nu, 0], [nu, 1, 0], [0, 0, (1 - nu)/2]],  D = E t^3 / (12 (1 - nu^2));
    kinetic energy 1/2 int [ rho t w'^2 + rho t^3/12 (theta_x'^2 + theta_y'^2) ] dA.

The shear correction kappa = pi^2 / 12 is Mindlin's own choice for dynamics (it puts the
thickness-shear cut-off at the 3-D value). The mesh is the 3-D plate's in-plane mesh (same grading,
same contact patch, half plate by symmetry); nodes on GLL points with GLL quadrature give a
diagonal mass, so central differences stay explicit, and the stiffness is applied by sum
factorisation (:mod:`solitonde.model.mindlin_kernels`). Clamped edges fix all three fields; the
mirror plane y = Ly/2 fixes theta_y. Full GLL quadrature of order 4 elements is free of visible
shear locking at the element sizes used here (the convergence test measures it).

Reference: R. D. Mindlin, "Influence of rotatory inertia and shear on flexural motions of
isotropic, elastic plates", Journal of Applied Mechanics 18 (1951) 31-38.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .gll import gll_derivative_matrix, gll_weights
from .materials import Material
from .mesh import PlateMesh
from .mindlin_kernels import mindlin_operator
from .plate_base import ExplicitPlate, element_bound, support_masks

SHEAR_FACTOR = np.pi**2 / 12.0
"""Mindlin's shear correction kappa (matches the 3-D thickness-shear cut-off frequency)."""


def rigidities(material: Material, thickness: float,
               shear_factor: float = SHEAR_FACTOR) -> tuple[float, float]:
    """(bending stiffness D = E t^3 / (12 (1 - nu^2)) in N m, shear stiffness kappa G t in N/m)."""
    e, nu = material.youngs_modulus, material.poisson_ratio
    return (e * thickness**3 / (12.0 * (1.0 - nu * nu)),
            shear_factor * material.shear_modulus * thickness)


def element_stiffness(size: tuple[float, float], order: tuple[int, int], material: Material,
                      thickness: float, shear_factor: float = SHEAR_FACTOR) -> np.ndarray:
    """Dense stiffness of one rectangular Mindlin element, dofs 3 node + (w, theta_x, theta_y).

    K = sum_q w_q |J| (B_b^T D_b B_b + kappa G t B_s^T B_s), the reference the sum-factorised
    kernel is checked against and the source of the element bound of the stable step.
    """
    hx, hy = size
    px, py = order
    gx = np.kron(np.eye(py + 1), gll_derivative_matrix(px) * (2.0 / hx))  # (q, a)
    gy = np.kron(gll_derivative_matrix(py) * (2.0 / hy), np.eye(px + 1))
    wq = np.kron(gll_weights(py), gll_weights(px)) * (hx * hy / 4.0)
    n = gx.shape[0]
    bb = np.zeros((n, 3, 3 * n))
    bb[:, 0, 1::3] = gx
    bb[:, 1, 2::3] = gy
    bb[:, 2, 1::3] = gy
    bb[:, 2, 2::3] = gx
    bs = np.zeros((n, 2, 3 * n))
    bs[:, 0, 0::3] = gx
    bs[:, 1, 0::3] = gy
    idx = np.arange(n)
    bs[idx, 0, 3 * idx + 1] = 1.0
    bs[idx, 1, 3 * idx + 2] = 1.0
    bend, shear = rigidities(material, thickness, shear_factor)
    nu = material.poisson_ratio
    db = bend * np.array([[1.0, nu, 0.0], [nu, 1.0, 0.0], [0.0, 0.0, 0.5 * (1.0 - nu)]])
    # the quadrature sums as two matrix products (one GEMM each: 25-50x the einsum's speed)
    wbb = (wq[:, None, None] * bb).reshape(-1, 3 * n)
    k = wbb.T @ (db @ bb).reshape(-1, 3 * n)
    k += shear * ((wq[:, None, None] * bs).reshape(-1, 3 * n).T @ bs.reshape(-1, 3 * n))
    return 0.5 * (k + k.T)


def element_mass(size: tuple[float, float], order: tuple[int, int], material: Material,
                 thickness: float) -> np.ndarray:
    """Diagonal (nodal-quadrature) mass per element dof: rho t for w, rho t^3 / 12 for theta."""
    hx, hy = size
    wq = np.kron(gll_weights(order[1]), gll_weights(order[0])) * (hx * hy / 4.0)
    per_field = material.density * np.array([thickness, thickness**3 / 12.0, thickness**3 / 12.0])
    return (wq[:, None] * per_field[None, :]).ravel()


@dataclass(frozen=True)
class MindlinPlate(ExplicitPlate):
    """A Mindlin-Reissner plate ready to time-step (the interface of the 3-D ``ElasticPlate``).

    Attributes
    ----------
    mesh: the plate's mesh; only its in-plane grid is used (one layer of nodes, the mid-plane).
    material, supports, thickness: what it is.
    dof_mass: (n_dofs,) diagonal mass per dof (rho t or rho t^3/12 times the node's area), kg.
    inv_mass: 1/m per dof, 0 on constrained dofs.
    sizes, shape_id: distinct element sizes (hx, hy) and each element's shape.
    kes: (n_shapes, n_edof, n_edof) dense element matrices (reference operator, element bound).
    operator: the sum-factorised stiffness (:func:`mindlin_kernels.mindlin_operator`).
    load_dofs, load_weights: the contact patch as w dofs and weights b (sum = share).
    """

    mesh: PlateMesh
    material: Material
    supports: str
    thickness: float
    dof_mass: np.ndarray
    inv_mass: np.ndarray
    sizes: np.ndarray
    shape_id: np.ndarray
    kes: np.ndarray
    operator: tuple
    load_dofs: np.ndarray
    load_weights: np.ndarray

    @property
    def grid_shape(self) -> tuple[int, int]:
        """In-plane nodes along (x, y)."""
        nx, ny, _ = self.mesh.grid_shape
        return nx, ny

    @property
    def contact_dof(self) -> int:
        """The w dof of the node under the chain (when the mesh has one there)."""
        nx, ny = self.grid_shape
        return 3 * (self.mesh.contact_node % (nx * ny))

    @cached_property
    def element_bound(self) -> float:
        """max over elements of lambda_max(K_e, M_e): an upper bound of ``max_eigenvalue``."""
        return element_bound(self.kes, [
            element_mass(tuple(size), self.mesh.order[:2], self.material, self.thickness)
            for size in self.sizes])

    def describe(self) -> dict[str, object]:
        """JSON-ready summary of the mesh as this plate uses it."""
        nx, ny = self.grid_shape
        ex, ey, _ = self.mesh.elements
        return {
            "plate_theory": "mindlin",
            "elements": [ex, ey],
            "order": list(self.mesh.order[:2]),
            "nodes": nx * ny,
            "dofs": self.n_dofs,
            "symmetry": self.mesh.symmetry,
            "element_shapes": len(self.sizes),
            "min_element_m": [float(np.diff(e).min()) for e in
                              (self.mesh.x_edges, self.mesh.y_edges)],
            "contact_radius_m": self.mesh.contact_radius,
            "contact_nodes": int(self.load_dofs.size),
            "shear_factor": SHEAR_FACTOR,
        }


def _in_plane(mesh: PlateMesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(connectivity of the in-plane elements, their sizes (n, 2), in-plane node coordinates)."""
    nx = mesh.grid_shape[0]
    px, py, _ = mesh.order
    ex, ey, _ = mesh.elements
    jj, ii = np.meshgrid(np.arange(py + 1), np.arange(px + 1), indexing="ij")
    ej, ei = np.meshgrid(np.arange(ey), np.arange(ex), indexing="ij")
    i = ei.ravel()[:, None] * px + ii.ravel()[None, :]
    j = ej.ravel()[:, None] * py + jj.ravel()[None, :]
    conn = (j * nx + i).astype(np.int64)
    hy, hx = np.meshgrid(np.diff(mesh.y_edges), np.diff(mesh.x_edges), indexing="ij")
    ax, ay, _ = mesh.axes
    y, x = np.meshgrid(ay, ax, indexing="ij")
    return conn, np.column_stack((hx.ravel(), hy.ravel())), np.column_stack((x.ravel(),
                                                                             y.ravel()))


def build_mindlin_plate(mesh: PlateMesh, material: Material,
                        supports: str = "opposite_edges") -> MindlinPlate:
    """Element matrices, diagonal mass and constraints of the Mindlin plate on ``mesh``'s
    in-plane grid, of thickness ``mesh``'s z extent."""
    thickness = float(mesh.z_edges[-1])
    px, py, _ = mesh.order
    conn, el_sizes, xy = _in_plane(mesh)
    clamped, mirror = support_masks(xy[:, 0], xy[:, 1], mesh, supports)
    scale = float(el_sizes.max())
    uniq, shape_id = np.unique(np.round(el_sizes / scale, 11), axis=0, return_inverse=True)
    shape_id = shape_id.ravel().astype(np.int64)
    sizes = np.array([el_sizes[np.argmax(shape_id == s)] for s in range(len(uniq))])
    kes = np.stack([element_stiffness(tuple(s), (px, py), material, thickness) for s in sizes])

    n_nodes = xy.shape[0]
    dof_mass = np.zeros(3 * n_nodes)
    edofs = (3 * conn[:, :, None] + np.arange(3)[None, None, :]).reshape(conn.shape[0], -1)
    for s, size in enumerate(sizes):
        me = element_mass(tuple(size), (px, py), material, thickness)
        els = edofs[shape_id == s]
        np.add.at(dof_mass, els.ravel(), np.tile(me, els.shape[0]))

    fixed = np.zeros((n_nodes, 3), dtype=bool)
    fixed[clamped] = True
    fixed[mirror, 2] = True  # theta_y, the rotation that moves a point across the mirror plane
    inv_mass = 1.0 / dof_mass
    inv_mass[fixed.ravel()] = 0.0

    nodes3d, weights = mesh.contact_load
    nodes = nodes3d % n_nodes  # the top-surface node above each in-plane node
    bend, shear = rigidities(material, thickness)
    geom = np.column_stack((2.0 / el_sizes, np.prod(el_sizes, axis=1) / 4.0))
    w2 = np.kron(gll_weights(py), gll_weights(px))
    operator = mindlin_operator(conn, geom, gll_derivative_matrix(px), gll_derivative_matrix(py),
                                w2, np.array([bend, material.poisson_ratio, shear]))
    return MindlinPlate(mesh, material, supports, thickness, dof_mass, inv_mass, sizes,
                        shape_id, kes, operator,
                        np.ascontiguousarray(3 * nodes, dtype=np.int64),
                        np.ascontiguousarray(weights, dtype=float))
