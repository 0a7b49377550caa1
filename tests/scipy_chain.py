"""An independent solve of the chain for the signal tests: SciPy's DOP853 on the equations of
motion written out here (Hertz contacts, gravity, a striker of any mass, Zener's dashpot under the
last sphere), not this project's integrators. Only the scene's constants are shared.

Displacements point down. With gravity the chain starts in static equilibrium: the contact below
the k-th sphere carries k m g and the plate the whole chain's weight, which Zener's infinite plate
carries statically (the dashpot moves at ``(F - F_static) / Z``). The sensor reads the mean of its
two contact forces; the trace starts ``pre_s`` before the impact with the static reading.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from solitonde.model.scene import Scene

G = 9.80665


@dataclass(frozen=True)
class ChainTrace:
    """A sensor trace sampled at ``dt`` from ``t0`` (the impact at t = 0) and the true peaks of
    the incident and the first pulse after it that travels back up (the reflection), found on
    the dense solution by a bounded search, above the static reading ``static_N``."""

    t0: float
    dt: float
    samples: np.ndarray
    static_N: float
    incident_time_s: float
    incident_peak_N: float
    reflected_time_s: float
    reflected_peak_N: float

    @property
    def tof_s(self) -> float:
        return self.reflected_time_s - self.incident_time_s

    @property
    def arr(self) -> float:
        return (self.reflected_peak_N - self.static_N) / (self.incident_peak_N - self.static_N)


def plate_impedance(scene: Scene) -> float:
    """Zener's point impedance of an infinite thin plate, ``8 sqrt(rho t D)``."""
    mat, t = scene.plate_material, scene.plate.thickness
    bending = mat.youngs_modulus * t**3 / (12.0 * (1.0 - mat.poisson_ratio**2))
    return 8.0 * np.sqrt(mat.density * t * bending)


def solve(scene: Scene, t_end: float, rate: float = 20e6, pre_s: float = 1e-4,
          rtol: float = 1e-10) -> ChainTrace:
    """The sensor trace of ``scene`` on Zener's plate up to ``t_end`` after the impact, sampled
    at ``rate``; the reflection is the largest maximum after the incident has passed and a pulse
    travelling down (the sensor sees each pulse once each way): ``t_end`` must end the record
    before the reflection comes back down."""
    n = scene.chain.n_particles
    sensor = scene.chain.sensor_index
    m = np.full(n + 1, scene.sphere_mass)
    m[0] = scene.striker_mass
    a = np.full(n, scene.a_s)
    a[0] = scene.a_0
    a_p = scene.a_p
    g = G if scene.effects.gravity else 0.0
    mg = scene.sphere_mass * g
    f_static = n * mg
    inv_z = 1.0 / plate_impedance(scene)

    # Static equilibrium: overlaps from the plate up; the striker just touches sphere 1.
    u = np.zeros(n + 1)
    u[n] = (f_static / a_p) ** (2.0 / 3.0)
    for k in range(n - 1, 0, -1):
        u[k] = u[k + 1] + (k * mg / a[k]) ** (2.0 / 3.0)
    u[0] = u[1]

    def contacts(pos: np.ndarray, w: float) -> tuple[np.ndarray, float]:
        return a * np.clip(pos[:-1] - pos[1:], 0.0, None) ** 1.5, \
            a_p * max(pos[-1] - w, 0.0) ** 1.5

    def rhs(_t: float, y: np.ndarray) -> np.ndarray:
        pos, vel, w = y[: n + 1], y[n + 1: 2 * n + 2], y[-1]
        f, fp = contacts(pos, w)
        acc = np.full(n + 1, g)
        acc[0] -= f[0] / m[0]
        acc[1:-1] += (f[:-1] - f[1:]) / m[1:-1]
        acc[-1] += (f[-1] - fp) / m[-1]
        return np.concatenate([vel, acc, [(fp - f_static) * inv_z]])

    y0 = np.concatenate([u, np.zeros(n + 1), [0.0]])
    y0[n + 1] = scene.impact_velocity
    sol = solve_ivp(rhs, (0.0, t_end), y0, method="DOP853", rtol=rtol, atol=1e-15,
                    dense_output=True)
    assert sol.success, sol.message

    def reading(t: np.ndarray) -> np.ndarray:
        ys = sol.sol(t)
        out = np.empty(t.size)
        for i in range(t.size):
            f, _ = contacts(ys[: n + 1, i], ys[-1, i])
            out[i] = 0.5 * (f[sensor - 1] + f[sensor])
        return out

    dt = 1.0 / rate
    t_after = np.arange(0.0, t_end, dt)
    x_after = reading(t_after)
    static = float(x_after[0])
    n_pre = round(pre_s / dt)
    samples = np.concatenate([np.full(n_pre, static), x_after])
    inc_t, inc_f = _refined_max(reading, t_after, x_after, 0, t_after.size)
    # The reflection: the largest maximum once the sensor has fallen back below a tenth of the
    # incident's height after it.
    k = int(np.argmax(x_after))
    while k < x_after.size and x_after[k] - static > 0.1 * (inc_f - static):
        k += 1
    ref_t, ref_f = _refined_max(reading, t_after, x_after, k, t_after.size)
    return ChainTrace(-n_pre * dt, dt, samples, static, inc_t, inc_f, ref_t, ref_f)


def _refined_max(reading, t: np.ndarray, x: np.ndarray, lo: int, hi: int) -> tuple[float, float]:
    """The maximum of ``x[lo:hi]`` refined on the dense solution by golden-section search."""
    k = lo + int(np.argmax(x[lo:hi]))
    a, b = t[max(k - 1, 0)], t[min(k + 1, t.size - 1)]
    phi = 0.5 * (np.sqrt(5.0) - 1.0)
    for _ in range(60):
        c, d = b - phi * (b - a), a + phi * (b - a)
        fc, fd = reading(np.array([c, d]))
        if fc > fd:
            b = d
        else:
            a = c
    tm = 0.5 * (a + b)
    return float(tm), float(reading(np.array([tm]))[0])
