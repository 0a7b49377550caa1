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

Order [4, 4] (every mesh the tiers build) has a kernel of its own that runs these operations on
16 elements at a time, each lane of a vector one element, and adds the results onto the nodes
element by element in order: the same result, bit for bit, as one element at a time, 2.5-3.5
times faster with AVX-512 (1.6 with SSE2 alone). Other orders go one element at a time.
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


#: Elements the order-[4, 4] kernel processes together, one per SIMD lane. The compiler vectorises
#: a loop over the lanes only with run-time checks that its arrays do not overlap, and it allows
#: those only from 16 iterations up.
LANES = 16


@njit(inline="always")
def _gather_block(u: np.ndarray, conn: np.ndarray, e0: int, nb: int, ue: np.ndarray,
                  nen: int, lanes: int) -> None:
    """ue[(3 a + c) lanes + l] = u[3 conn[e0 + l, a] + c] for the block's nb elements."""
    for el in range(nb):
        for a in range(nen):
            nd = 3 * conn[e0 + el, a]
            q = 3 * a * lanes + el
            ue[q] = u[nd]
            ue[q + lanes] = u[nd + 1]
            ue[q + 2 * lanes] = u[nd + 2]


@njit(inline="always")
def _scatter_block(res: np.ndarray, conn: np.ndarray, e0: int, nb: int, out: np.ndarray,
                   nen: int, lanes: int) -> None:
    """out[3 conn[e0 + l, a] + c] += res[(3 a + c) lanes + l], element by element in order,
    so that every dof receives its terms in the scalar kernel's order."""
    for el in range(nb):
        for a in range(nen):
            nd = 3 * conn[e0 + el, a]
            q = 3 * a * lanes + el
            out[nd] += res[q]
            out[nd + 1] += res[q + lanes]
            out[nd + 2] += res[q + 2 * lanes]


@njit(inline="always", fastmath={"contract"})
def _resultants_block(ue: np.ndarray, cst: np.ndarray, bend: float, nu: float, shear: float,
                      f: np.ndarray, n1: int, n2: int, lanes: int) -> None:
    """The weighted resultants of :func:`_mindlin_elements` (fx, fy, fq) for a block of
    elements, the same operations in the same order in each lane (layout: :func:`_mindlin_44`).
    """
    nen = n1 * n2
    fy = 3 * nen * lanes
    fq = 6 * nen * lanes
    dxo = 3 * lanes
    dyo = dxo + nen
    w2o = dyo + nen
    half = 0.5 * (1.0 - nu)
    for j in range(n2):
        for i in range(n1):
            # a from the loop indices, not a running count: the compiler then sees the lane
            # loop's indices as affine and non-negative, and vectorises it
            a = n1 * j + i
            q = 3 * a * lanes
            for el in range(lanes):
                rx = cst[el]
                ry = cst[lanes + el]
                wx = 0.0
                ax_ = 0.0
                bx = 0.0
                b = 3 * n1 * j * lanes + el
                for m in range(n1):
                    d = cst[dxo + n1 * i + m]
                    wx += d * ue[b]
                    ax_ += d * ue[b + lanes]
                    bx += d * ue[b + 2 * lanes]
                    b += 3 * lanes
                wy = 0.0
                ay = 0.0
                by = 0.0
                b = 3 * i * lanes + el
                for m in range(n2):
                    d = cst[dyo + n2 * j + m]
                    wy += d * ue[b]
                    ay += d * ue[b + lanes]
                    by += d * ue[b + 2 * lanes]
                    b += 3 * n1 * lanes
                wx *= rx
                ax_ *= rx
                bx *= rx
                wy *= ry
                ay *= ry
                by *= ry
                wq = cst[w2o + a] * cst[2 * lanes + el]
                qx = wq * shear * (wx + ue[q + lanes + el])
                qy = wq * shear * (wy + ue[q + 2 * lanes + el])
                mxx = wq * bend * (ax_ + nu * by)
                myy = wq * bend * (by + nu * ax_)
                mxy = wq * bend * half * (ay + bx)
                f[q + el] = rx * qx
                f[q + lanes + el] = rx * mxx
                f[q + 2 * lanes + el] = rx * mxy
                f[fy + q + el] = ry * qy
                f[fy + q + lanes + el] = ry * mxy
                f[fy + q + 2 * lanes + el] = ry * myy
                f[fq + q + lanes + el] = qx
                f[fq + q + 2 * lanes + el] = qy


