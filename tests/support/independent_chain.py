"""An independent solve of the measurement, written for the tests: scipy's DOP853 on the Hertzian
chain (striker, N spheres) standing under gravity on Zener's dashpot (an infinite thin plate of
point impedance Z = 8 sqrt(rho t D_p), the paper's Sec. 4.1), and the sensor traces a scope would
record of it (a static pre-trigger, white noise at a given SNR). Nothing here calls the model
package: the contact constants are Hertz's, computed from the materials by hand. Only
:func:`features_of` reads a trace with the signal package, as a measurement is read."""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

G = 9.80665
SPHERE_440C = {"youngs_modulus": 200e9, "poisson_ratio": 0.28, "density": 7800.0}


def _plane(m: Mapping[str, float]) -> float:
    return m["youngs_modulus"] / (1.0 - m["poisson_ratio"] ** 2)


def sensor_trace(plate: Mapping[str, float], thickness_m: float, diameter_m: float = 9.53e-3,
                 *, sphere: Mapping[str, float] = SPHERE_440C, n_particles: int = 20,
                 sensor_index: int = 7, drop_height_m: float = 5e-3, duration_s: float = 8e-4,
                 sample_rate: float = 2e6, gravity: bool = True, tau_s: float = 0.0
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Sensor force (N) sampled from the impact on: the mean of the contact forces above and
    below sphere ``sensor_index`` (1 = the top sphere) of a chain at static equilibrium under
    gravity (or without it: the spheres just touching), struck by a sphere like its own dropped
    from ``drop_height_m``. With ``tau_s`` > 0 the sphere-sphere contacts are Kuwabara and
    Kono's viscoelastic ones, ``F = [A d^1.5 + 1.5 A tau d^0.5 d']_+`` (the contact with the plate
    stays elastic)."""
    g = G if gravity else 0.0
    r = 0.5 * diameter_m
    m = sphere["density"] * math.pi * diameter_m**3 / 6.0
    a_s = 4.0 / 3.0 * (_plane(sphere) / 2.0) * math.sqrt(r / 2.0)
    e_star = 1.0 / (1.0 / _plane(sphere) + 1.0 / _plane(plate))
    a_p = 4.0 / 3.0 * e_star * math.sqrt(r)
    bending = _plane(plate) * thickness_m**3 / 12.0
    z = 8.0 * math.sqrt(plate["density"] * thickness_m * bending)
    n = n_particles
    f_static = n * m * g
    u = np.empty(n + 1)  # u[0] the striker, u[1..n] the chain; positive downwards
    u[n] = (f_static / a_p) ** (2.0 / 3.0)
    for k in range(n - 1, -1, -1):  # contact k (between u[k] and u[k+1]) carries k m g
        u[k] = u[k + 1] + (k * m * g / a_s) ** (2.0 / 3.0)
    v = np.zeros(n + 1)
    v[0] = math.sqrt(2.0 * G * drop_height_m)

    def contacts(pos: np.ndarray, w: np.ndarray | float, vel: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
        overlap = np.clip(pos[:-1] - pos[1:], 0.0, None)
        f = a_s * overlap**1.5
        if tau_s > 0.0 and vel is not None:
            f = np.clip(f + 1.5 * a_s * tau_s * np.sqrt(overlap) * (vel[:-1] - vel[1:]), 0.0,
                        None)
        return f, a_p * np.clip(pos[-1] - w, 0.0, None) ** 1.5

    def rhs(_t: float, y: np.ndarray) -> np.ndarray:
        pos, vel, w = y[: n + 1], y[n + 1: 2 * n + 2], y[-1]
        f, fb = contacts(pos, w, vel)
        acc = np.full(n + 1, g)
        acc[1:] += f / m
        acc[:-1] -= f / m
        acc[-1] -= fb / m
        return np.concatenate([vel, acc, [(fb - f_static) / z]])

    sol = solve_ivp(rhs, (0.0, duration_s), np.concatenate([u, v, [0.0]]), method="DOP853",
                    rtol=1e-10, atol=1e-15, dense_output=True, max_step=2e-7)
    t = np.arange(0.0, duration_s, 1.0 / sample_rate)
    y = sol.sol(t)
    f, _ = contacts(y[: n + 1], y[-1], y[n + 1: 2 * n + 2])
    return t, 0.5 * (f[sensor_index - 1] + f[sensor_index])


def features_of(plate: Mapping[str, float], thickness_m: float, tau_s: float = 0.0
                ) -> tuple[float, float]:
    """(TOF s, ARR) of the noise-free trace (:func:`sensor_trace`, 0.8 ms) as the signal
    package's extractor reads it, with 400 samples of static pre-trigger."""
    from solitonde.signal.features import extract
    from solitonde.signal.waveform import Waveform

    t, force = sensor_trace(plate, thickness_m, duration_s=8.0e-4, tau_s=tau_s)
    dt = t[1] - t[0]
    pre = np.full(400, force[0])
    f = extract(Waveform(t[0] - dt * pre.size, dt, np.concatenate([pre, force])))
    assert f.tof_s is not None and f.arr is not None
    return f.tof_s, f.arr


@functools.lru_cache(maxsize=16)
def _trace_of(plate: tuple[tuple[str, float], ...], thickness_m: float, duration_s: float
              ) -> tuple[np.ndarray, np.ndarray]:
    return sensor_trace(dict(plate), thickness_m, duration_s=duration_s)


def recorded_for(plate: Mapping[str, float], thickness_m: float, duration_s: float,
                 solved_s: float = 1.0e-3) -> tuple[np.ndarray, np.ndarray]:
    """The paper's chain's trace (:func:`sensor_trace`'s defaults) as a scope recording
    ``duration_s`` from the impact holds it: one solve to ``solved_s`` per plate and thickness,
    kept for the session and cut (the solve's steps up to a time do not depend on where it
    ends), so that tests of the record's length share it."""
    if duration_s > solved_s:
        raise ValueError(f"duration_s {duration_s} beyond the solve's {solved_s}")
    t, force = _trace_of(tuple(sorted(plate.items())), thickness_m, solved_s)
    keep = t < duration_s - 1e-12
    return t[keep].copy(), force[keep].copy()


def write_shots(path: Path, t: np.ndarray, force: np.ndarray, shots: int, snr_db: float,
                seed: int, metadata: Mapping[str, object] | None = None) -> Path:
    """``shots`` noisy records of one trace as a scope CSV (time column, one force column per
    shot, ``# key: value`` header lines): a quarter of the record as static pre-trigger, white
    noise of sigma = (incident peak above the static reading) / 10^(snr/20)."""
    rng = np.random.default_rng(seed)
    dt = t[1] - t[0]
    n_pre = max(64, force.size // 4)
    clean = np.concatenate([np.full(n_pre, force[0]), force])
    time = np.concatenate([t[0] - dt * np.arange(n_pre, 0, -1), t])
    sigma = (force.max() - force[0]) / 10.0 ** (snr_db / 20.0)
    columns = [time] + [clean + rng.normal(0.0, sigma, clean.size) for _ in range(shots)]
    header = "".join(f"# {k}: {v}\n" for k, v in (metadata or {}).items())
    header += "time_s," + ",".join(["force_N"] * shots) + "\n"
    body = "\n".join(",".join(f"{x:.9g}" for x in row) for row in np.column_stack(columns))
    path.write_text(header + body + "\n")
    return path
