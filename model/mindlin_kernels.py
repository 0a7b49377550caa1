"""Numba kernel of the Mindlin-Reissner plate: the stiffness product by sum factorisation.

Dofs are (w, theta_x, theta_y) per in-plane GLL node, dof = 3 node + c: w the deflection (z up),
theta the rotations of the normal, so that the in-plane displacement at height z above the
mid-plane is z theta. Per element, the kernel takes the derivatives of the three fields at the GLL
nodes with the 1-D derivative matrices, forms the quadrature-weighted stress resultants

    M_xx = D (k_xx + nu k_yy),  M_yy = D (k_yy + nu k_xx),  M_xy = D (1 - nu) / 2 k_xy,
    Q_x = kappa G t (w_x + theta_x),  Q_y = kappa G t (w_y + theta_y),

with k_xx = theta_x,x, k_yy = theta_y,y, k_xy = theta_x,y + theta_y,x, and applies the transposed
derivatives. That is (Ku) = B^T C B u of the element matrices in :mod:`solitonde.model.mindlin`,
at about 1,700 multiply-adds per element of order 4 instead of 5,625 for the dense 75 x 75
matrix.
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: Tuple length of a Mindlin operator: (conn, geom, dx, dy, w2, constants). The stiffness product
#: of :mod:`solitonde.model.sem_kernels` tells operator forms apart by it.
MINDLIN_LEN = 6


def mindlin_operator(conn: np.ndarray, geom: np.ndarray, dx: np.ndarray, dy: np.ndarray,
                     w2: np.ndarray, constants: np.ndarray) -> tuple:
    """The sum-factorised Mindlin operator.

    conn: (n_elements, (px+1)(py+1)) node numbers, local order i + (px+1) j (x fastest).
    geom: (n_elements, 3) per element [2/hx, 2/hy, hx hy / 4] (inverse Jacobian, determinant).
    dx, dy: reference GLL derivative matrices D[i, l] = l_l'(xi_i) along x and y.
    w2: (nloc,) products of the 1-D GLL weights, local order as ``conn``.
    constants: [D, nu, kappa G t]: bending stiffness E t^3 / (12 (1 - nu^2)) (N m), Poisson's
        ratio and shear stiffness (N/m).
    """
    n1, n2 = dx.shape[0], dy.shape[0]
    if conn.shape[1] != n1 * n2 or w2.size != n1 * n2 or geom.shape != (conn.shape[0], 3):
        raise ValueError(f"Mindlin operator: conn {conn.shape}, geom {geom.shape} and w2 "
                         f"{w2.shape} do not fit derivative matrices of {n1} and {n2} points")
    return tuple(np.ascontiguousarray(a, dtype=t) for a, t in (
        (conn, np.int64), (geom, float), (dx, float), (dy, float), (w2, float),
        (constants, float)))


@njit(inline="always", fastmath={"contract"})
def _mindlin_elements(u: np.ndarray, conn: np.ndarray, geom: np.ndarray, dx: np.ndarray,
                      dy: np.ndarray, w2: np.ndarray, bend: float, nu: float, shear: float,
                      out: np.ndarray, n1: int, n2: int) -> None:
    """out += K u over all elements (n1, n2 GLL points per axis; inlined so loops unroll)."""
    nen = n1 * n2
    ue = np.empty(3 * nen)
    fx = np.empty(3 * nen)  # w |J| (2/hx) x the resultant each field's x-derivative meets
    fy = np.empty(3 * nen)
    fq = np.empty(2 * nen)  # w |J| (Q_x, Q_y): what theta itself meets
    half = 0.5 * (1.0 - nu)
    for e in range(conn.shape[0]):
        rx = geom[e, 0]
        ry = geom[e, 1]
        jac = geom[e, 2]
        for a in range(nen):
            nd = 3 * conn[e, a]
            ue[3 * a] = u[nd]
            ue[3 * a + 1] = u[nd + 1]
            ue[3 * a + 2] = u[nd + 2]
        a = 0
        for j in range(n2):
            for i in range(n1):
                wx = 0.0
                ax_ = 0.0
                bx = 0.0
                b = 3 * n1 * j
                for m in range(n1):
                    d = dx[i, m]
                    wx += d * ue[b]
                    ax_ += d * ue[b + 1]
                    bx += d * ue[b + 2]
                    b += 3
                wy = 0.0
                ay = 0.0
                by = 0.0
                b = 3 * i
                for m in range(n2):
                    d = dy[j, m]
                    wy += d * ue[b]
                    ay += d * ue[b + 1]
                    by += d * ue[b + 2]
                    b += 3 * n1
                wx *= rx
                ax_ *= rx
                bx *= rx
                wy *= ry
                ay *= ry
                by *= ry
                q = 3 * a
                wq = w2[a] * jac
                qx = wq * shear * (wx + ue[q + 1])
                qy = wq * shear * (wy + ue[q + 2])
                mxx = wq * bend * (ax_ + nu * by)
                myy = wq * bend * (by + nu * ax_)
                mxy = wq * bend * half * (ay + bx)
                fx[q] = rx * qx
                fx[q + 1] = rx * mxx
                fx[q + 2] = rx * mxy
                fy[q] = ry * qy
                fy[q + 1] = ry * mxy
                fy[q + 2] = ry * myy
                fq[2 * a] = qx
                fq[2 * a + 1] = qy
                a += 1
        a = 0
        for j in range(n2):
            for i in range(n1):
                r0 = 0.0
                r1 = fq[2 * a]
                r2 = fq[2 * a + 1]
                b = 3 * n1 * j
                for m in range(n1):
                    d = dx[m, i]
                    r0 += d * fx[b]
                    r1 += d * fx[b + 1]
                    r2 += d * fx[b + 2]
                    b += 3
                b = 3 * i
                for m in range(n2):
                    d = dy[m, j]
                    r0 += d * fy[b]
                    r1 += d * fy[b + 1]
                    r2 += d * fy[b + 2]
                    b += 3 * n1
                nd = 3 * conn[e, a]
                out[nd] += r0
                out[nd + 1] += r1
                out[nd + 2] += r2
                a += 1


@njit(cache=True, fastmath={"contract"})
def _mindlin_44(u: np.ndarray, conn: np.ndarray, geom: np.ndarray, dx: np.ndarray,
                dy: np.ndarray, w2: np.ndarray, bend: float, nu: float, shear: float,
                out: np.ndarray) -> None:
    """Order [4, 4] (the default in-plane mesh) with loop lengths known to the compiler."""
    _mindlin_elements(u, conn, geom, dx, dy, w2, bend, nu, shear, out, 5, 5)


@njit(cache=True, fastmath={"contract"})
def _mindlin_any(u: np.ndarray, conn: np.ndarray, geom: np.ndarray, dx: np.ndarray,
                 dy: np.ndarray, w2: np.ndarray, bend: float, nu: float, shear: float,
                 out: np.ndarray) -> None:
    """Any orders (loop lengths at run time)."""
    _mindlin_elements(u, conn, geom, dx, dy, w2, bend, nu, shear, out, dx.shape[0], dy.shape[0])


@njit(cache=True)
def apply_stiffness_mindlin(u: np.ndarray, conn: np.ndarray, geom: np.ndarray, dx: np.ndarray,
                            dy: np.ndarray, w2: np.ndarray, constants: np.ndarray,
                            out: np.ndarray) -> None:
    """out = K u of the Mindlin plate (arguments: see :func:`mindlin_operator`)."""
    out[:] = 0.0
    if dx.shape[0] == 5 and dy.shape[0] == 5:
        _mindlin_44(u, conn, geom, dx, dy, w2, constants[0], constants[1], constants[2], out)
    else:
        _mindlin_any(u, conn, geom, dx, dy, w2, constants[0], constants[1], constants[2], out)
