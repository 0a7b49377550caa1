"""The independent solve of ``tests/support/independent_chain.py`` as a finely sampled trace with
its true peaks, for the signal tests: SciPy's DOP853 on the chain's equations written out there
(Hertz contacts from the materials by hand, gravity on or off, Zener's dashpot under the last
sphere), not this project's integrators.

The trace starts ``pre_s`` before the impact with the static reading, as a triggered scope's
pre-trigger; the incident's and the reflection's peaks are refined by a parabola through the three
samples about each maximum (20 MHz: well below a nanosecond and 1e-5 of the peak).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from independent_chain import sensor_trace

from solitonde.signal.accuracy import Truth

AL_6061 = {"youngs_modulus": 68.9e9, "poisson_ratio": 0.33, "density": 2700.0}


@dataclass(frozen=True)
class ChainTrace:
    """A sensor trace sampled at ``dt`` from ``t0`` (the impact at t = 0) and its ``truth``: the
    incident's and the reflection's peaks (the largest maximum once the sensor has fallen below
    a tenth of the incident's height after it), heights above the static reading."""

    t0: float
    dt: float
    samples: np.ndarray
    truth: Truth


def solve(diameter: float, thickness: float, gravity: bool, t_end: float, rate: float = 20e6,
          pre_s: float = 1e-4) -> ChainTrace:
    """The paper's chain (20 440C spheres, sensor 7th) of ``diameter`` spheres on an Al 6061
    plate of ``thickness`` (Zener's infinite plate) up to ``t_end`` after the impact, at ``rate``:
    ``t_end`` must end the record before the reflection comes back down."""
    t, x = sensor_trace(AL_6061, thickness, diameter, duration_s=t_end, sample_rate=rate,
                        gravity=gravity)
    dt = t[1] - t[0]
    static = float(x[0])
    n_pre = round(pre_s / dt)
    inc_t, inc_f = _peak(t, x, 0)
    k = int(np.argmax(x))
    while k < x.size and x[k] - static > 0.1 * (inc_f - static):
        k += 1
    ref_t, ref_f = _peak(t, x, k)
    return ChainTrace(-n_pre * dt, dt, np.concatenate([np.full(n_pre, static), x]),
                      Truth(inc_t, ref_t, inc_f - static, ref_f - static))


def _peak(t: np.ndarray, x: np.ndarray, lo: int) -> tuple[float, float]:
    """The largest sample of ``x[lo:]`` refined by the parabola through it and its neighbours."""
    k = lo + int(np.argmax(x[lo:]))
    a, b, c = x[k - 1], x[k], x[k + 1]
    shift = 0.5 * (a - c) / (a - 2.0 * b + c)
    return float(t[k] + shift * (t[1] - t[0])), float(b - 0.25 * (a - c) * shift)
