"""The plate material's spread: the library's values, how a table finds them, and the linearised
term the inversion adds (Zener's exchange rates checked against the model's own theory)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from solitonde.instrument.inference.inversion import invert
from solitonde.instrument.inference.inversion_inputs import FeatureSummary
from solitonde.instrument.inference.material_spread import exchange_rates, spread_of
from solitonde.instrument.inference.woodbury import solve2 as _solve2
from solitonde.instrument.tables.table import ModelTable
from solitonde.model import zener
from solitonde.model.materials import (
    DEFAULT_PROPERTY_SPREAD,
    MATERIALS,
    SPREAD_KEYS,
    is_default_spread,
    material_spread,
    properties_from,
)
from solitonde.model.scene import scene_from_dict

TABLE = Path(__file__).resolve().parents[2] / "data_samples" / "default_table.h5"
NO_SPREAD = dict.fromkeys(SPREAD_KEYS, 0.0)


def test_every_library_material_states_a_grade_spread_about_its_own_value() -> None:
    """Every entry has a spread, a few percent (PMMA's E, 2.4-3.4 GPa about 3.1, is 11 %), and
    the spread is the root-mean-square distance of the grade's range from the entry's value, not
    the range's own standard deviation where the value is off its centre."""
    for m in MATERIALS.values():
        assert 0.0 < m.youngs_modulus_rel_sd <= 0.12, m.name
        assert 0.0 < m.poisson_ratio_sd <= 0.03, m.name
        assert 0.0 < m.density_rel_sd <= 0.015, m.name
    a36 = MATERIALS["steel_structural"]  # nu 0.26 in 0.25-0.30; E 200 GPa at 190-210's centre
    assert a36.poisson_ratio_sd == pytest.approx(math.sqrt(0.05**2 / 12 + 0.015**2))
    assert a36.youngs_modulus_rel_sd == pytest.approx(20e9 / math.sqrt(12) / 200e9)


def test_a_spread_comes_from_the_mapping_the_library_or_the_stated_default() -> None:
    steel = MATERIALS["steel_structural"]
    # a table's family records properties with the library's name: the library's spread
    assert material_spread(properties_from("steel_structural"))["youngs_modulus_rel_sd"] == \
        steel.youngs_modulus_rel_sd
    stated = {"name": "S235", "youngs_modulus": 210e9, "poisson_ratio": 0.3, "density": 7850.0,
              "youngs_modulus_rel_sd": 0.05}
    assert material_spread(properties_from(stated)) == {
        "youngs_modulus_rel_sd": 0.05, "poisson_ratio_sd": 0.0, "density_rel_sd": 0.0}
    # a library name with other properties is not that grade: the stated default, never 0
    other = {**properties_from("steel_structural"), "youngs_modulus": 210e9}
    assert material_spread(other) == DEFAULT_PROPERTY_SPREAD
    assert is_default_spread(material_spread(other))
    assert not is_default_spread(material_spread(properties_from(stated)))
    # exact properties are said so by stating zeros
    exact = {**other, "youngs_modulus_rel_sd": 0.0, "poisson_ratio_sd": 0.0,
             "density_rel_sd": 0.0}
    assert material_spread(properties_from(exact)) == NO_SPREAD
    assert material_spread(None) == NO_SPREAD
    table = ModelTable.load(TABLE)
    assert spread_of(table)["youngs_modulus_rel_sd"] == MATERIALS["al_6061"].youngs_modulus_rel_sd
    assert spread_of(table, stated)["youngs_modulus_rel_sd"] == 0.05


@pytest.mark.parametrize(("value", "words"), [(-0.1, "out of range"), (0.9, "<= 0.5"),
                                              ("x", "out of range")])
def test_a_bad_spread_names_its_key(value: object, words: str) -> None:
    with pytest.raises(ValueError, match=r"\[youngs_modulus_rel_sd\]") as info:
        properties_from({"youngs_modulus": 2e11, "poisson_ratio": 0.3, "density": 7850.0,
                         "youngs_modulus_rel_sd": value})
    assert words in str(info.value)


@pytest.mark.parametrize("plate", ["al_6061", "steel_structural", "pmma"])
def test_exchange_rates_are_the_theorys_own_derivatives(plate: str) -> None:
    """Zener's theory (the model's closed form) moved by a material change equals the same
    theory moved by the thickness change the exchange rate names, plus the contact-time term:
    dF/dln E' = dF/dln t (-d ln lambda / 2) [- 0.4 w T_c for TOF]; likewise for rho."""
    base = {"plate": {"material": plate, "thickness": 3e-3}}
    props = properties_from(plate)
    eps = 1e-4

    def theory(thickness: float = 3e-3, e_scale: float = 1.0, rho_scale: float = 1.0):
        material = {**props, "youngs_modulus": props["youngs_modulus"] * e_scale,
                    "density": props["density"] * rho_scale}
        scene = scene_from_dict({"plate": {"material": material, "thickness": thickness}})
        p = zener.predict(scene)
        return np.array([p.tof_s, p.arr]), p.contact_time_s

    f0, t_c = theory()
    d_t = (theory(3e-3 * math.exp(eps))[0] - theory(3e-3 * math.exp(-eps))[0]) / (2 * eps)
    d_e = (theory(e_scale=math.exp(eps))[0] - theory(e_scale=math.exp(-eps))[0]) / (2 * eps)
    d_r = (theory(rho_scale=math.exp(eps))[0] - theory(rho_scale=math.exp(-eps))[0]) / (2 * eps)
    rates = exchange_rates(props, properties_from(scene_from_dict(base).chain.material))
    lam_e, lam_r = rates["d_ln_lambda"]
    expected_e = d_t * (-0.5 * lam_e) + np.array([-0.4 * rates["contact_share"] * t_c, 0.0])
    expected_r = d_t * (-0.5 * lam_r)
    np.testing.assert_allclose(d_e, expected_e, rtol=2e-3, atol=1e-12)
    np.testing.assert_allclose(d_r, expected_r, rtol=2e-3, atol=1e-12)
    assert f0[1] > 0


def test_the_closed_form_2x2_solve_is_the_linear_algebra() -> None:
    rng = np.random.default_rng(3)
    u = rng.normal(size=(50, 2, 4))
    m = np.einsum("nik,njk->nij", u, u)  # symmetric positive semi-definite
    b = rng.normal(size=(50, 2))
    quad, logdet = _solve2(np.stack([m[:, 0, 0], m[:, 0, 1], m[:, 1, 1]]), b.T)
    full = np.eye(2) + m
    solved = np.linalg.solve(full, b[..., None])[..., 0]
    np.testing.assert_allclose(quad, np.einsum("ni,ni->n", b, solved), rtol=1e-10)
    np.testing.assert_allclose(logdet, np.linalg.slogdet(full)[1], rtol=1e-10)


def test_the_spread_widens_the_answer_at_a_table_node_and_keeps_it_there() -> None:
    """A plate of the table's own family far from a support, measured as the table says: with a
    spread stated (E 10 %, rho 5 %: lambda by 3 %, the thickness read by 1.6 %) the 95 %
    thickness interval is wider and still holds the node. (The library's 6061 spread, E 0.8 %,
    moves lambda by 0.3 %: too little to show beside the shot scatter.)"""
    table = ModelTable.load(TABLE)
    i_t, i_l = 4, 13  # 3.31 mm at 457 mm
    item = FeatureSummary(9.53e-3, float(table.features["tof_s"][1, i_t, i_l]),
                          float(table.features["arr"][1, i_t, i_l]), None, None, 5)
    truth = float(table.axes["thickness_m"][i_t])
    widths = []
    loose = {"youngs_modulus_rel_sd": 0.10, "poisson_ratio_sd": 0.0, "density_rel_sd": 0.05}
    for spread in (loose, NO_SPREAD):
        est = invert(table, [item], material_spread=spread)
        low, high = est.thickness_m.ci95
        assert low <= truth <= high and est.thickness_m.status == "constrained"
        widths.append(high - low)
    assert widths[0] > 1.2 * widths[1]
