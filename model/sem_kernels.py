"""Numba kernels of the spectral-element plate: matrix-free stiffness and central differences.

The stiffness is applied element by element without assembling a global matrix: the element
displacement vectors of all elements of one shape are gathered into one (n_elements, n_edof)
array, multiplied by that shape's element matrix in a single BLAS GEMM, and scattered back.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .chain import (
    PK_BOT_F,
    accelerations,
    chain_energy,
    contact_forces,
    damped_contact_forces,
    hertz,
    record_sample,
    sensor_reading,
    track_peaks,
    verlet_step,
)


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
def run_plate_load(
    force: np.ndarray,
    ldofs: np.ndarray,
    lw: np.ndarray,
    dt: float,
    inv_mass: np.ndarray,
    edofs: np.ndarray,
    offsets: np.ndarray,
    kes: np.ndarray,
    record_dofs: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Central differences from rest under force[n] spread as nodal forces force[n] lw on ldofs.

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
    width = 0
    for s in range(offsets.size - 1):
        width = max(width, offsets[s + 1] - offsets[s])
    buf = np.empty((width, edofs.shape[1]))
    res = np.empty((width, edofs.shape[1]))
    rec = np.zeros((nsteps + 1, nrec))
    wsum = np.zeros(nsteps + 1)
    for n in range(nsteps):
        apply_stiffness(u, edofs, offsets, kes, buf, res, ku)
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
    """One central-difference step of the plate in place (the scheme of ``run_plate_load``).

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
    u: np.ndarray, v: np.ndarray, w: float, a_s: float, a_b: float, inv_m: float, g: float,
    tau: float, f: np.ndarray, acc: np.ndarray, vpc: np.ndarray,
) -> tuple[float, float]:
    """Forces and accelerations of the chain at t = 0; returns (bottom force, dissipated power)."""
    n = u.size - 1
    contact_forces(u, a_s, f)
    f_bottom = hertz(a_b, u[n] - w)
    accelerations(f, f_bottom, inv_m, g, acc)
    power = 0.0
    if tau > 0.0:
        for i in range(n + 1):
            vpc[i] = v[i]
        power = damped_contact_forces(u, vpc, a_s, tau, f)
        accelerations(f, f_bottom, inv_m, g, acc)
    return f_bottom, power


@njit(cache=True)
def chain_substeps(
    u: np.ndarray, v: np.ndarray, acc: np.ndarray, f: np.ndarray, vpc: np.ndarray,
    w_old: float, w_new: float, r: int, dt: float, a_s: float, a_b: float, inv_m: float,
    g: float, tau: float, sensor: int, power: float, t_start: float, pk: np.ndarray,
) -> tuple[float, float, float]:
    """r chain steps of dt with the plate surface moving linearly from w_old to w_new.

    Returns (bottom force at the end, dissipated power at the end, energy dissipated).
    """
    dissipated = 0.0
    f_bottom = 0.0
    for s in range(1, r + 1):
        w = w_old + (w_new - w_old) * (s / r)
        power_before = power
        f_bottom, power = verlet_step(u, v, acc, f, vpc, w, a_s, a_b, inv_m, g, tau, dt)
        dissipated += 0.5 * dt * (power_before + power)
        track_peaks(pk, t_start + s * dt, dt, sensor_reading(f, f_bottom, sensor), f_bottom)
    return f_bottom, power, dissipated


@njit(cache=True)
def integrate_sem(
    u: np.ndarray,
    v: np.ndarray,
    u0: np.ndarray,
    m: float,
    g: float,
    a_s: float,
    a_b: float,
    f_static: float,
    tau: float,
    sensor: int,
    h: float,
    r: int,
    n_sub: int,
    n_samples: int,
    samples: np.ndarray,
    energy: np.ndarray,
    u_trace: np.ndarray,
    v_trace: np.ndarray,
    f_trace: np.ndarray,
    w_trace: np.ndarray,
    pk: np.ndarray,
    inv_mass: np.ndarray,
    mass: np.ndarray,
    edofs: np.ndarray,
    offsets: np.ndarray,
    kes: np.ndarray,
    ldofs: np.ndarray,
    lw: np.ndarray,
    up: np.ndarray,
    vp: np.ndarray,
    share: float,
) -> tuple[int, int, float, float, float]:
    """Chain on a spectral-element plate; the contract of ``boundary.integrate_dashpot``.

    ``h`` is the plate step, ``r`` chain steps per plate step, ``n_sub`` plate steps per sample.
    The contact force acts through the patch (vertical dofs ``ldofs``, weights ``lw`` summing to
    ``share``) and the Hertz spring sees the work-conjugate deflection w = -(lw . up) / share
    (z up); ``up``, ``vp`` hold the plate's displacement and velocity (in and out). ``share``
    is the part of the plate that is modelled (1/2 for a half model on a symmetry plane: it
    carries half the force and half the energy). Returns (status, samples recorded, final w,
    plate energy J, dissipated energy J); ``energy[k]`` is the full balance (chain + plate +
    dissipated).
    """
    n = u.size - 1
    ndof = up.size
    inv_m = 1.0 / m
    dt = h / r
    half = 0.5 * h
    f = np.empty(n)
    acc = np.empty(n + 1)
    vpc = np.empty(n + 1)
    ku = np.zeros(ndof)
    ap = np.zeros(ndof)
    width = 0
    for s in range(offsets.size - 1):
        width = max(width, offsets[s + 1] - offsets[s])
    buf = np.empty((width, edofs.shape[1]))
    res = np.empty((width, edofs.shape[1]))

    nl = ldofs.size
    w = patch_deflection(up, ldofs, lw, share)
    f_bottom, power = chain_start(u, v, w, a_s, a_b, inv_m, g, tau, f, acc, vpc)
    apply_stiffness(up, edofs, offsets, kes, buf, res, ku)
    for i in range(ndof):
        ap[i] = -inv_mass[i] * ku[i]
    for i in range(nl):
        ap[ldofs[i]] -= inv_mass[ldofs[i]] * (f_bottom - f_static) * lw[i]

    dissipated = 0.0
    e_plate = 0.0
    step = 0
    for k in range(n_samples):
        record_sample(k, u, v, f, w, a_b, sensor, samples, u_trace, v_trace, f_trace, w_trace)
        e_plate = plate_energy(up, vp, ap, ku, mass, w, f_static * share, h) / share
        energy[k] = chain_energy(u, v, u0, w, m, g, a_s, a_b) + e_plate + dissipated
        if not np.isfinite(samples[k]) or not np.isfinite(energy[k]):
            return 1, k + 1, w, e_plate, dissipated
        if k == n_samples - 1:
            break
        for _ in range(n_sub):
            for i in range(ndof):
                vp[i] += half * ap[i]
                up[i] += h * vp[i]
            w_old = w
            w = patch_deflection(up, ldofs, lw, share)
            f_bottom, power, lost = chain_substeps(
                u, v, acc, f, vpc, w_old, w, r, dt, a_s, a_b, inv_m, g, tau, sensor, power,
                step * h, pk,
            )
            dissipated += lost
            apply_stiffness(up, edofs, offsets, kes, buf, res, ku)
            for i in range(ndof):
                ap[i] = -inv_mass[i] * ku[i]
            for i in range(nl):
                ap[ldofs[i]] -= inv_mass[ldofs[i]] * (f_bottom - f_static) * lw[i]
            for i in range(ndof):
                vp[i] += half * ap[i]
            step += 1
    if not pk[PK_BOT_F] >= 0.0:
        return 1, n_samples, w, e_plate, dissipated
    return 0, n_samples, w, e_plate, dissipated
