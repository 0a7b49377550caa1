"""Numba kernels of the spectral-element plate: matrix-free stiffness and central differences.

The stiffness is applied element by element without assembling a global matrix: the element
displacement vectors of all elements of one shape are gathered into one (n_elements, n_edof)
array, multiplied by that shape's element matrix in a single BLAS GEMM, and scattered back.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def gather(u: np.ndarray, edofs: np.ndarray, start: int, stop: int, buf: np.ndarray) -> None:
    """buf[e - start, :] = u[edofs[e, :]] for the elements start..stop-1."""
    n = edofs.shape[1]
    for e in range(start, stop):
        row = e - start
        for a in range(n):
            buf[row, a] = u[edofs[e, a]]


@njit(cache=True)
def scatter_add(out: np.ndarray, edofs: np.ndarray, start: int, stop: int, buf: np.ndarray) -> None:
    """out[edofs[e, :]] += buf[e - start, :] for the elements start..stop-1."""
    n = edofs.shape[1]
    for e in range(start, stop):
        row = e - start
        for a in range(n):
            out[edofs[e, a]] += buf[row, a]


@njit(cache=True)
def apply_stiffness(
    u: np.ndarray,
    edofs: np.ndarray,
    offsets: np.ndarray,
    kes: np.ndarray,
    buf: np.ndarray,
    res: np.ndarray,
    out: np.ndarray,
) -> None:
    """out = K u, with elements grouped by shape (``offsets``) and one matrix ``kes[s]`` per shape.

    ``buf`` and ``res`` are work arrays of shape (max elements per shape, n_edof).
    """
    out[:] = 0.0
    for s in range(offsets.size - 1):
        start = offsets[s]
        stop = offsets[s + 1]
        m = stop - start
        gather(u, edofs, start, stop, buf)
        # element matrices are symmetric: (buf @ K)[e] = K @ u_e
        np.dot(buf[:m], kes[s], res[:m])
        scatter_add(out, edofs, start, stop, res)


@njit(cache=True)
def run_plate_point_force(
    force: np.ndarray,
    dof: int,
    dt: float,
    inv_mass: np.ndarray,
    edofs: np.ndarray,
    offsets: np.ndarray,
    kes: np.ndarray,
    record_dofs: np.ndarray,
) -> np.ndarray:
    """Central differences from rest under a force history at one dof; records some dofs.

    u_{n+1} = u_n + dt v_{n+1/2},  v_{n+1/2} = v_{n-1/2} + dt M^-1 (f_n - K u_n), f_n = force[n] e_dof.
    Returns rec[n, r] = u_n[record_dofs[r]] for n = 0..len(force) (u_0 = 0).
    """
    ndof = inv_mass.size
    nsteps = force.size
    nrec = record_dofs.size
    u = np.zeros(ndof)
    v = np.zeros(ndof)
    ku = np.zeros(ndof)
    width = 0
    for s in range(offsets.size - 1):
        width = max(width, offsets[s + 1] - offsets[s])
    buf = np.empty((width, edofs.shape[1]))
    res = np.empty((width, edofs.shape[1]))
    rec = np.zeros((nsteps + 1, nrec))
    for n in range(nsteps):
        apply_stiffness(u, edofs, offsets, kes, buf, res, ku)
        ku[dof] -= force[n]
        for i in range(ndof):
            v[i] -= dt * inv_mass[i] * ku[i]
            u[i] += dt * v[i]
        for r in range(nrec):
            rec[n + 1, r] = u[record_dofs[r]]
    return rec


@njit(cache=True)
def plate_step(
    u: np.ndarray,
    v: np.ndarray,
    force: float,
    dof: int,
    dt: float,
    inv_mass: np.ndarray,
    edofs: np.ndarray,
    offsets: np.ndarray,
    kes: np.ndarray,
    buf: np.ndarray,
    res: np.ndarray,
    ku: np.ndarray,
) -> None:
    """One central-difference step of the plate in place (see ``run_plate_point_force``).

    On return ``ku`` holds K u_n (the old displacement), which the caller may use for energy.
    """
    apply_stiffness(u, edofs, offsets, kes, buf, res, ku)
    ndof = u.size
    for i in range(ndof):
        f = -ku[i]
        if i == dof:
            f += force
        v[i] += dt * inv_mass[i] * f
        u[i] += dt * v[i]
