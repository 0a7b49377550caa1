"""The posterior's per-cell passes, compiled.

:mod:`.likelihood` sums the deviance and finds its best cell as it adds the last terms
(:func:`total_and_best`); :mod:`.cell_posterior` turns it into the normalised posterior on the
cells that may carry weight (:func:`exponents`, :func:`weigh`); :mod:`.posterior` asks, per
sphere size resting on floor cells, how much of it lies where the size's TOF and ARR are
explained without the floor's looseness (:func:`strict_cells`). As numpy expressions each step
walks the 114,000 cells again and builds temporaries; here a pass does several steps at once, in
numpy's order per cell, and numpy still takes every exp and every sum: the numbers are the same
to the bit.

Most cells lie so far below the best that their posterior is exactly 0: ``exp`` of an exponent
under ``exp_zero`` (:data:`.cell_posterior.EXP_ZERO`) underflows to 0, and numpy's exp takes its
slow path there (eight times its normal cost; fifty times where the result is subnormal), which
made that one exp a fifth of an inversion. :func:`exponents` hands numpy's exp only the other
cells (numpy's exp is the same per element whatever array the element lies in).

Self-contained, like :mod:`.likelihood_kernel` (numba's check of this file's timestamp keeps
its cache true): constants come as arguments.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy", nogil=True)
def total_and_best(misfit: np.ndarray, logdet: np.ndarray, penalty: np.ndarray,
                   bound: np.ndarray, out: np.ndarray, row_min: np.ndarray, start: int,
                   stop: int) -> int:
    """``out`` = ``misfit + logdet + penalty + bound`` (``Deviance.total``'s order) on the rows
    ``start..stop-1``, each row's least value into ``row_min`` (NaN if it has one); returns the
    flat index of their least cell as ``np.argmin`` gives it (the first of equal ones, the
    first NaN if there is one), so ``out.flat[index]`` is what the rows' ``min()`` gives."""
    n_l = out.shape[1]
    best = np.inf
    at = -1
    k = start * n_l
    for i in range(start, stop):
        low = np.inf
        for j in range(n_l):
            v = ((misfit[i, j] + logdet[i, j]) + penalty[i, j]) + bound[i, j]
            out[i, j] = v
            if v < low or (v != v and low == low):
                low = v
            if at < 0 or v < best or (v != v and best == best):
                best = v
                at = k
            k += 1
        row_min[i] = low
    return at


@njit(cache=True, error_model="numpy")
def exponents(chi2: np.ndarray, best: float, exp_zero: float, row_min: np.ndarray,
              cells: np.ndarray, rows: np.ndarray, cols: np.ndarray, x: np.ndarray,
              over: np.ndarray) -> int:
    """The cells whose exponent ``-0.5 (chi2 - best)`` is not under ``exp_zero`` (NaN
    included), in C order: their flat indices, rows and columns (into ``cells``, ``rows``,
    ``cols``), that exponent (into ``x``) and ``chi2 - best`` (into ``over``); returns how many.
    A row whose least value ``row_min`` gives an exponent under ``exp_zero`` has no such cell
    (rounding keeps the order) and is skipped."""
    n_t, n_l = chi2.shape
    count = 0
    for i in range(n_t):
        if (row_min[i] - best) * -0.5 < exp_zero:
            continue
        k = i * n_l
        for j in range(n_l):
            d = chi2[i, j] - best
            e = d * -0.5
            if not e < exp_zero:
                cells[count] = k + j
                rows[count] = i
                cols[count] = j
                x[count] = e
                over[count] = d
                count += 1
    return count


@njit(cache=True, error_model="numpy")
def weigh(rows: np.ndarray, cols: np.ndarray, like: np.ndarray, weight_t: np.ndarray,
          weight_l: np.ndarray, weight: np.ndarray, profile_t: np.ndarray,
          profile_l: np.ndarray) -> None:
    """The unnormalised posterior and the profile likelihoods from the likelihood ``like`` at
    the cells ``rows``, ``cols`` (in C order; every other cell's likelihood is 0): each cell's
    likelihood times the prior mass ``weight_t`` x ``weight_l`` (in that order, into
    ``weight``); ``profile_t``, ``profile_l`` the maximum per row and per column, from 0
    (``np.maximum``'s: NaN once one is NaN). A row's maximum is kept in a register while its
    cells run (they are consecutive)."""
    profile_t[:] = 0.0
    profile_l[:] = 0.0
    n = 0
    while n < like.size:
        i = rows[n]
        w_t = weight_t[i]
        top = 0.0
        while n < like.size and rows[n] == i:
            j = cols[n]
            v = like[n]
            weight[n] = (v * w_t) * weight_l[j]
            if v > top or (v != v and top == top):
                top = v
            if v > profile_l[j] or (v != v and profile_l[j] == profile_l[j]):
                profile_l[j] = v
            n += 1
        profile_t[i] = top


@njit(cache=True, error_model="numpy")
def masses(rows: np.ndarray, cols: np.ndarray, weight: np.ndarray, mass_t: np.ndarray,
           mass_l: np.ndarray) -> None:
    """Each cell's ``weight`` added to its row's ``mass_t`` and its column's ``mass_l``, in the
    cells' order from 0 (``np.bincount``'s: the same sums to the bit); the cells in C order, a
    row's sum is kept in a register while its cells run."""
    mass_t[:] = 0.0
    mass_l[:] = 0.0
    n = 0
    while n < weight.size:
        i = rows[n]
        total = 0.0
        while n < weight.size and rows[n] == i:
            total += weight[n]
            mass_l[cols[n]] += weight[n]
            n += 1
        mass_t[i] = total


@njit(cache=True, error_model="numpy", nogil=True)
def strict_cells(tof: np.ndarray, arr: np.ndarray, tof_var: np.ndarray, arr_var: np.ndarray,
                 tof_obs: np.ndarray, tof_var_add: np.ndarray, arr_obs: float,
                 factor: np.ndarray, f_std: np.ndarray, arr_var_add: float, limit: float,
                 cells: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Whether each of ``cells`` (flat indices; ``cols`` their distance columns) has a chi^2
    against the strict model error of at most ``limit``: TOF ``(tof_obs - tof)^2 / (tof_var_add
    + tof_var)`` plus ARR ``(arr_obs - factor arr)^2 / (arr_var_add + factor^2 arr_var +
    (f_std arr)^2)``; ``tof_obs`` (the measured TOF less the offset), ``tof_var_add``,
    ``factor`` and ``f_std`` per distance column."""
    tof, arr, tof_var, arr_var = tof.ravel(), arr.ravel(), tof_var.ravel(), arr_var.ravel()
    out = np.empty(cells.size, dtype=np.bool_)
    for n in range(cells.size):
        k = cells[n]
        j = cols[n]
        a = tof_obs[j] - tof[k]
        b = arr_obs - factor[j] * arr[k]
        c = f_std[j] * arr[k]
        chi2 = (a * a) / (tof_var_add[j] + tof_var[k]) + (b * b) / (
            (arr_var_add + (factor[j] * factor[j]) * arr_var[k]) + c * c)
        out[n] = chi2 <= limit
    return out


def warm() -> None:
    """Load (on a fresh install: compile) the kernels, on one cell with the argument types the
    posterior passes."""
    one, row = np.ones((1, 1)), np.ones(1)
    cell = np.zeros(1, dtype=np.intp)
    total_and_best(one, one, one, one, np.empty((1, 1)), np.empty(1), 0, 1)
    exponents(one, 0.0, -746.0, row, cell, cell.copy(), cell.copy(), np.empty(1), np.empty(1))
    weigh(cell, cell, row, row, row, np.empty(1), np.empty(1), np.empty(1))
    masses(cell, cell, row, np.empty(1), np.empty(1))
    strict_cells(one, one, one, one, row, row, 1.0, row, row, 1.0, 1.0, cell, cell)
