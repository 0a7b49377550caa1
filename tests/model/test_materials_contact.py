"""Materials and Hertz contact constants (the paper's Secs. 2, 3.1 and 4.1.1)."""

from __future__ import annotations

from math import pi, sqrt

import pytest

from solitonde.model import MATERIALS, SceneError, get_material
from solitonde.model import contact as c

STEEL = get_material("steel_440c")
AL = get_material("al_6061")


def test_library_holds_the_paper_materials():
    assert (STEEL.youngs_modulus, STEEL.poisson_ratio, STEEL.density) == (200e9, 0.28, 7800.0)
    assert (AL.youngs_modulus, AL.poisson_ratio, AL.density) == (68.9e9, 0.33, 2700.0)
    printed = get_material("al_6061_paper")
    assert printed.density == 2360.0 and printed.youngs_modulus == AL.youngs_modulus


def test_unknown_material_lists_the_known_ones():
    with pytest.raises(SceneError) as info:
        get_material("unobtainium", field="plate.material")
    assert info.value.field == "plate.material"
    for name in MATERIALS:
        assert name in str(info.value)


@pytest.mark.parametrize("mat", list(MATERIALS.values()), ids=list(MATERIALS))
def test_elastic_constants_are_consistent(mat):
    """Lamé parameters reproduce E and nu; c_T < c_plate < c_L; sqrt(E/rho) < c_plate."""
    g, lam = mat.shear_modulus, mat.lame_lambda
    assert g * (3 * lam + 2 * g) / (lam + g) == pytest.approx(mat.youngs_modulus, rel=1e-12)
    assert lam / (2 * (lam + g)) == pytest.approx(mat.poisson_ratio, rel=1e-12)
    assert mat.shear_velocity < mat.bar_velocity < mat.plate_velocity < mat.longitudinal_velocity


def test_hertz_constants_by_hand():
    d = 9.53e-3
    a_s = c.hertz_sphere_sphere(d, STEEL)
    assert a_s == pytest.approx(200e9 * sqrt(d) / (3 * (1 - 0.28**2)), rel=1e-14)
    e_star = 1 / ((1 - 0.28**2) / 200e9 + (1 - 0.33**2) / 68.9e9)
    assert c.hertz_sphere_flat(d, STEEL, AL) == pytest.approx(4 / 3 * e_star * sqrt(d / 2),
                                                              rel=1e-14)
    # Sphere on sphere is the general Hertz law with R = D/4 and E* = E/(2 (1 - nu^2)).
    e_ss = c.effective_modulus(STEEL, STEEL)
    assert a_s == pytest.approx(4 / 3 * e_ss * sqrt(d / 4), rel=1e-14)
    assert c.sphere_mass(d, STEEL) == pytest.approx(7800 * pi * d**3 / 6, rel=1e-14)


def test_scaling_with_size():
    assert c.hertz_sphere_sphere(4e-3, STEEL) / c.hertz_sphere_sphere(1e-3, STEEL) == (
        pytest.approx(2.0, rel=1e-14))
    assert c.sphere_mass(2e-3, STEEL) / c.sphere_mass(1e-3, STEEL) == pytest.approx(8.0, rel=1e-14)
    # Z = 8 sqrt(rho t D_p) grows as t^2 (D_p ~ t^3).
    assert c.plate_impedance(2e-3, AL) / c.plate_impedance(1e-3, AL) == (
        pytest.approx(4.0, rel=1e-14))
    d_p = c.plate_bending_stiffness(3.18e-3, AL)
    assert d_p == pytest.approx(68.9e9 * 3.18e-3**3 / (12 * (1 - 0.33**2)), rel=1e-14)
    assert c.plate_impedance(3.18e-3, AL) == pytest.approx(8 * sqrt(2700 * 3.18e-3 * d_p),
                                                           rel=1e-14)


def test_effective_modulus_is_symmetric():
    assert c.effective_modulus(STEEL, AL) == pytest.approx(c.effective_modulus(AL, STEEL),
                                                           rel=1e-15)
