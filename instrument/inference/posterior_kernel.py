"""The posterior's per-cell passes, compiled.

:mod:`.posterior` turns the deviance into the normalised posterior, then asks, per sphere size
resting on floor cells, how much of it lies where the size's TOF and ARR are explained without
the floor's looseness, and the posterior mean of the deviance (p_D). As numpy expressions each
step walks the 114,000 cells again and builds temporaries; here a pass does several steps at
once, in numpy's order per cell, and numpy still takes every exp and every sum: the numbers are
the same to the bit.

Most cells lie so far below the best that their posterior is exactly 0: ``exp`` of an exponent
under :data:`EXP_ZERO` underflows to 0, and numpy's exp takes its slow path there (eight times
its normal cost; fifty times where the result is subnormal), which made that one exp a fifth of
an inversion. :func:`exponents` hands numpy's exp only the other cells (numpy's exp is the same
per element whatever array the element lies in), and :func:`weigh` writes 0 at the rest.

Self-contained, like :mod:`.likelihood_kernel` (numba's check of this file's timestamp keeps
its cache true).
"""

from __future__ import annotations

import numpy as np
from numba import njit

EXP_ZERO = -746.0
"""An exponent below which ``exp`` is exactly 0: below ln(2^-1075) = -745.13 the result is under
half the smallest subnormal and rounds to 0 (tests/instrument/test_likelihood_kernel.py checks
numpy's exp does)."""


@njit(cache=True, error_model="numpy")
def total_and_best(misfit: np.ndarray, logdet: np.ndarray, penalty: np.ndarray,
                   bound: np.ndarray, out: np.ndarray) -> int:
    """``out`` = ``misfit + logdet + penalty + bound`` (``Deviance.total``'s order); returns the
    flat index of its least cell as ``np.argmin`` gives it (the first of equal ones, the first
    NaN if there is one), so ``out.flat[index]`` is what ``out.min()`` gives."""
    n_t, n_l = out.shape
    best = np.inf
    at = -1
    k = 0
    for i in range(n_t):
        for j in range(n_l):
            v = ((misfit[i, j] + logdet[i, j]) + penalty[i, j]) + bound[i, j]
            out[i, j] = v
            if at < 0 or v < best or (v != v and best == best):
                best = v
                at = k
            k += 1
    return at


@njit(cache=True, error_model="numpy")
def exponents(chi2: np.ndarray, best: float, finite: np.ndarray, cells: np.ndarray,
              x: np.ndarray) -> int:
    """``chi2 -= best`` in place and ``finite`` where the result is finite; the cells (flat
    indices, into ``cells``) whose exponent ``-0.5 chi2`` is not under :data:`EXP_ZERO` (NaN
    included), with that exponent (into ``x``), in C order; returns how many."""
    n_t, n_l = chi2.shape
    count = 0
    k = 0
    for i in range(n_t):
        for j in range(n_l):
            d = chi2[i, j] - best
            chi2[i, j] = d
            finite[i, j] = np.isfinite(d)
            e = d * -0.5
            if not e < EXP_ZERO:
                cells[count] = k
                x[count] = e
                count += 1
            k += 1
    return count


@njit(cache=True, error_model="numpy")
def weigh(cells: np.ndarray, like: np.ndarray, weight_t: np.ndarray, weight_l: np.ndarray,
          post: np.ndarray, profile_t: np.ndarray, profile_l: np.ndarray) -> None:
    """The unnormalised posterior and the profile likelihoods from the likelihood ``like`` at
    ``cells`` (flat indices, in C order; every other cell's likelihood is 0): ``post`` the
    likelihood times the prior mass ``weight_t`` x ``weight_l`` (in that order), 0 elsewhere;
    ``profile_t``, ``profile_l`` its maximum per row and per column (``np.max``'s: NaN if one
    is NaN)."""
    n_l = post.shape[1]
    post[:] = 0.0
    profile_t[:] = 0.0
    profile_l[:] = 0.0
    for n in range(cells.size):
        k = cells[n]
        i = k // n_l
        j = k - i * n_l
        v = like[n]
        post[i, j] = (v * weight_t[i]) * weight_l[j]
        if v > profile_t[i] or (v != v and profile_t[i] == profile_t[i]):
            profile_t[i] = v
        if v > profile_l[j] or (v != v and profile_l[j] == profile_l[j]):
            profile_l[j] = v


@njit(cache=True, error_model="numpy")
def strict_mask(tof: np.ndarray, arr: np.ndarray, tof_var: np.ndarray, arr_var: np.ndarray,
                tof_obs: np.ndarray, tof_var_add: np.ndarray, arr_obs: float,
                factor: np.ndarray, f_std: np.ndarray, arr_var_add: float, limit: float
                ) -> np.ndarray:
    """Cells whose chi^2 against the strict model error is at most ``limit``: TOF
    ``(tof_obs - tof)^2 / (tof_var_add + tof_var)`` plus ARR ``(arr_obs - factor arr)^2 /
    (arr_var_add + factor^2 arr_var + (f_std arr)^2)``; ``tof_obs`` (the measured TOF less the
    offset), ``tof_var_add``, ``factor`` and ``f_std`` per distance column."""
    n_t, n_l = tof.shape
    out = np.empty((n_t, n_l), dtype=np.bool_)
    for i in range(n_t):
        for j in range(n_l):
            a = tof_obs[j] - tof[i, j]
            b = arr_obs - factor[j] * arr[i, j]
            c = f_std[j] * arr[i, j]
            chi2 = (a * a) / (tof_var_add[j] + tof_var[i, j]) + (b * b) / (
                (arr_var_add + (factor[j] * factor[j]) * arr_var[i, j]) + c * c)
            out[i, j] = chi2 <= limit
    return out


@njit(cache=True, error_model="numpy")
def weighted_excess(post: np.ndarray, excess: np.ndarray, finite: np.ndarray, count: int
                    ) -> np.ndarray:
    """``post * excess`` over the ``count`` cells with ``finite``, in C order (what numpy's
    boolean indexing gives); ``excess`` the deviance over its minimum, as :func:`exponents`
    leaves it."""
    out = np.empty(count)
    k = 0
    n_t, n_l = post.shape
    for i in range(n_t):
        for j in range(n_l):
            if finite[i, j]:
                out[k] = post[i, j] * excess[i, j]
                k += 1
    return out


def warm() -> None:
    """Load (on a fresh install: compile) the kernels, on one cell with the argument types the
    posterior passes."""
    one, row = np.ones((1, 1)), np.ones(1)
    flag, cell = np.ones((1, 1), dtype=np.bool_), np.zeros(1, dtype=np.intp)
    total_and_best(one, one, one, one, np.empty((1, 1)))
    exponents(np.ones((1, 1)), 0.0, flag, cell, np.empty(1))
    weigh(cell, row, row, row, np.empty((1, 1)), np.empty(1), np.empty(1))
    strict_mask(one, one, one, one, row, row, 1.0, row, row, 1.0, 1.0)
    weighted_excess(one, one, flag, 1)
