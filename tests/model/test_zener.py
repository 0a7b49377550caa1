"""Zener impact theory: closed-form limits, scaling laws, derived constants (paper, Sec. 4.1)."""

from __future__ import annotations

from math import pi, sqrt

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import quad, solve_ivp

from solitonde.model import scene_from_dict
from solitonde.model import zener as z


def _scene(**sections):
    return scene_from_dict(sections)


# --- the ODE -----------------------------------------------------------------------------------


def test_halfspace_contact_time_matches_closed_form():
    """tau_c(0) equals 2 (5/4)^(2/5) (2/5) B(2/5, 1/2) = 3.2181 to 1e-9."""
    _, tau_c = z.restitution_and_contact_time(0.0)
    closed = z.halfspace_contact_time()
    assert round(closed, 4) == 3.2181
    assert tau_c == pytest.approx(closed, rel=1e-9)


def test_elastic_limit_restitution_is_one():
    """lambda = 0 conserves energy: e = 1."""
    e, _ = z.restitution_and_contact_time(0.0)
    assert e == pytest.approx(1.0, abs=1e-9)


def test_energy_lost_to_plate_at_small_lambda():
    """1 - e^2 = 2 lambda int sigma^3 dtau; as lambda -> 0 the Hertz solution gives the integral.

    Along the Hertz motion sigma'^2/2 + sigma^(5/2)/(5/2) = 1/2, so
    int sigma^3 dtau = 2 int_0^sigma_m sigma^3 / sqrt(1 - 0.8 sigma^(5/2)) dsigma.
    """
    sigma_m = 1.25**0.4
    integral = 2.0 * quad(lambda s: s**3 / sqrt(1.0 - 0.8 * s**2.5), 0.0, sigma_m,
                          epsabs=1e-13, epsrel=1e-12, limit=200)[0]
    for lam in (1e-3, 1e-4):
        e, _ = z.restitution_and_contact_time(lam)
        # The next term is O(lambda), so the relative error shrinks in proportion to lambda.
        assert (1.0 - e * e) / (2.0 * lam) == pytest.approx(integral, rel=5.0 * lam)


def test_regularised_integration_agrees_with_direct_integration():
    """The r = sqrt(sigma), dtau = r ds formulation gives what a plain integration in tau gives."""

    def rhs(_t, u, lam):
        s, v = u
        sp = max(s, 0.0)
        return [v, -(sp**1.5) - 1.5 * lam * sqrt(sp) * v]

    def end(_t, u, _lam):
        return u[0]

    end.terminal = True
    end.direction = -1
    for lam in (0.0, 0.3, 1.0, 2.5):
        sol = solve_ivp(rhs, (0.0, 1e3), [0.0, 1.0], args=(lam,), method="DOP853", rtol=1e-12,
                        atol=1e-14, events=end)
        t_direct = sol.t_events[0][-1]
        # sigma' at separation is zeta' (the plate surface is at rest once the force is zero).
        e_direct = -sol.y_events[0][-1][1]
        e, tau_c = z.restitution_and_contact_time(lam)
        # The direct integration suffers from the sqrt singularities; 1e-6 is what it can do.
        assert tau_c == pytest.approx(t_direct, rel=1e-6)
        assert e == pytest.approx(e_direct, rel=1e-6, abs=1e-9)


def test_restitution_falls_and_contact_time_grows_with_lambda():
    lams = np.linspace(0.0, 20.0, 401)
    e, tau_c = z.restitution_and_contact_time_many(lams)
    assert np.all(np.diff(e) < 0)
    assert np.all(np.diff(tau_c) > 0)
    assert e[-1] < 1e-6  # e tends to 0 for a very inelastic impact
    ref = [z.restitution_and_contact_time(lam) for lam in (0.0, 0.5, 2.0)]
    assert [r[0] for r in ref] == sorted((r[0] for r in ref), reverse=True)
    assert [r[1] for r in ref] == sorted(r[1] for r in ref)


