"""Numba kernels of the spectral-element plate: matrix-free stiffness and central differences.

The stiffness is never assembled. Two forms of K u exist, both passed around as a plain tuple
(the *operator*) and applied by :func:`stiffness_product`, whose compiled form is chosen by the
tuple's type:

* sum-factorised (:func:`sumfact_operator`, the one the time loops use): per element, the
  displacement gradient at the GLL nodes by 1-D derivative matrices along each axis, the
  isotropic stress weighted by w_q |J|, and the transposed derivatives back onto the nodes
  (about 6,000 multiply-adds per element of order [4, 4, 2] instead of 50,625 for the dense
  element matrix);
* dense (:func:`dense_operator`, the reference): the element vectors of all elements of one shape
  gathered into one (n_elements, n_edof) array, multiplied by that shape's element matrix in a
  single BLAS GEMM, and scattered back.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit, types
from numba.extending import overload

from .chain import (
    PK_BOT_F,
    accelerations,
    chain_energy,
    contact_forces,
    damped_contact_forces,
    hertz,
    record_into,
    sensor_reading,
    track_peaks,
    verlet_step,
)
from .mindlin_kernels import MINDLIN_LEN, apply_stiffness_mindlin
from .record import ChainRecord
from .status import RUN_NONFINITE, RUN_OK

#: Tuple lengths that tell the two operator forms apart (see the constructors below).
DENSE_LEN = 5
SUMFACT_LEN = 7


# Dense element matrices (reference) ----------------------------------------------------------
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


def dense_operator(edofs: np.ndarray, offsets: np.ndarray, kes: np.ndarray) -> tuple:
    """The dense-element-matrix operator with its own work arrays (one per concurrent user).

    ``edofs`` (n_elements, n_edof) element dofs sorted by shape, ``offsets`` (n_shapes + 1,)
    element ranges per shape, ``kes`` (n_shapes, n_edof, n_edof) element matrices.
    """
    width = int(np.max(np.diff(offsets)))
    n = edofs.shape[1]
    return (edofs, offsets, kes, np.empty((width, n)), np.empty((width, n)))


# Sum factorisation -------------------------------------------------------------------------
def sumfact_operator(
    conn: np.ndarray, geom: np.ndarray, dx: np.ndarray, dy: np.ndarray, dz: np.ndarray,
    w3: np.ndarray, lame: np.ndarray,
) -> tuple:
    """The sum-factorised operator of box elements on GLL nodes with GLL quadrature.

    Parameters
    ----------
    conn: (n_elements, nloc) global node numbers, local order i + n1 (j + n2 k) (x fastest).
    geom: (n_elements, 4) per element [2/hx, 2/hy, 2/hz, hx hy hz / 8]: the (diagonal) inverse
        Jacobian and the Jacobian determinant of the box.
    dx, dy, dz: reference GLL derivative matrices D[i, l] = l_l'(xi_i) along x, y, z (orders may
        differ per axis).
    w3: (nloc,) products of the 1-D GLL weights, same local order as ``conn``.
    lame: [lambda, mu], Pa.
    """
    n1, n2, n3 = dx.shape[0], dy.shape[0], dz.shape[0]
    nloc = conn.shape[1]
    if nloc != n1 * n2 * n3 or w3.size != nloc or geom.shape != (conn.shape[0], 4):
        raise ValueError(f"sum-factorised operator: conn {conn.shape}, geom {geom.shape} and "
                         f"w3 {w3.shape} do not fit derivative matrices of {n1}, {n2}, {n3} points")
    return tuple(np.ascontiguousarray(a, dtype=t) for a, t in (
        (conn, np.int64), (geom, float), (dx, float), (dy, float), (dz, float), (w3, float),
        (lame, float)))


@njit(inline="always", fastmath={"contract"})
def _sumfact_elements(
    u: np.ndarray, conn: np.ndarray, geom: np.ndarray, dx: np.ndarray, dy: np.ndarray,
    dz: np.ndarray, w3: np.ndarray, lam: float, mu: float, out: np.ndarray,
    n1: int, n2: int, n3: int,
) -> None:
    """out += K u over all elements; n1, n2, n3 GLL points per axis (inlined: constants unroll).

    (K u)_(a,c) = sum_q w_q |J| sum_d G_qad sigma_cd(q), sigma = lambda div u I + mu (grad u +
    grad u^T), with G_qad = (2 / h_d) D_d[q_d, a_d] when q and a agree off axis d, else 0.
    """
    n12 = n1 * n2
    nen = n12 * n3
    ue = np.empty(3 * nen)
    fx = np.empty(3 * nen)  # w |J| (2/hx) sigma[c, x] at each node, then likewise y and z
    fy = np.empty(3 * nen)
    fz = np.empty(3 * nen)
    for e in range(conn.shape[0]):
        rx = geom[e, 0]
        ry = geom[e, 1]
        rz = geom[e, 2]
        lamj = lam * geom[e, 3]
        muj = mu * geom[e, 3]
        for a in range(nen):
            nd = 3 * conn[e, a]
            ue[3 * a] = u[nd]
            ue[3 * a + 1] = u[nd + 1]
            ue[3 * a + 2] = u[nd + 2]
        a = 0
        for k in range(n3):
            for j in range(n2):
                for i in range(n1):
                    # g_cd = d u_c / d x_d at node (i, j, k)
                    g00 = 0.0
                    g10 = 0.0
                    g20 = 0.0
                    b = 3 * n1 * (j + n2 * k)
                    for m in range(n1):
                        d = dx[i, m]
                        g00 += d * ue[b]
                        g10 += d * ue[b + 1]
                        g20 += d * ue[b + 2]
                        b += 3
                    g01 = 0.0
                    g11 = 0.0
                    g21 = 0.0
                    b = 3 * (i + n12 * k)
                    for m in range(n2):
                        d = dy[j, m]
                        g01 += d * ue[b]
                        g11 += d * ue[b + 1]
                        g21 += d * ue[b + 2]
                        b += 3 * n1
                    g02 = 0.0
                    g12 = 0.0
                    g22 = 0.0
                    b = 3 * (i + n1 * j)
                    for m in range(n3):
                        d = dz[k, m]
                        g02 += d * ue[b]
                        g12 += d * ue[b + 1]
                        g22 += d * ue[b + 2]
                        b += 3 * n12
                    g00 *= rx
                    g10 *= rx
                    g20 *= rx
                    g01 *= ry
                    g11 *= ry
                    g21 *= ry
                    g02 *= rz
                    g12 *= rz
                    g22 *= rz
                    wl = w3[a] * lamj * (g00 + g11 + g22)
                    wm = w3[a] * muj
                    s01 = wm * (g01 + g10)
                    s02 = wm * (g02 + g20)
                    s12 = wm * (g12 + g21)
                    q = 3 * a
                    fx[q] = rx * (wl + 2.0 * wm * g00)
                    fx[q + 1] = rx * s01
                    fx[q + 2] = rx * s02
                    fy[q] = ry * s01
                    fy[q + 1] = ry * (wl + 2.0 * wm * g11)
                    fy[q + 2] = ry * s12
                    fz[q] = rz * s02
                    fz[q + 1] = rz * s12
                    fz[q + 2] = rz * (wl + 2.0 * wm * g22)
                    a += 1
        a = 0
        for k in range(n3):
            for j in range(n2):
                for i in range(n1):
                    r0 = 0.0
                    r1 = 0.0
                    r2 = 0.0
                    b = 3 * n1 * (j + n2 * k)
                    for m in range(n1):
                        d = dx[m, i]
                        r0 += d * fx[b]
                        r1 += d * fx[b + 1]
                        r2 += d * fx[b + 2]
                        b += 3
                    b = 3 * (i + n12 * k)
                    for m in range(n2):
                        d = dy[m, j]
                        r0 += d * fy[b]
                        r1 += d * fy[b + 1]
                        r2 += d * fy[b + 2]
                        b += 3 * n1
                    b = 3 * (i + n1 * j)
                    for m in range(n3):
                        d = dz[m, k]
                        r0 += d * fz[b]
                        r1 += d * fz[b + 1]
                        r2 += d * fz[b + 2]
                        b += 3 * n12
                    nd = 3 * conn[e, a]
                    out[nd] += r0
                    out[nd + 1] += r1
                    out[nd + 2] += r2
                    a += 1


@njit(cache=True, fastmath={"contract"})
def _sumfact_442(
    u: np.ndarray, conn: np.ndarray, geom: np.ndarray, dx: np.ndarray, dy: np.ndarray,
    dz: np.ndarray, w3: np.ndarray, lam: float, mu: float, out: np.ndarray,
) -> None:
    """Order [4, 4, 2] (the default mesh) with the loop lengths known to the compiler."""
    _sumfact_elements(u, conn, geom, dx, dy, dz, w3, lam, mu, out, 5, 5, 3)


@njit(cache=True, fastmath={"contract"})
def _sumfact_443(
    u: np.ndarray, conn: np.ndarray, geom: np.ndarray, dx: np.ndarray, dy: np.ndarray,
    dz: np.ndarray, w3: np.ndarray, lam: float, mu: float, out: np.ndarray,
) -> None:
    """Order [4, 4, 3] (the accuracy reference mesh)."""
    _sumfact_elements(u, conn, geom, dx, dy, dz, w3, lam, mu, out, 5, 5, 4)


@njit(cache=True, fastmath={"contract"})
def _sumfact_any(
    u: np.ndarray, conn: np.ndarray, geom: np.ndarray, dx: np.ndarray, dy: np.ndarray,
    dz: np.ndarray, w3: np.ndarray, lam: float, mu: float, out: np.ndarray,
) -> None:
    """Any orders (loop lengths at run time: 1.1 to 3 times slower than a kernel of its own)."""
    _sumfact_elements(u, conn, geom, dx, dy, dz, w3, lam, mu, out,
                      dx.shape[0], dy.shape[0], dz.shape[0])


#: Orders with a kernel of their own (fixed loop lengths, which the compiler unrolls): the default
#: mesh and the accuracy reference. Each one costs about 2 s of first (cached) compilation.
SUMFACT_SPECIALISED = ((4, 4, 2), (4, 4, 3))


@njit(cache=True)
def apply_stiffness_sumfact(
    u: np.ndarray, conn: np.ndarray, geom: np.ndarray, dx: np.ndarray, dy: np.ndarray,
    dz: np.ndarray, w3: np.ndarray, lame: np.ndarray, out: np.ndarray,
) -> None:
    """out = K u by sum factorisation (arguments: see :func:`sumfact_operator`)."""
    out[:] = 0.0
    n1, n2, n3 = dx.shape[0], dy.shape[0], dz.shape[0]
    lam, mu = lame[0], lame[1]
    if n1 == 5 and n2 == 5 and n3 == 3:
        _sumfact_442(u, conn, geom, dx, dy, dz, w3, lam, mu, out)
    elif n1 == 5 and n2 == 5 and n3 == 4:
        _sumfact_443(u, conn, geom, dx, dy, dz, w3, lam, mu, out)
    else:
        _sumfact_any(u, conn, geom, dx, dy, dz, w3, lam, mu, out)


# Either form --------------------------------------------------------------------------------
def stiffness_product(op: tuple, u: np.ndarray, out: np.ndarray) -> None:
    """out = K u for an operator from :func:`sumfact_operator`, :func:`dense_operator` or
    :func:`~solitonde.model.mindlin_kernels.mindlin_operator`.

    Callable from Python and from compiled code (where the form is resolved at compile time).
    """
    if len(op) == DENSE_LEN:
        apply_stiffness(u, op[0], op[1], op[2], op[3], op[4], out)
    elif len(op) == SUMFACT_LEN:
        # numba's stubs type a dispatcher's call from its signature and cannot count *op
        apply_stiffness_sumfact(u, *op, out)  # type: ignore[call-arg]
    elif len(op) == MINDLIN_LEN:
        apply_stiffness_mindlin(u, *op, out)  # type: ignore[call-arg]
    else:
        raise TypeError(f"not a stiffness operator: a tuple of {len(op)} items")


@overload(stiffness_product)
def _stiffness_product_impl(op, u, out):
    """Compiled ``stiffness_product``: picks the kernel from the operator tuple's length."""
    if not isinstance(op, types.BaseTuple):
        return None
    if len(op) == DENSE_LEN:
        def dense(op, u, out):
            apply_stiffness(u, op[0], op[1], op[2], op[3], op[4], out)
        return dense
    if len(op) == SUMFACT_LEN:
        def sumfact(op, u, out):
            apply_stiffness_sumfact(u, op[0], op[1], op[2], op[3], op[4], op[5], op[6], out)
        return sumfact
    if len(op) == MINDLIN_LEN:
        def mindlin(op, u, out):
            apply_stiffness_mindlin(u, op[0], op[1], op[2], op[3], op[4], op[5], out)
        return mindlin
    return None


