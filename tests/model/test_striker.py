"""A striker of another material (``striker.material``): its mass and its Hertz contact with the
first sphere enter every integrator and plate tier; conservation laws, an independent scipy solve
of the chain, and the limit of a striker given with the chain's own properties."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from solitonde.model.contact import hertz_sphere_flat, hertz_sphere_sphere, hertz_two_spheres
from solitonde.model.errors import SceneError
from solitonde.model.materials import MATERIALS
from solitonde.model.scene import scene_from_dict
from solitonde.model.simulate import simulate
from solitonde.model.zener import predict

LONG = {"chain": {"n_particles": 60, "sensor_index": 20},
        "effects": {"plate_model": "rigid", "gravity": False},
        "output": {"duration": 7e-4, "sample_rate": 5e6, "traces": True}}
SMALL_SEM = {"elements": [2, 2, 1], "order": [2, 2, 1], "contact_refinement": 0}


def _with_striker(base: dict, material) -> dict:
    return {**base, "striker": {"material": material}}


def test_two_sphere_contact_constant_reduces_to_identical_spheres() -> None:
    steel = MATERIALS["steel_440c"]
    assert hertz_two_spheres(9.53e-3, steel, steel) == pytest.approx(
        hertz_sphere_sphere(9.53e-3, steel), rel=1e-14)


def test_the_chains_own_properties_give_the_default_run_bit_for_bit() -> None:
    steel = MATERIALS["steel_440c"]
    same = {"name": "my steel", "youngs_modulus": steel.youngs_modulus,
            "poisson_ratio": steel.poisson_ratio, "density": steel.density}
    base = {"effects": {"plate_model": "infinite"}}
    a = simulate(scene_from_dict(base))
    b = simulate(scene_from_dict(_with_striker(base, same)))
    np.testing.assert_array_equal(a.samples, b.samples)
    assert predict(scene_from_dict(_with_striker(base, same))).tof_s == predict(
        scene_from_dict(base)).tof_s


@pytest.mark.parametrize("material", ["tungsten_carbide", "glass"])
@pytest.mark.parametrize("integrator", ["verlet", "dopri5"])
def test_momentum_and_energy_are_conserved_before_the_wave_reaches_the_wall(
        material: str, integrator: str) -> None:
    """Gravity off, a 60-sphere chain, 0.7 ms (the wave is 35 spheres down): the total momentum
    m0 v0 + m sum v_i stays m0 v_imp (internal forces cancel pairwise; Verlet keeps it to
    round-off) only if the striker's mass is the one its contact force acts on; the energy
    balance stays within 1e-6 (dopri5 at rtol 1e-10: at 1e-8 its drift is 2-3e-6 here with the
    chain's own striker too)."""
    scene = scene_from_dict({**_with_striker(LONG, material),
                             "solver": {"integrator": integrator, "rtol": 1e-10}})
    r = simulate(scene)
    v = r.traces["v_m_s"]
    momentum = scene.striker_mass * v[:, 0] + scene.sphere_mass * v[:, 1:].sum(axis=1)
    p0 = scene.striker_mass * scene.impact_velocity
    rtol = 1e-10 if integrator == "verlet" else 1e-6  # dopri5 keeps it to its tolerance
    np.testing.assert_allclose(momentum, p0, rtol=rtol)
    assert np.all(r.traces["contact_force_N"][:, -1] == 0.0)  # the wall was not reached
    assert r.diagnostics["energy_drift"] < 1e-6


def test_a_light_striker_rebounds_and_a_heavy_one_launches_a_train() -> None:
    """Glass (m0/m = 0.33) bounces back off the chain; tungsten carbide (m0/m = 1.95) follows it
    down and sends more than one solitary wave, the identical striker exactly one (the known
    behaviour of striker mass ratios below and above 1)."""
    def run(material):
        return simulate(scene_from_dict(_with_striker(LONG, material) if material else LONG))

    glass = run("glass")
    assert glass.traces["v_m_s"][-1, 0] < 0.0
    counts = {}
    for material in (None, "tungsten_carbide"):
        r = run(material)
        force = r.traces["contact_force_N"][:, 20]  # a contact 20 spheres down
        peaks = [k for k in range(1, force.size - 1)
                 if force[k] > force[k - 1] and force[k] >= force[k + 1]
                 and force[k] > 0.05 * force.max()]
        counts[material] = len(peaks)
    assert counts[None] == 1 and counts["tungsten_carbide"] >= 2, counts


def _scipy_chain(m0: float, m: float, a_0: float, a_s: float, a_w: float, n: int, v_imp: float,
                 t_end: float, sensor: int) -> tuple[np.ndarray, np.ndarray]:
    """An independent solve: striker + n spheres on a rigid wall, Hertz contacts, no gravity;
    returns times and the sensor reading (mean of its two contact forces)."""
    masses = np.full(n + 1, m)
    masses[0] = m0
    consts = np.full(n, a_s)
    consts[0] = a_0

    def forces(u):
        d = np.clip(u[:-1] - u[1:], 0.0, None)
        return consts * d**1.5, a_w * max(u[-1], 0.0) ** 1.5

    def rhs(_t, y):
        u, v = y[:n + 1], y[n + 1:]
        f, fw = forces(u)
        acc = np.empty(n + 1)
        acc[0] = -f[0] / masses[0]
        acc[1:-1] = (f[:-1] - f[1:]) / masses[1:-1]
        acc[-1] = (f[-1] - fw) / masses[-1]
        return np.concatenate([v, acc])

    y0 = np.zeros(2 * (n + 1))
    y0[n + 1] = v_imp
    t = np.linspace(0.0, t_end, 4001)
    sol = solve_ivp(rhs, (0.0, t_end), y0, method="DOP853", t_eval=t, rtol=1e-10, atol=1e-14)
    reading = np.array([0.5 * (forces(y[:n + 1])[0][sensor - 1] + forces(y[:n + 1])[0][sensor])
                        for y in sol.y.T])
    return t, reading


def test_the_incident_pulse_agrees_with_an_independent_scipy_solve() -> None:
    """Tungsten carbide striker on the paper's 20-sphere 440C chain, rigid wall, gravity off:
    the sensor's incident peak time and force within 0.2 % of a scipy DOP853 solve of the same
    equations written here from the scene's constants."""
    scene = scene_from_dict({"striker": {"material": "tungsten_carbide"},
                             "effects": {"plate_model": "rigid", "gravity": False},
                             "output": {"duration": 2e-4, "sample_rate": 2e7}})
    r = simulate(scene)
    n, sensor = scene.chain.n_particles, scene.chain.sensor_index
    a_w = hertz_sphere_flat(scene.chain.diameter, scene.sphere_material, scene.sphere_material)
    t, ref = _scipy_chain(scene.striker_mass, scene.sphere_mass, scene.a_0, scene.a_s, a_w, n,
                          scene.impact_velocity, 2e-4, sensor)
    k = int(np.argmax(ref))
    assert r.truth["incident_time_s"] == pytest.approx(t[k], rel=2e-3)
    assert r.truth["incident_peak_N"] == pytest.approx(ref[k], rel=2e-3)


@pytest.mark.parametrize("tier", ["infinite", "sem", "greens"])
def test_every_plate_tier_runs_a_heavy_striker_with_its_energy_balanced(tier: str) -> None:
    scene = scene_from_dict({"striker": {"material": "tungsten_carbide"},
                             "effects": {"plate_model": tier}, "sem": SMALL_SEM,
                             "plate": {"distance_to_support": 0.1},
                             "output": {"duration": 3e-4}})
    r = simulate(scene)
    assert r.diagnostics["energy_drift"] < 1e-5
    assert r.truth["incident_peak_N"] > simulate(scene_from_dict(
        {"effects": {"plate_model": tier}, "sem": SMALL_SEM,
         "plate": {"distance_to_support": 0.1}, "output": {"duration": 3e-4}})
    ).truth["incident_peak_N"]  # the heavier striker sends a stronger leading wave


def test_theory_refuses_a_striker_it_does_not_describe_naming_the_key() -> None:
    with pytest.raises(SceneError) as err:
        predict(scene_from_dict({"striker": {"material": "tungsten_carbide"}}))
    assert err.value.field == "striker.material"
    with pytest.raises(SceneError, match=r"striker\.material"):
        scene_from_dict({"striker": {"material": {"name": "x", "youngs_modulus": 2e11,
                                                  "poisson_ratio": 0.7, "density": 8000}}})
