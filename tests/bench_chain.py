"""Benchmark of the chain model (marker ``bench``): ``pytest -m bench -s tests/bench_chain.py``.

Prints: the paper's default scene (infinite plate, until the reflection has passed) per run after
compilation; the ratio against scipy's ``solve_ivp`` RK45 (the paper's ode45 approach) at matched
accuracy, i.e. both within 0.1 % of a converged reference on the incident and reflected sensor
peaks; and a batch of 1,000 scenes in scenes per second on 2 worker processes.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from solitonde.model.batch import scene_grid, simulate_many
from solitonde.model.scene import STANDARD_GRAVITY, Scene, scene_from_dict
from solitonde.model.simulate import simulate

pytestmark = pytest.mark.bench

TOLERANCE = 1e-3  # matched accuracy: peak sensor force within 0.1 %


def _peaks(result_time: np.ndarray, samples: np.ndarray, split: float) -> np.ndarray:
    """Largest sampled sensor force before and after ``split`` (incident, reflected)."""
    return np.array([samples[result_time < split].max(), samples[result_time >= split].max()])


def _rk45(scene: Scene, times: np.ndarray, rtol: float) -> np.ndarray:
    """The same chain (gravity, static start, Zener dashpot) with solve_ivp RK45, vectorised RHS."""
    n, m, a_s, a_p = scene.chain.n_particles, scene.sphere_mass, scene.a_s, scene.a_p
    g = STANDARD_GRAVITY
    z, f_static, s = scene.plate_impedance, n * m * g, scene.chain.sensor_index
    j = np.arange(n, dtype=float)
    deltas = (j * m * g / a_s) ** (2 / 3)
    u = np.empty(n + 1)
    u[n] = (f_static / a_p) ** (2 / 3)
    for k in range(n - 1, -1, -1):
        u[k] = u[k + 1] + deltas[k]
    v = np.zeros(n + 1)
    v[0] = scene.impact_velocity

    def rhs(_t: float, y: np.ndarray) -> np.ndarray:
        pos, vel, w = y[: n + 1], y[n + 1: 2 * n + 2], y[-1]
        f = a_s * np.maximum(pos[:-1] - pos[1:], 0.0) ** 1.5
        fb = a_p * max(pos[-1] - w, 0.0) ** 1.5
        above = np.concatenate(([0.0], f))
        below = np.concatenate((f, [fb]))
        return np.concatenate((vel, g + (above - below) / m, [(fb - f_static) / z]))

    sol = solve_ivp(rhs, (0.0, times[-1]), np.concatenate((u, v, [0.0])), method="RK45",
                    t_eval=times, rtol=rtol, atol=1e-14)
    pos, w = sol.y[: n + 1], sol.y[-1]
    f = a_s * np.maximum(pos[:-1] - pos[1:], 0.0) ** 1.5
    fb = a_p * np.maximum(pos[-1] - w, 0.0) ** 1.5
    below = f[s] if s < n else fb
    return 0.5 * (f[s - 1] + below)


def test_bench_default_scene_and_rk45():
    """Default scene per run, and the speed-up over RK45 at matched (0.1 %) peak accuracy."""
    scene = scene_from_dict({"effects": {"plate_model": "infinite"}})
    simulate(scene)  # compile / load the cache
    walls, integ = [], []
    for _ in range(30):
        t0 = time.perf_counter()
        r = simulate(scene)
        walls.append(time.perf_counter() - t0)
        integ.append(r.diagnostics["integration_wall_s"])
    ours = float(np.median(walls))
    print(f"\ndefault scene (D 9.53 mm, t 3.18 mm, infinite, to the reflection): "
          f"{ours * 1e3:.2f} ms per run (integration {np.median(integ) * 1e3:.2f} ms), "
          f"{r.diagnostics['steps']} steps of {r.diagnostics['dt_s']:.3g} s, "
          f"energy drift {r.diagnostics['energy_drift']:.2e}")

    split = r.truth["bottom_peak_time_s"]
    reference = _peaks(r.time, simulate(scene, steps_per_period=12800).samples, split)
    ours_err = np.abs(_peaks(r.time, r.samples, split) / reference - 1).max()
    assert ours_err < TOLERANCE
    coarsest = None
    for spp in (25, 50, 100, 200, 400):
        rc = simulate(scene, steps_per_period=spp)
        if np.abs(_peaks(rc.time, rc.samples, split) / reference - 1).max() < TOLERANCE:
            coarsest = spp
            t0 = time.perf_counter()
            for _ in range(10):
                simulate(scene, steps_per_period=spp)
            coarse_wall = (time.perf_counter() - t0) / 10
            break

    for rtol in (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8):
        t0 = time.perf_counter()
        trace = _rk45(scene, r.time, rtol)
        rk_wall = time.perf_counter() - t0
        rk_err = np.abs(_peaks(r.time, trace, split) / reference - 1).max()
        if rk_err < TOLERANCE:
            break
    print(f"RK45 (solve_ivp, rtol {rtol:g}, peak error {rk_err:.1e}): {rk_wall * 1e3:.1f} ms; "
          f"default Verlet (peak error {ours_err:.1e}): {ours * 1e3:.2f} ms -> "
          f"speed-up {rk_wall / ours:.0f}x")
    if coarsest is not None:
        print(f"Verlet at the coarsest step that still meets 0.1 % ({coarsest} steps/period): "
              f"{coarse_wall * 1e3:.2f} ms -> speed-up {rk_wall / coarse_wall:.0f}x")


def test_bench_batch_1000_scenes():
    """1,000 scenes (D 4.76-9.53 mm x t 2.29-4.83 mm, infinite plate) on 2 worker processes."""
    scenes = scene_grid({"effects": {"plate_model": "infinite"}}, {
        "chain.diameter": list(np.linspace(4.76e-3, 9.53e-3, 25)),
        "plate.thickness": list(np.linspace(2.29e-3, 4.83e-3, 40)),
    })
    assert len(scenes) == 1000
    simulate(scenes[0])
    t0 = time.perf_counter()
    simulate_many(scenes[::10], workers=1)
    serial = 100 / (time.perf_counter() - t0)
    t0 = time.perf_counter()
    results = simulate_many(scenes, workers=2)
    rate = len(results) / (time.perf_counter() - t0)
    drift = max(r.diagnostics["energy_drift"] for r in results)
    print(f"\nbatch of 1000 scenes on 2 workers: {rate:.0f} scenes/s "
          f"(1 process, 100 of them: {serial:.0f} scenes/s; ratio {rate / serial:.2f}); "
          f"worst energy drift {drift:.1e}")