def test_fast_path_matches_reference():
    """The Chebyshev table keeps 1e-6 relative (it achieves ~1e-12) over lambda in [0, 20]."""
    rng = np.random.default_rng(7)
    table = z._table()
    width = table.x_max / z.TABLE_PANELS
    # Random lambdas, both table ends, and panel edges where two series meet.
    lams = np.concatenate([[0.0, 1e-9, 20.0], np.expm1(width * np.arange(1, 4)),
                           rng.uniform(0.0, 20.0, 12)])
    e, tau_c = z.restitution_and_contact_time_many(lams)
    for lam, e_fast, t_fast in zip(lams, e, tau_c, strict=True):
        e_ref, t_ref = z.restitution_and_contact_time(lam)
        assert e_fast == pytest.approx(e_ref, rel=1e-8)
        assert t_fast == pytest.approx(t_ref, rel=1e-8)
    assert table.tail < 1e-10


def test_shipped_table_is_what_the_integrator_builds_today():
    """zener_table.json is current: a fresh build from the compiled DOP853 gives the same e and
    tau_c (to 1e-12 relative: the builds differ only in rounding) and the same anchor.

    If this fails after a TABLE_* change, regenerate with ``zener.write_table()``."""
    import json

    shipped = json.loads(z.TABLE_FILE.read_text(encoding="utf-8"))
    fresh = z.build_table()
    assert {k: shipped[k] for k in ("lambda_max", "panels", "degree", "rtol")} == {
        k: fresh[k] for k in ("lambda_max", "panels", "degree", "rtol")}
    a, b = z._cheb_table(shipped), z._cheb_table(fresh)
    t = np.linspace(-1.0, 1.0, 41)
    for panel in range(z.TABLE_PANELS):
        idx = np.full_like(t, panel, dtype=np.intp)
        for name in ("log_e", "log_tau"):
            np.testing.assert_allclose(z._clenshaw(getattr(a, name), idx, t),
                                       z._clenshaw(getattr(b, name), idx, t), rtol=0, atol=1e-12)
    assert (a.anchor_e, a.anchor_tau) == pytest.approx((b.anchor_e, b.anchor_tau), rel=1e-12)


def test_scalar_and_vector_table_reads_agree_and_predict_uses_them():
    """The scalar Clenshaw loop equals the vectorised one; predict's e is the table's."""
    lams = np.array([0.0, 0.37, 3.0, 19.99])
    e_vec, tau_vec = z.restitution_and_contact_time_many(lams)
    for lam, e, tau in zip(lams, e_vec, tau_vec, strict=True):
        assert z.restitution_and_contact_time_one(lam) == pytest.approx((e, tau), rel=1e-14)
    p = z.predict(_scene())
    assert p.e == pytest.approx(z.restitution_and_contact_time(p.lambda_)[0], rel=1e-10)


def test_fast_path_beyond_table_and_shapes():
    """Lambdas above the table are integrated (compiled DOP853); output keeps the input shape."""
    e, tau_c = z.restitution_and_contact_time_many(np.array([[0.25, 25.0]]))
    assert e.shape == tau_c.shape == (1, 2)
    e_ref, t_ref = z.restitution_and_contact_time(25.0)
    assert e[0, 1] == pytest.approx(e_ref, rel=1e-8)
    assert tau_c[0, 1] == pytest.approx(t_ref, rel=1e-8)
    with pytest.raises(ValueError, match="lambda"):
        z.restitution_and_contact_time_many([0.1, -0.5])
    with pytest.raises(ValueError, match="lambda"):
        z.restitution_and_contact_time(float("nan"))


# --- constants derived from their definitions -----------------------------------------------


def test_derived_constants_match_the_printed_ones():
    assert round(z.travel_time_coefficient(), 3) == 1.180
    assert round(z.contact_time_coefficient(), 3) == 1.080
    assert round(z.critical_distance_coefficient(), 2) == 1.37
    assert round(z.nesterenko_force_coefficient(), 4) == 0.6802


# --- lambda and its scaling ---------------------------------------------------------------------