@njit(cache=True)
def run_plate_load(
    force: np.ndarray,
    ldofs: np.ndarray,
    lw: np.ndarray,
    dt: float,
    inv_mass: np.ndarray,
    op: tuple,
    record_dofs: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Central differences from rest under force[n] spread as nodal forces force[n] lw on ldofs.

    ``op`` is the stiffness operator (see :func:`stiffness_product`).
    Returns (wsum, rec): wsum[n] = sum_i lw_i u_n[ldofs_i] (the work-conjugate deflection times
    sum(lw)) and rec[n, r] = u_n[record_dofs[r]], n = 0..len(force), u_0 = 0.
    """
    ndof = inv_mass.size
    nsteps = force.size
    nrec = record_dofs.size
    nl = ldofs.size
    u = np.zeros(ndof)
    v = np.zeros(ndof)
    ku = np.zeros(ndof)
    rec = np.zeros((nsteps + 1, nrec))
    wsum = np.zeros(nsteps + 1)
    for n in range(nsteps):
        stiffness_product(op, u, ku)
        for i in range(nl):
            ku[ldofs[i]] -= force[n] * lw[i]
        for i in range(ndof):
            v[i] -= dt * inv_mass[i] * ku[i]
            u[i] += dt * v[i]
        for r in range(nrec):
            rec[n + 1, r] = u[record_dofs[r]]
        acc = 0.0
        for i in range(nl):
            acc += lw[i] * u[ldofs[i]]
        wsum[n + 1] = acc
    return wsum, rec


@njit(cache=True)
def patch_deflection(up: np.ndarray, ldofs: np.ndarray, lw: np.ndarray, share: float) -> float:
    """Downward deflection under the chain: -(sum lw u_z) / share (z up)."""
    acc = 0.0
    for i in range(ldofs.size):
        acc += lw[i] * up[ldofs[i]]
    return -acc / share


# Coupled chain + plate ----------------------------------------------------------------------
# Velocity Verlet for the plate (= central differences) with its own step h, the chain sub-cycled
# r times per plate step with the chain module's verlet_step: kick the plate by h/2 with the
# contact force at t_n and drift it to t_n + h; advance the chain r steps of h/r with the plate
# surface moving linearly from w_n to w_{n+1}; evaluate the contact force at t_n + h; kick the
# plate by h/2. With r = 1 this is velocity Verlet on the whole coupled system. The plate carries
# the chain's weight F_static before the impact, so only F_bottom - F_static drives its
# (dynamic) displacement; the static deflection shifts w by a constant that drops out of every
# overlap.


@njit(cache=True)
def plate_energy(
    up: np.ndarray, vp: np.ndarray, ap: np.ndarray, ku: np.ndarray, mass: np.ndarray,
    w: float, f_static: float, h: float,
) -> float:
    """Plate energy (dynamic part), J: 0.5 v M v + 0.5 u K u + F_static w - h^2/8 a M a.

    The last term turns the integer-step energy into central differences' exactly conserved
    quadratic invariant (0.5 v_{n+1/2} M v_{n+1/2} + 0.5 u_n K u_{n+1} for a free linear plate),
    so what remains in the balance is the coupling's own O(h^2) error, not the bounded
    oscillation of the high plate modes. F_static w is the work of the constant static load.
    """
    e = 0.0
    for i in range(up.size):
        e += 0.5 * mass[i] * (vp[i] * vp[i] - 0.25 * h * h * ap[i] * ap[i]) + 0.5 * up[i] * ku[i]
    return e + f_static * w


@njit(cache=True)
def chain_start(
    u: np.ndarray, v: np.ndarray, w: float, a_s: float, a_0: float, a_b: float, inv_m: float,
    inv_m0: float, g: float, tau: float, f: np.ndarray, acc: np.ndarray, vpc: np.ndarray,
) -> tuple[float, float]:
    """Forces and accelerations of the chain at t = 0; returns (bottom force, dissipated power).
    ``a_0``, ``inv_m0``: the striker's contact constant and inverse mass."""
    n = u.size - 1
    contact_forces(u, a_s, a_0, f)
    f_bottom = hertz(a_b, u[n] - w)
    accelerations(f, f_bottom, inv_m, inv_m0, g, acc)
    power = 0.0
    if tau > 0.0:
        for i in range(n + 1):
            vpc[i] = v[i]
        power = damped_contact_forces(u, vpc, a_s, a_0, tau, f)
        accelerations(f, f_bottom, inv_m, inv_m0, g, acc)
    return f_bottom, power


@njit(cache=True)
def chain_substeps(
    u: np.ndarray, v: np.ndarray, acc: np.ndarray, f: np.ndarray, vpc: np.ndarray,
    w_old: float, w_new: float, r: int, dt: float, a_s: float, a_0: float, a_b: float,
    inv_m: float, inv_m0: float, g: float, tau: float, sensor: int, power: float,
    t_start: float, pk: np.ndarray,
) -> tuple[float, float, float]:
    """r chain steps of dt with the plate surface moving linearly from w_old to w_new.

    Returns (bottom force at the end, dissipated power at the end, energy dissipated).
    """
    dissipated = 0.0
    f_bottom = 0.0
    for s in range(1, r + 1):
        w = w_old + (w_new - w_old) * (s / r)
        power_before = power
        f_bottom, power = verlet_step(u, v, acc, f, vpc, w, a_s, a_0, a_b, inv_m, inv_m0, g,
                                      tau, dt)
        dissipated += 0.5 * dt * (power_before + power)
        track_peaks(pk, t_start + s * dt, dt, sensor_reading(f, f_bottom, sensor), f_bottom)
    return f_bottom, power, dissipated


class SemPlate(NamedTuple):
    """The spectral-element plate as the coupled driver sees it.

    inv_mass, mass: per dof; op: the stiffness operator (:func:`stiffness_product`); ldofs, lw:
    the patch's vertical dofs and weights (summing to ``share``); up, vp: the plate's
    displacement and velocity (in and out); share: the modelled part of the plate (1/2 for a
    half model on a symmetry plane: it carries half the force and half the energy).
    """

    inv_mass: np.ndarray
    mass: np.ndarray
    op: tuple
    ldofs: np.ndarray
    lw: np.ndarray
    up: np.ndarray
    vp: np.ndarray
    share: float


@njit(cache=True)
def integrate_sem(
    rec: ChainRecord, h: float, r: int, n_sub: int, n_samples: int, plate: SemPlate
) -> tuple[int, int, float, float, float]:
    """Chain on a spectral-element plate; the contract of ``boundary.dashpot_run``.

    ``h`` is the plate step, ``r`` chain steps per plate step, ``n_sub`` plate steps per sample.
    The contact force acts through the patch and the Hertz spring sees the work-conjugate
    deflection w = -(lw . up) / share (z up). Returns (status, samples recorded, final w, plate
    energy J, dissipated energy J); ``rec.energy[k]`` is the full balance (chain + plate +
    dissipated).
    """
    u, v, u0, m, g, a_s, a_b = rec.u, rec.v, rec.u0, rec.m, rec.g, rec.a_s, rec.a_b
    f_static, tau, sensor, pk = rec.f_static, rec.tau, rec.sensor, rec.pk
    inv_mass, mass, op, ldofs, lw = plate.inv_mass, plate.mass, plate.op, plate.ldofs, plate.lw
    up, vp, share = plate.up, plate.vp, plate.share
    n = u.size - 1
    ndof = up.size
    inv_m = 1.0 / m
    m0, a_0 = rec.m0, rec.a_0
    inv_m0 = 1.0 / m0
    dt = h / r
    half = 0.5 * h
    f = np.empty(n)
    acc = np.empty(n + 1)
    vpc = np.empty(n + 1)
    ku = np.zeros(ndof)
    ap = np.zeros(ndof)

    nl = ldofs.size
    w = patch_deflection(up, ldofs, lw, share)
    f_bottom, power = chain_start(u, v, w, a_s, a_0, a_b, inv_m, inv_m0, g, tau, f, acc, vpc)
    stiffness_product(op, up, ku)
    for i in range(ndof):
        ap[i] = -inv_mass[i] * ku[i]
    for i in range(nl):
        ap[ldofs[i]] -= inv_mass[ldofs[i]] * (f_bottom - f_static) * lw[i]

    dissipated = 0.0
    e_plate = 0.0
    step = 0
    for k in range(n_samples):
        record_into(rec, k, f, w)
        e_plate = plate_energy(up, vp, ap, ku, mass, w, f_static * share, h) / share
        rec.energy[k] = (chain_energy(u, v, u0, w, m, g, a_s, a_b, m0, a_0) + e_plate
                         + dissipated)
        if not np.isfinite(rec.samples[k]) or not np.isfinite(rec.energy[k]):
            return RUN_NONFINITE, k + 1, w, e_plate, dissipated
        if k == n_samples - 1:
            break
        for _ in range(n_sub):
            for i in range(ndof):
                vp[i] += half * ap[i]
                up[i] += h * vp[i]
            w_old = w
            w = patch_deflection(up, ldofs, lw, share)
            f_bottom, power, lost = chain_substeps(
                u, v, acc, f, vpc, w_old, w, r, dt, a_s, a_0, a_b, inv_m, inv_m0, g, tau, sensor,
                power, step * h, pk,
            )
            dissipated += lost
            stiffness_product(op, up, ku)
            for i in range(ndof):
                ap[i] = -inv_mass[i] * ku[i]
            for i in range(nl):
                ap[ldofs[i]] -= inv_mass[ldofs[i]] * (f_bottom - f_static) * lw[i]
            for i in range(ndof):
                vp[i] += half * ap[i]
            step += 1
    if not pk[PK_BOT_F] >= 0.0:
        return RUN_NONFINITE, n_samples, w, e_plate, dissipated
    return RUN_OK, n_samples, w, e_plate, dissipated
