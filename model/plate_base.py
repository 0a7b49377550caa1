"""What every explicit plate model shares: a diagonal mass, a matrix-free stiffness, a patch load.

The 3-D spectral-element plate (:mod:`solitonde.model.sem`) and the Mindlin-Reissner plate
(:mod:`solitonde.model.mindlin`) differ in their dofs and their stiffness operator; once those are
built, stepping them, loading them through the contact patch, bounding their stable step and
booking their energy are the same, and live here.
"""

from __future__ import annotations

from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.sparse.linalg import LinearOperator, eigsh

from .mesh import PlateMesh
from .sem_kernels import run_plate_load, stiffness_product

SUPPORTS = ("opposite_edges", "all_edges", "none")


def support_masks(x: np.ndarray, y: np.ndarray, mesh: PlateMesh,
                  supports: str) -> tuple[np.ndarray, np.ndarray]:
    """(clamped, mirror): the nodes at in-plane positions ``x``, ``y`` on a clamped edge (every
    dof fixed) and on the symmetry plane y = Ly/2 of a half model (the dof that moves across it
    fixed). ``supports`` is one of :data:`SUPPORTS`; clamped edges are x = 0 and x = Lx, and with
    ``all_edges`` also y = 0 and, on a full model, y = Ly."""
    if supports not in SUPPORTS:
        raise ValueError(f"supports must be one of {', '.join(SUPPORTS)}, got {supports!r}")
    lx, ly = float(mesh.x_edges[-1]), float(mesh.y_edges[-1])
    tol = 1e-9 * max(lx, mesh.full_width)
    on_top = np.abs(y - ly) < tol
    clamped = np.zeros(x.shape, dtype=bool)
    if supports in ("opposite_edges", "all_edges"):
        clamped |= (np.abs(x) < tol) | (np.abs(x - lx) < tol)
    if supports == "all_edges":
        clamped |= np.abs(y) < tol
        if not mesh.symmetry:
            clamped |= on_top
    mirror = on_top if mesh.symmetry else np.zeros(x.shape, dtype=bool)
    return clamped, mirror


def element_bound(kes: np.ndarray, masses: list[np.ndarray]) -> float:
    """max over element shapes of lambda_max(K_e, M_e) with a diagonal M_e (per dof): an upper
    bound of the largest eigenvalue of the assembled M^-1 K, so 2 / sqrt of it is a safe step."""
    best = 0.0
    for k, m in zip(kes, masses, strict=True):
        d = 1.0 / np.sqrt(m)
        best = max(best, float(np.linalg.eigvalsh(k * d[:, None] * d[None, :])[-1]))
    return best


class ExplicitPlate:
    """Mixin of the plate dataclasses. They provide ``mesh`` (its ``share``), ``inv_mass`` (1/m
    per dof, 0 on constrained dofs), ``dof_mass``, ``operator`` (for :func:`stiffness_product`),
    ``load_dofs``/``load_weights`` (the contact patch, weights summing to the share) and
    ``element_bound`` (an upper bound of the largest eigenvalue of M^-1 K)."""

    mesh: PlateMesh
    inv_mass: np.ndarray
    operator: tuple[Any, ...]
    load_dofs: np.ndarray
    load_weights: np.ndarray

    if TYPE_CHECKING:  # a field of one plate, a property of the other: declared for the checker
        @property
        def dof_mass(self) -> np.ndarray: ...

    @property
    def n_dofs(self) -> int:
        return self.inv_mass.size

    @property
    def force_share(self) -> float:
        """Part of the contact force (and plate energy) the mesh carries: 1/2 for a half model."""
        return self.mesh.share

    @property
    def fixed(self) -> np.ndarray:
        return self.inv_mass == 0.0

    def apply_stiffness(self, u: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """K u, matrix-free."""
        if out is None:
            out = np.empty(self.n_dofs)
        stiffness_product(self.operator, np.ascontiguousarray(u, dtype=float), out)
        return out

    @cached_property
    def max_eigenvalue(self) -> float:
        """Largest eigenvalue of M^-1 K on the free dofs (rad^2/s^2), by Lanczos.

        Works on the symmetric form M^-1/2 K M^-1/2 (a few hundred matrix-free products). The
        time step itself uses ``element_bound``, which is cheaper and never below this.
        """
        free = ~self.fixed
        s = np.sqrt(self.inv_mass)
        out = np.empty(self.n_dofs)

        def matvec(x: np.ndarray) -> np.ndarray:
            y = s * np.ravel(x)
            stiffness_product(self.operator, y, out)
            return s * out

        op = LinearOperator((self.n_dofs, self.n_dofs), matvec=matvec, dtype=float)
        v0 = np.random.default_rng(0).standard_normal(self.n_dofs) * free
        vals = eigsh(op, k=1, which="LA", tol=1e-6, v0=v0, return_eigenvectors=False,
                     ncv=min(self.n_dofs, 40), maxiter=5000)
        return float(vals[0])

    @property
    def critical_step(self) -> float:
        """dt_crit = 2 / omega_max for central differences, s."""
        return 2.0 / np.sqrt(self.max_eigenvalue)

    def kinetic_energy(self, v: np.ndarray) -> float:
        """0.5 v^T M v, J."""
        return 0.5 * float(np.dot(self.dof_mass * v, v))

    def strain_energy(self, u: np.ndarray, u_next: np.ndarray | None = None) -> float:
        """0.5 u^T K u, or the time-centred 0.5 u_n^T K u_{n+1} (exactly conserved by leapfrog)."""
        ku = self.apply_stiffness(u)
        return 0.5 * float(np.dot(ku, u if u_next is None else u_next))

    def run_contact_load(self, force: np.ndarray, dt: float,
                         record_dofs: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Central differences from rest under a contact force history ``force[n]`` (+z, N).

        The force acts through the contact patch (nodal forces force[n] b). Returns (w, rec):
        w[n] = b . u_n / share, the patch-weighted vertical displacement under the chain (+z),
        and rec[n, r] = u_n[record_dofs[r]] (empty without ``record_dofs``), n = 0..len(force).
        """
        rec = np.asarray([] if record_dofs is None else record_dofs, dtype=np.int64)
        w, out = run_plate_load(np.ascontiguousarray(force, dtype=float), self.load_dofs,
                                self.load_weights, float(dt), self.inv_mass, self.operator, rec)
        return w / self.force_share, out