def test_lambda_of_default_scene_by_hand():
    s = _scene()
    m = 7800.0 * pi * 9.53e-3**3 / 6.0
    e_star = 1.0 / ((1 - 0.28**2) / 200e9 + (1 - 0.33**2) / 68.9e9)
    a_p = 4.0 / 3.0 * e_star * sqrt(9.53e-3 / 2.0)
    d_p = 68.9e9 * 3.18e-3**3 / (12.0 * (1 - 0.33**2))
    zimp = 8.0 * sqrt(2700.0 * 3.18e-3 * d_p)
    v_in = 0.682 * sqrt(2.0 * 9.80665 * 5e-3)
    assert z.inelasticity(s) == pytest.approx(a_p**0.4 * m**0.6 * v_in**0.2 / zimp, rel=1e-12)


@settings(max_examples=40, deadline=None)
@given(
    diameter=st.floats(1e-3, 0.05),
    thickness=st.floats(0.5e-3, 0.02),
    velocity=st.floats(0.01, 5.0),
)
def test_lambda_scales_as_d_over_t_squared_times_v_to_one_fifth(diameter, thickness, velocity):
    """lambda / ((D/t)^2 v^(1/5)) is one constant for fixed materials."""
    ref = _scene(striker={"velocity": 1.0}, chain={"diameter": 0.01}, plate={"thickness": 0.01})
    s = _scene(striker={"velocity": velocity}, chain={"diameter": diameter},
               plate={"thickness": thickness})
    ratio = z.inelasticity(s) / ((diameter / thickness) ** 2 * velocity**0.2)
    assert ratio == pytest.approx(z.inelasticity(ref), rel=1e-10)


# --- ARR, TOF, critical distance ----------------------------------------------------------------


def _grid():
    rows = []
    for d in (4.76e-3, 9.53e-3, 19.05e-3):
        for t in (2.29e-3, 3.18e-3, 4.83e-3):
            rows.append(z.predict(_scene(chain={"diameter": d}, plate={"thickness": t})))
    return sorted(rows, key=lambda p: p.d_over_t)


def test_arr_of_the_paper_grid_falls_with_d_over_t_and_vanishes_above_five():
    grid = _grid()
    arr = np.array([p.arr for p in grid])
    assert np.all(np.diff(arr) < 0)
    assert all(p.arr < 0.01 for p in grid if p.d_over_t > 5.0)
    assert all(p.arr > 0.1 for p in grid if p.d_over_t < 4.5)
    # Along a continuous D/t sweep (default plate, varying D) ARR is small from about D/t = 5 on.
    for ratio, bound in ((5.0, 0.05), (6.0, 0.01), (8.0, 1e-3)):
        p = z.predict(_scene(chain={"diameter": ratio * 3.18e-3}))
        assert p.arr < bound


def test_arr_and_tof_over_d_depend_on_d_over_t_only():
    """Eq. 16: at fixed D/t, ARR is unchanged and TOF scales with D."""
    a = z.predict(_scene(chain={"diameter": 9.53e-3}, plate={"thickness": 3.18e-3}))
    b = z.predict(_scene(chain={"diameter": 2 * 9.53e-3}, plate={"thickness": 2 * 3.18e-3}))
    assert b.arr == pytest.approx(a.arr, rel=1e-12)
    assert b.tof_s / b.diameter_m == pytest.approx(a.tof_s / a.diameter_m, rel=1e-12)


def test_tof_equals_equation_15():
    """predict() builds TOF from travel and contact times; that is Eq. 15 term by term."""
    s = _scene()
    p = z.predict(s)
    n = z.travel_diameters(s)
    assert n == 14
    m, v = s.sphere_mass, s.impact_velocity

    def eq15(c_travel, c_contact):
        return m**0.4 * v**-0.2 * (c_travel * n * (1 + p.e**-0.2) * s.a_s**-0.4
                                   + c_contact * p.tau_c * s.a_p**-0.4)

    assert p.tof_s == pytest.approx(
        eq15(z.travel_time_coefficient(), z.contact_time_coefficient()), rel=1e-12)
    # With the printed, rounded constants: agreement to their 4 significant digits.
    assert p.tof_s == pytest.approx(eq15(1.180, 1.080), rel=1e-3)
    assert p.contact_time_s == pytest.approx(
        p.tau_c * z.time_scale(m, s.a_p, z.CHATTERJEE_RATIO * v), rel=1e-12)


