"""Throughput of feature extraction on one core for 10,000-sample shots (run: -m bench -s).

Baseline measured in the same run: a plain scipy pipeline (median baseline, zero-phase
Butterworth, scipy.signal.find_peaks, parabolic peak refinement) that gives TOF and ARR but none
of the drift handling, shape fit or flags.
"""

from __future__ import annotations

import os
import time

import numpy as np
import pytest
from scipy.signal import butter, find_peaks, sosfiltfilt

from solitonde.signal.features import extract_many
from solitonde.signal.synth import degrade, pulse_train
from solitonde.signal.waveform import Waveform

N = 10_000
DT = 1e-7  # 10 MHz: 1 ms per shot
SHOTS = 400


def _shots() -> list[Waveform]:
    rng = np.random.default_rng(0)
    out = []
    for _ in range(SHOTS):
        tof = rng.uniform(400e-6, 600e-6)
        x = pulse_train(N, DT, [(150e-6, 30.0, 90e-6), (150e-6 + tof, 15.0, 95e-6)])
        out.append(Waveform(0.0, DT, degrade(x, 30.0, rng, 30.0, drift=0.02, bits=12)))
    return out


def scipy_pipeline(w: Waveform, sos: np.ndarray) -> tuple[float, float]:
    x = w.samples
    base = np.median(x[: N // 10])
    y = sosfiltfilt(sos, x - base)
    peaks, _ = find_peaks(y, height=0.1 * y.max(), distance=int(100e-6 / DT))
    t, a = [], []
    for p in peaks[:2]:
        y0, y1, y2 = y[p - 1 : p + 2]
        d = 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2)
        t.append(p + d)
        a.append(y1 - 0.25 * (y0 - y2) * d)
    return (t[1] - t[0]) * DT, a[1] / a[0]


def _rate(fn, shots) -> float:
    best = 0.0
    for _ in range(3):
        start = time.perf_counter()
        fn(shots)
        best = max(best, len(shots) / (time.perf_counter() - start))
    return best


@pytest.mark.bench
def test_throughput():
    """Waveforms per second (best of 3) for solitonde and the scipy find_peaks baseline."""
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    shots = _shots()
    sos = butter(4, 100e3, fs=1 / DT, output="sos")
    extract_many(shots[:5])  # compile / load numba caches outside the timing
    ours = _rate(extract_many, shots)
    base = _rate(lambda ws: [scipy_pipeline(w, sos) for w in ws], shots)
    feats = extract_many(shots[:50])
    assert all(f.tof_s is not None for f in feats)
    print(f"\nsolitonde extract: {ours:,.0f} waveforms/s (10,000 samples, one core; target 5,000)")
    print(f"scipy find_peaks pipeline: {base:,.0f} waveforms/s")
    print(f"ratio solitonde / scipy: {ours / base:.2f}")
