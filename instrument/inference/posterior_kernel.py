"""Two sums over the posterior's cells, with the per-cell work compiled.

:mod:`.posterior` asks, per sphere size resting on floor cells, how much of the posterior lies
where the size's TOF and ARR are explained without the floor's looseness, and the posterior mean
of the deviance (p_D). As numpy expressions each builds half a dozen temporaries over the
114,000 cells and gathers through a boolean mask; here one pass gives the mask, or the masked
products in numpy's order, and numpy sums them as before: the numbers are the same to the bit.

Self-contained, like :mod:`.likelihood_kernel` (numba's check of this file's timestamp keeps
its cache true).
"""

from __future__ import annotations

import numpy as np
from numba import njit


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
def weighted_excess(post: np.ndarray, misfit: np.ndarray, logdet: np.ndarray,
                    bound: np.ndarray, finite: np.ndarray, best: float, count: int
                    ) -> np.ndarray:
    """``post * (misfit + logdet + bound - best)`` over the ``count`` cells with ``finite``, in
    C order (what numpy's boolean indexing gives)."""
    out = np.empty(count)
    k = 0
    n_t, n_l = post.shape
    for i in range(n_t):
        for j in range(n_l):
            if finite[i, j]:
                out[k] = post[i, j] * (((misfit[i, j] + logdet[i, j]) + bound[i, j]) - best)
                k += 1
    return out


def warm() -> None:
    """Load (on a fresh install: compile) both kernels, on one cell with the argument types the
    posterior passes."""
    one, row = np.ones((1, 1)), np.ones(1)
    strict_mask(one, one, one, one, row, row, 1.0, row, row, 1.0, 1.0)
    weighted_excess(one, one, one, one, np.ones((1, 1), dtype=np.bool_), 0.0, 1)