def test_travel_diameters_follow_the_chain():
    assert z.travel_diameters(_scene(chain={"n_particles": 30, "sensor_index": 10})) == 21
    assert z.travel_diameters(_scene(chain={"n_particles": 5, "sensor_index": 5})) == 1


def test_critical_distance_matches_equation_18():
    s = _scene()
    mat_s, mat_p = s.sphere_material, s.plate_material
    bracket = mat_s.density * ((1 - mat_s.poisson_ratio**2) / mat_s.youngs_modulus
                               + (1 - mat_p.poisson_ratio**2) / mat_p.youngs_modulus)

    def eq18(coefficient, k):
        return (coefficient * k * s.chain.diameter * mat_p.bar_velocity * bracket**0.4
                * s.impact_velocity**-0.2)

    for k in (0.57, 0.2, 1.0):
        lc = z.critical_distance(s, k)
        assert lc == pytest.approx(eq18(z.critical_distance_coefficient(), k), rel=1e-12)
        assert lc == pytest.approx(eq18(1.37, k), rel=0.005 / 1.37)
    # k = 0.57 and 0.2 are the paper's c of about 2,900 and 1,000 m/s for Al 6061 (rho 2700).
    assert 0.57 * mat_p.bar_velocity == pytest.approx(2900.0, rel=0.01)
    assert 0.2 * mat_p.bar_velocity == pytest.approx(1000.0, rel=0.02)
    with pytest.raises(ValueError):
        z.critical_distance(s, 0.0)


def test_thinner_plate_does_not_change_halfspace_critical_distance_but_larger_spheres_do():
    a = z.predict(_scene(plate={"thickness": 2.29e-3}))
    b = z.predict(_scene(plate={"thickness": 4.83e-3}))
    assert a.critical_distance_m == pytest.approx(b.critical_distance_m, rel=1e-12)
    c = z.predict(_scene(chain={"diameter": 2 * 9.53e-3}))
    assert c.critical_distance_m == pytest.approx(2 * a.critical_distance_m, rel=1e-12)


# --- solitary waves ---------------------------------------------------------------------------


def test_solitary_wave_force_and_velocity_forms_agree():
    s = _scene()
    d, a_s, m = s.chain.diameter, s.a_s, s.sphere_mass
    mat = s.sphere_material
    for v_m in (0.05, 0.2135, 1.0):
        v_s = z.solitary_wave_speed(d, a_s, m, v_m)
        f_m = z.incident_peak_force(d, a_s, m, v_m)
        assert z.solitary_wave_speed_from_force(d, a_s, m, f_m) == pytest.approx(v_s, rel=1e-12)
        printed = 0.6802 * (2 * mat.youngs_modulus / (
            d * mat.density**1.5 * (1 - mat.poisson_ratio**2))) ** (1 / 3) * f_m ** (1 / 6)
        assert v_s == pytest.approx(printed, rel=1e-4)
    # Peak force scales as v_m^(6/5).
    f1 = z.incident_peak_force(d, a_s, m, 0.1)
    f2 = z.incident_peak_force(d, a_s, m, 0.2)
    assert f2 / f1 == pytest.approx(2**1.2, rel=1e-12)


def test_prediction_dict_keys():
    data = z.predict(_scene()).to_dict()
    for key in ("lambda", "e", "tau_c", "contact_time_s", "arr", "tof_s", "critical_distance_m",
                "critical_distance_k057_m", "critical_distance_k02_m", "solitary_wave_speed_m_s",
                "incident_peak_force_N"):
        assert key in data
    assert data["critical_distance_m"] == {"0.57": data["critical_distance_k057_m"],
                                           "0.2": data["critical_distance_k02_m"]}
    assert data["arr"] == pytest.approx(data["e"] ** 1.2, rel=1e-12)
