"""The baseline drift of a shot, measured on every quiet stretch the chain gives: the pre-trigger
and the gap between the incident and the reflection.

The paper's ARR is the reflection's height over the incident's, both above the sensor's reading
before the impact. A drifting baseline (a charge amplifier's leak, temperature) adds its value at
each peak to that peak. The pre-trigger alone measures the drift badly: its slope, carried over
the record, is noisy, and a slope kept only where it stands out of the noise moves the mean ARR
with the noise. The gap between the pulses is ten times longer and lies next to the reflection,
but with gravity it is not quiet: the chain above the sensor lets go of part of its weight after
the incident and settles back, a level change of about the static preload. That relaxation is
the chain's own and blind to the plate until the reflection returns, so a model trace of the
chain gives it (``relax``: the clean sensor level above the pre-impact reading, one value per
sample from the incident's peak on; zeros without gravity). What is left in the gap once it is
subtracted is drift, measured with the pre-trigger's level at the other end of a long lever.

:func:`gap_drift` fits a quadratic in time to the pre-trigger and to the gap less the relaxation,
the same way on every shot (no choice that depends on the noise, so none that moves the mean).
On a noise-free model trace of the same chain the fit is the pre-impact reading: nothing
changes.

Compiled with numba; used by :mod:`.kernels`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .pulse_fit import solve_spd

GAP_FOOT = 2.0
"""The gap starts and ends this many FWHM from the incident's and the reflection's peaks (and
skips as much about every pulse of the incident's train): the relaxation is sampled at the
model's incident peak, so the steep flanks are left out, and the reflection's leading tail, the
plate's, never enters."""
MIN_GAP = 16
"""Fewest gap samples for a drift fit; a shorter gap leaves the pre-trigger's baseline."""
DEGREE = 2
"""The drift is a quadratic in time: a linear drift, and a slow curvature (a parabola of 5 % of
the incident over the record moves the ARR by 5-20 % when only a line is taken)."""
# Columns of the coefficient array gap_drift fills.
(D_C0, D_C1, D_C2, D_CENTRE, D_SCALE, D_GAP, D_MISFIT, D_MISFIT_N) = range(8)
DRIFT = 8


@njit(cache=True)
def _relaxation_at(relax: np.ndarray, k: float) -> float:
    """``relax`` linearly interpolated at ``k`` samples after the incident's peak."""
    k0 = int(np.floor(k))
    f = k - k0
    return relax[k0] * (1.0 - f) + relax[k0 + 1] * f


@njit(cache=True)
def _in_train(i: int, rows: np.ndarray, n_train: int, time_col: int, width_col: int) -> bool:
    """Whether sample ``i`` lies within :data:`GAP_FOOT` FWHM of a pulse of the incident's train
    (``rows[2:2 + n_train]``), which the drift's stretches leave out."""
    for j in range(2, 2 + n_train):
        if abs(i - rows[j, time_col]) <= GAP_FOOT * rows[j, width_col]:
            return True
    return False


@njit(cache=True)
def _accumulate(u: float, r: float, acc: np.ndarray, rhs: np.ndarray) -> None:
    """Add the sample ``r`` at scaled time ``u`` to the quadratic's normal equations."""
    p = 1.0
    for k in range(2 * DEGREE + 1):
        acc[k] += p
        if k <= DEGREE:
            rhs[k] += r * p
        p *= u


@njit(cache=True)
def gap_drift(y: np.ndarray, n_pre: int, rows: np.ndarray, n_train: int, relax: np.ndarray,
              time_col: int, width_col: int) -> np.ndarray:
    """The baseline ``c0 + c1 u + c2 u^2`` (``u = (i - centre) / scale`` at sample ``i``) fitted to
    ``y[:n_pre]`` and to ``y - relax`` over the gap between ``rows[0]`` (the incident) and
    ``rows[1]`` (the reflection), the ``n_train`` pulses after row 1 (the incident's train) left
    out with their flanks. ``time_col``, ``width_col``: the rows' columns of the fitted peak time
    and FWHM, in samples. Returns ``[c0, c1, c2, centre, scale, gap samples, misfit, its
    samples]``: the misfit is the largest mean residual of the fit over the pre-trigger and either
    half of the gap (in the trace's units), over that many samples. No fit (a gap under
    :data:`MIN_GAP` samples, no pre-trigger, a singular system) has 0 gap samples."""
    out = np.zeros(DRIFT)
    n = y.size
    t_inc = rows[0, time_col]
    lo = max(int(np.ceil(t_inc + GAP_FOOT * rows[0, width_col])), n_pre)
    hi = min(int(np.floor(rows[1, time_col] - GAP_FOOT * rows[1, width_col])),
             int(np.floor(t_inc)) + relax.size - 2, n)
    if n_pre < MIN_GAP or hi - lo < MIN_GAP:
        return out
    centre = 0.5 * hi
    scale = 0.5 * hi
    acc = np.zeros(2 * DEGREE + 1)
    rhs = np.zeros(DEGREE + 1)
    for i in range(n_pre):
        _accumulate((i - centre) / scale, y[i], acc, rhs)
    used = 0
    for i in range(lo, hi):
        if _in_train(i, rows, n_train, time_col, width_col):
            continue
        _accumulate((i - centre) / scale, y[i] - _relaxation_at(relax, i - t_inc), acc, rhs)
        used += 1
    if used < MIN_GAP:
        return out
    a = np.empty((DEGREE + 1, DEGREE + 1))
    for r in range(DEGREE + 1):
        for c in range(DEGREE + 1):
            a[r, c] = acc[r + c]
    coef = np.empty(DEGREE + 1)
    if not solve_spd(a, rhs, coef):
        return out
    for k in range(DEGREE + 1):
        out[D_C0 + k] = coef[k]
    out[D_CENTRE] = centre
    out[D_SCALE] = scale
    out[D_GAP] = used
    # How far the fitted baseline misses its own quiet samples: the largest mean residual over
    # the pre-trigger and either half of the gap. A smooth drift leaves noise; a jump of the level
    # (a range switch, a cable knocked) leaves a mean of its own in each stretch.
    mid = (lo + hi) // 2
    for first, stop, in_gap in ((0, n_pre, False), (lo, mid, True), (mid, hi, True)):
        total = 0.0
        count = 0
        for i in range(first, stop):
            if _in_train(i, rows, n_train, time_col, width_col):
                continue
            u = (i - centre) / scale
            r = y[i] - (coef[0] + u * (coef[1] + u * coef[2]))
            if in_gap:
                r -= _relaxation_at(relax, i - t_inc)
            total += r
            count += 1
        if count > 0 and abs(total / count) > out[D_MISFIT]:
            out[D_MISFIT] = abs(total / count)
            out[D_MISFIT_N] = count
    return out


@njit(cache=True)
def drift_at(drift: np.ndarray, t: float) -> float:
    """The fitted baseline at sample ``t`` (fractional)."""
    u = (t - drift[D_CENTRE]) / drift[D_SCALE]
    return drift[D_C0] + u * (drift[D_C1] + u * drift[D_C2])
