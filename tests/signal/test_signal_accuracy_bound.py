"""The Cramer-Rao bound of signal/accuracy.py against an independent Fisher matrix and against an
estimator that attains it.

Traces: two Nesterenko cos^6 pulses (synth.pulse_train) on a constant baseline, sampled at 30 MHz
and acquired at 2 MHz, white noise at 20 dB re the incident. The model the bound states: each pulse
is b + A s((t - tau) / w) with b, A, tau, w unknown, over the union of its level window
(kernels.FOOT to FOOT + LEVEL_SPAN FWHM before the peak, not before the previous pulse's foot) and
its pulse window (2.5 FWHM each side of the peak), each sample once. A bound on the variance of
every unbiased estimator cannot exceed the variance of one: least squares of exactly that model,
started at the truth (the oracle maximum-likelihood estimator for white Gaussian noise).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from solitonde.signal import kernels as K
from solitonde.signal.accuracy import Truth, cramer_rao
from solitonde.signal.synth import pulse_train

FINE_DT = 1.0 / 30e6
RATE = 2e6
STEP = 15
SUPPORT = 125e-6  # cos^6 support: FWHM 0.30 of it, 37.5 us, the reference chain's incident
FWHM = 2.0 * np.arccos(0.5 ** (1.0 / 6.0)) / np.pi * SUPPORT
BASE, A_INC, A_REF = 0.2, 30.0, 16.5
SIGMA = A_INC / 10.0  # 20 dB


def pulses(t_inc: float) -> list[tuple[float, float, float]]:
    return [(t_inc, A_INC, SUPPORT), (t_inc + 20 * FWHM, A_REF, SUPPORT)]


def trace(t_inc: float) -> tuple[np.ndarray, Truth]:
    n = round((t_inc + 24 * FWHM) / FINE_DT)
    x = pulse_train(n, FINE_DT, pulses(t_inc), baseline=BASE)
    p = pulses(t_inc)
    return x, Truth(p[0][0], p[1][0], p[0][1], p[1][1])


def windows(t_inc: float, n: int) -> list[np.ndarray]:
    """Fine-sample indices of each pulse's level window joined with its pulse window."""
    out, prev_foot, prev_hi = [], 0, 0
    fw = FWHM / FINE_DT
    for tp, _a, _s in pulses(t_inc):
        i = round(tp / FINE_DT)
        stop = int(i - K.FOOT * fw)
        start = max(prev_foot, int(stop - K.LEVEL_SPAN * fw))
        lo, hi = max(0, int(i - 2.5 * fw)), min(n, int(i + 2.5 * fw) + 1)
        idx = np.union1d(np.arange(max(start, 0), max(stop, 0)), np.arange(lo, hi))
        out.append(idx[idx >= prev_hi])
        prev_foot, prev_hi = min(n, int(i + K.FOOT * fw) + 1), hi
    return out


def model(p: np.ndarray, t: np.ndarray) -> np.ndarray:
    b, amp, tau, lnw = p
    u = np.clip(np.pi * (t - tau) / (SUPPORT * np.exp(lnw)), -np.pi / 2, np.pi / 2)
    return b + amp * np.cos(u) ** 6


def fd_jacobian(p: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Central differences of the explicit model in (b, ln A, t in sample periods, ln w)."""
    steps = np.array([1e-4, 1e-6, 1e-4 / RATE, 1e-6])
    cols = []
    for k, h in enumerate(steps):
        dp = np.zeros(4)
        dp[k] = h
        if k == 1:  # d/d ln A = A d/dA
            dp[k] = h * p[1]
        col = (model(p + dp, t) - model(p - dp, t)) / (2 * h)
        cols.append(col)
    return np.stack(cols, axis=1)


def independent_arr_rel(t_inc: float) -> float:
    x, _ = trace(t_inc)
    t = np.arange(x.size) * FINE_DT
    var = 0.0
    for offset in range(STEP):
        for idx, (tp, amp, _s) in zip(windows(t_inc, x.size), pulses(t_inc), strict=True):
            ti = t[idx[(idx - offset) % STEP == 0]]
            g = fd_jacobian(np.array([BASE, amp, tp, 0.0]), ti) / SIGMA
            g[:, 2] /= RATE  # d/d(time in sample periods)
            var += np.linalg.inv(g.T @ g)[1, 1]
    return float(np.sqrt(var / STEP))


@pytest.mark.parametrize("t_inc", [14 * FWHM, 1.6 * FWHM], ids=["long-pretrigger", "short"])
def test_bound_matches_independent_fisher(t_inc):
    """The ARR bound is the Fisher information of the stated model, computed here from finite
    differences of the explicit cos^6 pulse: within 0.1 % (the bound's gradient of the 30 MHz trace
    and the differences agree to a few parts per million). The long pre-trigger is the reference
    trace's layout (a baseline from the level window alone, added to a fit that holds it known,
    is 1.1 % high there); the short one leaves the incident 0.1 FWHM of level window, so its
    baseline is known mostly from the pulse window's own flat tail (49 % high)."""
    x, truth = trace(t_inc)
    bound = cramer_rao(x, FINE_DT, truth, RATE, SIGMA)["arr_rel"]
    assert bound == pytest.approx(independent_arr_rel(t_inc), rel=1e-3)


def test_bound_not_beaten_by_oracle_ml():
    """The bound does not exceed the spread of the oracle ML estimator of the model it states
    (300 shots, random sub-sample offsets; the sample standard deviation is within 3 standard
    errors, 12 %, of the truth), and that estimator is efficient: its spread within 15 % above
    the bound. Short pre-trigger, where a baseline taken from the level window alone would put the
    bound 50 % above what the estimator achieves."""
    t_inc = 1.6 * FWHM
    x, truth = trace(t_inc)
    bound = cramer_rao(x, FINE_DT, truth, RATE, SIGMA)["arr_rel"]
    t = np.arange(x.size) * FINE_DT
    wins = windows(t_inc, x.size)
    rng = np.random.default_rng(7)
    errors = []
    for _ in range(300):
        offset = int(rng.integers(STEP))
        amps = []
        for idx, (tp, amp, _s) in zip(wins, pulses(t_inc), strict=True):
            sel = idx[(idx - offset) % STEP == 0]
            y = x[sel] + rng.normal(0.0, SIGMA, sel.size)
            p0 = np.array([BASE, amp, tp, 0.0])
            fit = least_squares(lambda p, ts=t[sel], ys=y: model(p, ts) - ys, p0,
                                x_scale=[1.0, 1.0, 1e-6, 0.1], method="lm")
            amps.append(fit.x[1])
        errors.append(amps[1] / amps[0] / truth.arr - 1.0)
    spread = float(np.std(errors))
    assert bound <= spread * (1.0 + 3.0 / np.sqrt(2 * 300))
    assert spread <= 1.15 * bound
