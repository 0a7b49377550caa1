"""Checks of a solitary wave in a long chain that both integrators' tests run (Verlet in
test_chain_physics, dopri5 in test_chain_dopri): Chatterjee's peak velocity, Nesterenko's speed
and width. ``long_chain`` is a run with per-particle traces of a 100-particle chain."""

from __future__ import annotations

import numpy as np
import pytest

from solitonde.model.simulate import SimulationResult
from solitonde.model.zener import CHATTERJEE_RATIO, solitary_wave_speed


def _peak_time(t: np.ndarray, y: np.ndarray) -> float:
    k = int(np.argmax(y))
    a, b, c = y[k - 1], y[k], y[k + 1]
    return float(t[k] + 0.5 * (a - c) / (a - 2.0 * b + c) * (t[1] - t[0]))


def check_chatterjee(long_chain: SimulationResult) -> None:
    """An identical striker forms a wave with peak particle velocity 0.682 v_imp (Chatterjee)."""
    v = long_chain.traces["v_m_s"][:, 20:70].max(axis=0) / long_chain.scene.impact_velocity
    assert np.ptp(v) < 1e-4  # a steady wave: the same peak on every particle
    assert v.mean() == pytest.approx(CHATTERJEE_RATIO, rel=5e-3)


def check_nesterenko(long_chain: SimulationResult) -> None:
    """Wave speed within 2 % of Nesterenko's V_s(v_m); width about five diameters."""
    r, scene = long_chain, long_chain.scene
    d = scene.chain.diameter
    t = r.time
    v = r.traces["v_m_s"]
    particles = np.arange(20, 70)
    arrival = np.array([_peak_time(t, v[:, i]) for i in particles])
    speed = np.polyfit(arrival, particles * d, 1)[0]
    v_m = v[:, particles].max(axis=0).mean()
    nesterenko = solitary_wave_speed(d, scene.a_s, scene.sphere_mass, v_m)
    assert speed == pytest.approx(nesterenko, rel=0.02)
    # Width: second moment of the overlap pulse at one contact, mapped to space with the speed,
    # divided by that of the long-wave cos^4 profile of unit support.
    u = r.traces["u_m"]
    y = np.linspace(-0.5, 0.5, 100_001)
    shape = np.cos(np.pi * y) ** 4
    unit_sigma = np.sqrt((y**2 * shape).sum() / shape.sum())
    for j in (30, 45, 60):
        overlap = np.clip(u[:, j] - u[:, j + 1], 0.0, None)
        weight = overlap / overlap.sum()
        mean = (weight * t).sum()
        sigma = np.sqrt((weight * (t - mean) ** 2).sum()) * speed
        width = sigma / unit_sigma / d
        # Long-wave support 5 pi / sqrt(10) = 4.97 D; the discrete wave is within 5 % of it.
        assert width == pytest.approx(5 * np.pi / np.sqrt(10), rel=0.05)
