"""Physics of the discrete element chain against analytic limits, scaling laws and conservation."""

from __future__ import annotations

import numpy as np
import pytest
from chain_checks import check_chatterjee, check_nesterenko

from solitonde.model.chain import new_peak_tracker
from solitonde.model.record import chain_record
from solitonde.model.scene import STANDARD_GRAVITY, scene_from_dict
from solitonde.model.simulate import simulate
from solitonde.model.tiers import make_boundary
from solitonde.model.tiers.dashpot import dashpot_run


@pytest.fixture(scope="module")
def long_chain():
    """A 100-particle chain on a wall, no gravity, traces at 20 MHz until the wave is past 70."""
    scene = scene_from_dict({
        "chain": {"n_particles": 100, "sensor_index": 50},
        "effects": {"plate_model": "rigid", "gravity": False},
        "output": {"duration": 1.7e-3, "traces": True, "sample_rate": 2e7},
    })
    return simulate(scene)


def test_chatterjee_peak_velocity(long_chain):
    """An identical striker forms a wave with peak particle velocity 0.682 v_imp (Chatterjee)."""
    check_chatterjee(long_chain)


def test_nesterenko_speed_and_width(long_chain):
    """Wave speed within 2 % of Nesterenko's V_s(v_m); width about five diameters."""
    check_nesterenko(long_chain)


@pytest.mark.parametrize("plate_model", ["rigid", "halfspace", "infinite"])
@pytest.mark.parametrize("gravity", [False, True])
def test_energy_balance_default_scene(plate_model, gravity):
    """Energy (kinetic + contact + gravity + plate work) drifts below 1e-6 without dissipation."""
    scene = scene_from_dict({"effects": {"plate_model": plate_model, "gravity": gravity}})
    r = simulate(scene)
    d = r.diagnostics
    assert d["energy_drift"] < 1e-6
    if plate_model == "infinite":
        # Most of the striker's energy leaves into the plate (ARR well below 1 at D/t = 3).
        assert d["plate_work_J"] > 0.5 * d["energy_scale_J"]
    else:
        assert d["plate_work_J"] == 0.0
    assert d["dissipated_J"] == 0.0


def test_second_order_convergence():
    """Velocity Verlet: the energy error falls as dt^2 (fitted order within 1.7..2.3)."""
    scene = scene_from_dict({"effects": {"plate_model": "rigid"}, "output": {"duration": 6e-4}})
    dts, drifts = [], []
    for spp in (200, 400, 800, 1600):
        r = simulate(scene, steps_per_period=spp)
        dts.append(r.diagnostics["dt_s"])
        drifts.append(r.diagnostics["energy_drift"])
    order = np.polyfit(np.log(dts), np.log(drifts), 1)[0]
    assert 1.7 < order < 2.3


def test_dashpot_law_and_sensor_definition():
    """Infinite plate: w' = (F - N m g) / Z at every sample; sensor = mean of its two contacts."""
    scene = scene_from_dict({
        "effects": {"plate_model": "infinite", "gravity": True},
        "output": {"traces": True, "sample_rate": 1e7},
    })
    r = simulate(scene)
    f = r.traces["contact_force_N"]
    w = r.traces["plate_deflection_m"]
    s = scene.chain.sensor_index
    np.testing.assert_allclose(r.samples, 0.5 * (f[:, s - 1] + f[:, s]), rtol=0, atol=1e-12)
    f_static = scene.chain.n_particles * scene.sphere_mass * STANDARD_GRAVITY
    w_dot = (w[2:] - w[:-2]) / (2 * r.dt)
    law = (f[1:-1, -1] - f_static) / scene.plate_impedance
    assert np.max(np.abs(w_dot - law)) < 1e-3 * np.max(np.abs(law))


@pytest.mark.parametrize("plate_model", ["rigid", "halfspace", "infinite"])
def test_static_equilibrium_is_exact(plate_model):
    """With gravity and everything at rest (striker resting on top) nothing moves for 2 ms."""
    scene = scene_from_dict({"effects": {"plate_model": plate_model, "gravity": True}})
    b = make_boundary(scene)
    n, m, g, a_s = scene.chain.n_particles, scene.sphere_mass, STANDARD_GRAVITY, scene.a_s
    # Column of N + 1 spheres: the contact below sphere j (0-based) carries (j + 1) m g.
    u = np.empty(n + 1)
    u[n] = ((n + 1) * m * g / b.a_bottom) ** (2 / 3)
    for j in range(n - 1, -1, -1):
        u[j] = u[j + 1] + ((j + 1) * m * g / a_s) ** (2 / 3)
    v = np.zeros(n + 1)
    samples, energy = np.empty(2001), np.empty(2001)
    empty = np.empty((0, n + 1))
    inv_z = 1.0 / b.impedance if plate_model == "infinite" else 0.0
    record = chain_record(u, v, u.copy(), m, g, a_s, b.a_bottom, (n + 1) * m * g, 0.0,
                          scene.chain.sensor_index, samples, energy, empty, empty, empty,
                          np.empty(0), new_peak_tracker())
    status, *_ = dashpot_run(record, 0.0, inv_z, 2e-8, 50, samples.size)
    assert status == 0
    static = (scene.chain.sensor_index + 0.5) * m * g
    assert np.max(np.abs(samples - static)) < 1e-9 * static


def test_gravity_static_load_before_arrival():
    """In a real shot the sensor reads (s - 1/2) m g, flat to 1e-6, until the wave front arrives.

    The front of a Hertzian wave in a chain precompressed by gravity decays only exponentially, so
    "arrival" is taken generously early: a quarter of the incident peak time.
    """
    scene = scene_from_dict({"effects": {"plate_model": "infinite", "gravity": True}})
    r = simulate(scene)
    static = r.truth["static_sensor_N"]
    assert static == pytest.approx(6.5 * scene.sphere_mass * STANDARD_GRAVITY, rel=1e-12)
    before = r.time < 0.25 * r.truth["incident_time_s"]
    assert before.sum() > 50
    assert np.max(np.abs(r.samples[before] - static)) < 1e-6 * static


def test_dissipation_lowers_arr_and_balances_energy():
    """Kuwabara-Kono damping: energy balance still closes, energy is dissipated, ARR drops."""
    base = {"effects": {"plate_model": "halfspace", "gravity": True}}
    elastic = simulate(scene_from_dict(base))
    damped_scene = scene_from_dict({
        "effects": {"plate_model": "halfspace", "gravity": True, "dissipation": True,
                    "damping": 2e-6},
    })
    errors = []
    for spp in (800, 1600):
        damped = simulate(damped_scene, steps_per_period=spp)
        errors.append(damped.diagnostics["energy_drift"])
    d = damped.diagnostics
    striker_energy = 0.5 * damped_scene.sphere_mass * damped_scene.impact_velocity**2
    assert d["dissipated_J"] > 0.05 * striker_energy
    assert errors[-1] < 1e-6
    assert errors[-1] < errors[0] / 3.0  # the balance error converges at second order
    assert damped.truth["arr"] < elastic.truth["arr"] - 0.02