@njit(inline="always", fastmath={"contract"})
def _divergence_block(f: np.ndarray, cst: np.ndarray, res: np.ndarray, n1: int, n2: int,
                      lanes: int) -> None:
    """res = the transposed derivatives of the resultants plus fq (each element's K u), per
    lane in :func:`_mindlin_elements`' order (layout: :func:`_mindlin_44`)."""
    nen = n1 * n2
    fy = 3 * nen * lanes
    fq = 6 * nen * lanes
    dxo = 3 * lanes
    dyo = dxo + nen
    for j in range(n2):
        for i in range(n1):
            q = 3 * (n1 * j + i) * lanes
            for el in range(lanes):
                r0 = 0.0
                r1 = f[fq + q + lanes + el]
                r2 = f[fq + q + 2 * lanes + el]
                b = 3 * n1 * j * lanes + el
                for m in range(n1):
                    d = cst[dxo + n1 * m + i]
                    r0 += d * f[b]
                    r1 += d * f[b + lanes]
                    r2 += d * f[b + 2 * lanes]
                    b += 3 * lanes
                b = fy + 3 * i * lanes + el
                for m in range(n2):
                    d = cst[dyo + n2 * m + j]
                    r0 += d * f[b]
                    r1 += d * f[b + lanes]
                    r2 += d * f[b + 2 * lanes]
                    b += 3 * n1 * lanes
                res[q + el] = r0
                res[q + lanes + el] = r1
                res[q + 2 * lanes + el] = r2


@njit(cache=True, fastmath={"contract"})
def _mindlin_44(u: np.ndarray, conn: np.ndarray, geom: np.ndarray, dx: np.ndarray,
                dy: np.ndarray, w2: np.ndarray, bend: float, nu: float, shear: float,
                out: np.ndarray) -> None:
    """Order [4, 4] (the default in-plane mesh): :func:`_mindlin_elements`' arithmetic on
    ``LANES`` elements at a time, as vector operations across them (the scalar loop is bound by
    the issue of its ~1,700 scalar multiply-adds per element).

    Work arrays hold one row of ``LANES`` values per quantity: ``ue`` the block's 75 dofs (then
    its results), ``f`` the resultants fx, fy and fq (75 rows each; fq in rows 3 a + 1 and
    3 a + 2, so that all of a node's stores lie at fixed distances, which the compiler can
    check), ``cst`` [rx, ry, jac] per lane, then dx, dy and w2. Each lane loop reads two arrays
    and writes a third: few run-time overlap checks.
    """
    n1 = 5
    n2 = 5
    lanes = LANES
    nen = n1 * n2
    # zeros: a short last block computes on finite values that it never scatters
    ue = np.zeros(3 * nen * lanes)
    f = np.zeros(9 * nen * lanes)
    cst = np.ones(3 * lanes + 3 * nen)  # by loops: numba compiles a slice copy for seconds
    for i in range(n1):
        for m in range(n1):
            cst[3 * lanes + n1 * i + m] = dx[i, m]
    for j in range(n2):
        for m in range(n2):
            cst[3 * lanes + nen + n2 * j + m] = dy[j, m]
    for a in range(nen):
        cst[3 * lanes + 2 * nen + a] = w2[a]
    ne = conn.shape[0]
    for e0 in range(0, ne, lanes):
        nb = min(lanes, ne - e0)
        for el in range(nb):
            cst[el] = geom[e0 + el, 0]
            cst[lanes + el] = geom[e0 + el, 1]
            cst[2 * lanes + el] = geom[e0 + el, 2]
        _gather_block(u, conn, e0, nb, ue, nen, lanes)
        _resultants_block(ue, cst, bend, nu, shear, f, n1, n2, lanes)
        _divergence_block(f, cst, ue, n1, n2, lanes)  # the results replace the dofs
        _scatter_block(ue, conn, e0, nb, out, nen, lanes)


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
