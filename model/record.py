"""The run record: what every compiled chain driver reads and fills, as one argument.

A ``typing.NamedTuple`` of arrays and numbers, which numba passes to compiled code as a plain
struct (and caches, unlike a jitclass). Drivers take it plus their own time grid, instead of the
22 positional arguments each used to repeat.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class ChainRecord(NamedTuple):
    """The chain's state, constants and output arrays for one run (arrays modified in place).

    u, v: displacements (down, m) and velocities (m/s) of particles 0..N (0 = striker);
    u0: the displacements at the start (reference of the gravity energy).
    m: particle mass, kg. g: gravity, m/s^2. a_s, a_b: sphere-sphere and bottom Hertz constants,
    N/m^1.5. f_static: static force on the bottom contact at the start, N. tau: Kuwabara-Kono
    time, s (0: elastic). sensor: sensor particle, 1..N.
    samples, energy: per-sample sensor force (N) and energy balance (J); u_trace, v_trace,
    f_trace, w_trace: per-sample fields (zero rows: traces off); pk: the peak tracker
    (:func:`solitonde.model.chain.new_peak_tracker`).
    m0, a_0: the striker's mass (kg) and the Hertz constant of its contact with particle 1
    (N/m^1.5); ``m`` and ``a_s`` when the striker is one of the chain's spheres.
    """

    u: np.ndarray
    v: np.ndarray
    u0: np.ndarray
    m: float
    g: float
    a_s: float
    a_b: float
    f_static: float
    tau: float
    sensor: int
    samples: np.ndarray
    energy: np.ndarray
    u_trace: np.ndarray
    v_trace: np.ndarray
    f_trace: np.ndarray
    w_trace: np.ndarray
    pk: np.ndarray
    m0: float
    a_0: float


def chain_record(
    u: np.ndarray, v: np.ndarray, u0: np.ndarray, m: float, g: float, a_s: float, a_b: float,
    f_static: float, tau: float, sensor: int, samples: np.ndarray, energy: np.ndarray,
    u_trace: np.ndarray, v_trace: np.ndarray, f_trace: np.ndarray, w_trace: np.ndarray,
    pk: np.ndarray, m0: float | None = None, a_0: float | None = None,
) -> ChainRecord:
    """A record with the numbers coerced to float/int, so that one compiled version serves all;
    the striker defaults to one of the chain's spheres."""
    return ChainRecord(u, v, u0, float(m), float(g), float(a_s), float(a_b), float(f_static),
                       float(tau), int(sensor), samples, energy, u_trace, v_trace, f_trace,
                       w_trace, pk, float(m if m0 is None else m0),
                       float(a_s if a_0 is None else a_0))
