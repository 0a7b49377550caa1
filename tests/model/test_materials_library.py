"""Materials by name or by their properties: the library, the checks, and the physics using them.

A steel plate given only by its properties goes through the infinite-plate chain and must agree
with an independent solve written here (scipy's DOP853 on the Hertz chain with Zener's dashpot
under the last sphere, Sec. 5 of the physics notes); the theory's inelasticity lambda (Eq. 4)
must be the hand-computed one for three materials.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app
from solitonde.model.errors import SceneError
from solitonde.model.materials import MATERIALS
from solitonde.model.scene import load_scene, scene_from_dict
from solitonde.model.simulate import simulate

STEEL = {"name": "S235", "youngs_modulus": 210e9, "poisson_ratio": 0.30, "density": 7850.0}


def test_the_library_has_the_common_nde_materials_with_plausible_wave_speeds():
    expected = {  # bar velocity sqrt(E/rho), m/s, from handbook tables, 10 %
        "steel_structural": 5050, "steel_304": 4910, "al_2024_t3": 5130, "al_6061": 5050,
        "al_7075_t6": 5050, "ti_6al_4v": 5070, "copper": 3600, "brass": 3590, "glass": 5370,
        "pmma": 1610, "steel_440c": 5060, "steel_52100": 5190, "tungsten_carbide": 6420,
    }
    for name, speed in expected.items():
        m = MATERIALS[name]
        assert abs(m.bar_velocity / speed - 1) < 0.10, (name, m.bar_velocity)
        assert m.youngs_modulus > 0 and -1 < m.poisson_ratio < 0.5 and m.density > 0


@pytest.mark.parametrize(("material", "field", "words"), [
    ({**STEEL, "youngs_modulus": 0}, "plate.material.youngs_modulus",
     "1e+06 <= youngs_modulus <= 1e+13 Pa"),
    ({**STEEL, "poisson_ratio": 0.5}, "plate.material.poisson_ratio", "-1 < nu < 0.5"),
    ({**STEEL, "poisson_ratio": -1.0}, "plate.material.poisson_ratio", "-1 < nu < 0.5"),
    ({**STEEL, "density": "heavy"}, "plate.material.density",
     "1 <= density <= 100000 kg/m^3"),
    ({k: v for k, v in STEEL.items() if k != "density"}, "plate.material.density", "missing"),
    ({**STEEL, "E": 1}, "plate.material.E", "unknown key"),
    ("unobtainium", "plate.material", "steel_structural"),
    (True, "plate.material", "mapping"),
])
def test_a_bad_material_names_the_key_and_what_is_allowed(material, field, words):
    with pytest.raises(SceneError) as err:
        scene_from_dict({"plate": {"material": material}})
    assert err.value.field == field and words in str(err.value), str(err.value)


def test_a_material_by_properties_is_the_same_as_by_name():
    props = {"name": "x", **{k: getattr(MATERIALS["ti_6al_4v"], k)
                             for k in ("youngs_modulus", "poisson_ratio", "density")}}
    a = load_scene(None, ["plate.material=ti_6al_4v"])
    b = scene_from_dict({"plate": {"material": props}})
    assert a.a_p == b.a_p and a.plate_material.density == b.plate_material.density
    # the sphere too, from the command line, key by key
    c = load_scene(None, ["chain.material.youngs_modulus=614e9",
                          "chain.material.poisson_ratio=0.22", "chain.material.density=14900"])
    assert c.sphere_mass == pytest.approx(load_scene(None, [
        "chain.material=tungsten_carbide"]).sphere_mass)


def _lambda_by_hand(sphere: dict, plate: dict, d: float, t: float, h: float) -> float:
    """Eq. 4 from the material constants, written out here: lambda = A_p^(2/5) m^(3/5)
    v_in^(1/5) / Z."""
    e_star = 1.0 / ((1 - sphere["nu"] ** 2) / sphere["E"] + (1 - plate["nu"] ** 2) / plate["E"])
    a_p = 4.0 / 3.0 * e_star * math.sqrt(d / 2.0)
    m = sphere["rho"] * math.pi * d**3 / 6.0
    v_in = 0.682 * math.sqrt(2.0 * 9.80665 * h)
    bending = plate["E"] * t**3 / (12.0 * (1.0 - plate["nu"] ** 2))
    z = 8.0 * math.sqrt(plate["rho"] * t * bending)
    return a_p**0.4 * m**0.6 * v_in**0.2 / z


@pytest.mark.parametrize(("plate", "constants"), [
    ("steel_structural", {"E": 200e9, "nu": 0.26, "rho": 7850.0}),
    ("ti_6al_4v", {"E": 113.8e9, "nu": 0.342, "rho": 4430.0}),
    ("pmma", {"E": 3.1e9, "nu": 0.37, "rho": 1190.0}),
])
def test_theory_lambda_for_three_plate_materials_is_eq_4_by_hand(plate, constants):
    res = CliRunner().invoke(build_app(), ["theory", "--set", f"plate.material={plate}",
                                           "--set", "plate.thickness=4e-3", "--json"])
    assert res.exit_code == 0, res.output
    spheres = {"E": 200e9, "nu": 0.28, "rho": 7800.0}  # 440C, the default chain
    expected = _lambda_by_hand(spheres, constants, 9.53e-3, 4e-3, 5e-3)
    assert json.loads(res.stdout)["lambda"] == pytest.approx(expected, rel=1e-9)


def _independent_chain(scene, duration: float) -> tuple[np.ndarray, np.ndarray]:
    """Striker + N spheres + Zener's dashpot, gravity off, by scipy: the sensor force."""
    n, m, a_s, a_p = scene.chain.n_particles, scene.sphere_mass, scene.a_s, scene.a_p
    plate = scene.plate_material
    bending = plate.plane_stress_modulus * scene.plate.thickness**3 / 12.0
    z = 8.0 * math.sqrt(plate.density * scene.plate.thickness * bending)
    k = scene.chain.sensor_index

    def forces(u: np.ndarray, w: float) -> tuple[np.ndarray, float]:
        chain = a_s * np.clip(u[:-1] - u[1:], 0.0, None) ** 1.5
        return chain, a_p * max(u[-1] - w, 0.0) ** 1.5

    def rhs(_t: float, y: np.ndarray) -> np.ndarray:
        u, v, w = y[: n + 1], y[n + 1: 2 * n + 2], y[-1]
        f, fp = forces(u, w)
        acc = np.zeros(n + 1)
        acc[:-1] -= f / m
        acc[1:] += f / m
        acc[-1] -= fp / m
        return np.concatenate([v, acc, [fp / z]])

    y0 = np.zeros(2 * n + 3)
    y0[n + 1] = scene.impact_velocity
    sol = solve_ivp(rhs, (0.0, duration), y0, method="DOP853", rtol=1e-10, atol=1e-16,
                    dense_output=True, max_step=2e-7)
    t = np.arange(0.0, duration, 2e-9)
    u = sol.sol(t)[: n + 1]
    chain = a_s * np.clip(u[:-1] - u[1:], 0.0, None) ** 1.5
    return t, 0.5 * (chain[k - 1] + chain[k])  # contacts above and below particle k


def test_a_steel_plate_by_properties_agrees_with_an_independent_chain_solve():
    scene = scene_from_dict({"plate": {"material": STEEL, "thickness": 3.0e-3},
                             "effects": {"plate_model": "infinite", "gravity": False}})
    result = simulate(scene)
    t, f = _independent_chain(scene, result.t0 + result.dt * result.samples.size)
    i_inc = int(np.argmax(f))
    quiet = i_inc + int(np.argmax(f[i_inc:] < 0.01 * f[i_inc]))
    i_ref = quiet + int(np.argmax(f[quiet:]))
    tof, arr = t[i_ref] - t[i_inc], f[i_ref] / f[i_inc]
    truth = result.truth
    assert truth["tof_s"] == pytest.approx(tof, rel=0.01), (truth["tof_s"], tof)
    assert truth["arr"] == pytest.approx(arr, rel=0.02), (truth["arr"], arr)
    assert 0.2 < arr < 0.9  # a reflection the test can tell from the incident
