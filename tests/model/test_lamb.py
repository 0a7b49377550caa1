"""Rayleigh-Lamb dispersion: analytic limits, cut-off, the original equations, no branch jumps."""

from __future__ import annotations

import numpy as np
import pytest

from solitonde.model import SimulationError, get_material, lamb

AL = get_material("al_6061")
T = 3.18e-3


@pytest.fixture(scope="module")
def fig9():
    """The three paper plates' A0/S0/A1 up to 3 MHz (paper Fig. 9)."""
    f = np.linspace(2e3, 3e6, 400)
    return {t: lamb.lamb_dispersion(t, AL, f) for t in (2.29e-3, 3.18e-3, 4.83e-3)}


def test_rayleigh_velocity_solves_rayleigh_equation():
    c_r = lamb.rayleigh_velocity(AL)
    x2 = (c_r / AL.shear_velocity) ** 2
    k2 = (AL.shear_velocity / AL.longitudinal_velocity) ** 2
    assert (2 - x2) ** 2 == pytest.approx(4 * np.sqrt(1 - x2 * k2) * np.sqrt(1 - x2), rel=1e-12)
    # Viktorov's approximation (0.87 + 1.12 nu)/(1 + nu) is good to about half a per cent.
    nu = AL.poisson_ratio
    assert c_r / AL.shear_velocity == pytest.approx((0.87 + 1.12 * nu) / (1 + nu), rel=5e-3)


def test_s0_low_frequency_limit_is_plate_velocity():
    """S0 -> sqrt(E / (rho (1 - nu^2))), approached as (k h)^2, i.e. as f^2."""
    f = np.array([1e3, 2e3, 4e3, 8e3])
    d = lamb.lamb_dispersion(T, AL, f)
    dev = np.abs(d.phase_velocity["S0"] / AL.plate_velocity - 1.0)
    assert dev[0] < 1e-5
    slope = np.polyfit(np.log(f), np.log(dev), 1)[0]
    assert slope == pytest.approx(2.0, abs=0.05)
    assert d.group_velocity["S0"][0] == pytest.approx(AL.plate_velocity, rel=1e-4)


def test_a0_low_frequency_limit_is_kirchhoff_flexural_wave():
    """A0 phase -> sqrt(w) (D_p/(rho t))^(1/4), group -> twice that; the error falls as f."""
    f = np.array([250.0, 500.0, 1e3, 2e3])
    d = lamb.lamb_dispersion(T, AL, f)
    c_k = lamb.kirchhoff_phase_velocity(f, T, AL)
    dev = np.abs(d.phase_velocity["A0"] / c_k - 1.0)
    assert dev[0] < 1e-3
    assert np.polyfit(np.log(f), np.log(dev), 1)[0] == pytest.approx(1.0, abs=0.05)
    dev_g = np.abs(d.group_velocity["A0"] / (2 * c_k) - 1.0)
    assert dev_g[0] < 3e-3
    assert np.polyfit(np.log(f), np.log(dev_g), 1)[0] == pytest.approx(1.0, abs=0.05)


def test_a1_cuts_on_at_thickness_shear_frequency():
    """A1 is absent below c_T/(2t); above, k^2 grows linearly from zero at the cut-off."""
    f_c = lamb.a1_cutoff_frequency(T, AL)
    assert f_c == pytest.approx(AL.shear_velocity / (2 * T), rel=1e-15)
    f = f_c * np.linspace(0.90, 1.02, 121)
    d = lamb.lamb_dispersion(T, AL, f)
    k = d.wavenumber["A1"]
    assert np.all(np.isnan(k[f < f_c]))
    near = (f > f_c * 1.001) & (f < f_c * 1.01)
    assert np.all(np.isfinite(k[near]))
    slope, intercept = np.polyfit(f[near], k[near] ** 2, 1)
    assert -intercept / slope == pytest.approx(f_c, rel=1e-4)
    # Phase velocity rises without bound and group velocity falls to zero at the cut-off.
    first = np.flatnonzero(np.isfinite(k))[0]
    assert d.phase_velocity["A1"][first] > 10 * AL.longitudinal_velocity
    assert d.group_velocity["A1"][first] < 0.2 * AL.shear_velocity


def test_high_frequency_a0_and_s0_approach_rayleigh_speed():
    """A0 rises and S0 falls to c_R (their gap closes exponentially in k h); A1 falls to c_T."""
    c_r = lamb.rayleigh_velocity(AL)
    f = np.linspace(1e6, 12e6, 60)
    d = lamb.lamb_dispersion(T, AL, f)
    a0, s0 = d.phase_velocity["A0"], d.phase_velocity["S0"]
    assert np.all(a0 < c_r * (1 + 1e-12)) and np.all(s0 > c_r * (1 - 1e-12))
    gap = s0 - a0
    assert gap[0] > 10.0  # m/s, clearly apart at 1 MHz
    assert gap[-1] < 1e-6 * c_r
    assert a0[-1] == pytest.approx(c_r, rel=1e-9)
    assert s0[-1] == pytest.approx(c_r, rel=1e-9)
    assert d.phase_velocity["A1"][-1] == pytest.approx(AL.shear_velocity, rel=0.01)
    assert d.phase_velocity["A1"][-1] > AL.shear_velocity


def _residual_of_tangent_form(family, k, omega, h):
    """The textbook tangent form evaluated in complex arithmetic (p or q may be imaginary)."""
    p = np.sqrt(complex(omega**2 / AL.longitudinal_velocity**2 - k**2))
    q = np.sqrt(complex(omega**2 / AL.shear_velocity**2 - k**2))
    ratio = np.tan(q * h) / np.tan(p * h)
    if family == "S":
        rhs = -4 * k**2 * p * q / (k**2 - q**2) ** 2
    else:
        rhs = -((k**2 - q**2) ** 2) / (4 * k**2 * p * q)
    return abs(ratio - rhs) / max(abs(ratio), abs(rhs))


def test_traced_roots_satisfy_the_tangent_equations(fig9):
    d = fig9[T]
    h = T / 2
    for i in (3, 100, 250, 399):
        omega = 2 * np.pi * d.frequency_hz[i]
        for mode in lamb.MODES:
            k = d.wavenumber[mode][i]
            if np.isfinite(k):
                assert _residual_of_tangent_form(mode[0], k, omega, h) < 1e-7


def test_group_velocity_equals_slope_of_traced_branch(fig9):
    """Implicit dw/dk at each root agrees with differentiating the traced w(k) numerically."""
    d = fig9[T]
    omega = 2 * np.pi * d.frequency_hz
    for mode in lamb.MODES:
        k = d.wavenumber[mode]
        ok = np.isfinite(k)
        ok &= np.roll(ok, 1) & np.roll(ok, -1)
        ok[[0, -1]] = False
        slope = (omega[2:] - omega[:-2]) / (k[2:] - k[:-2])
        inner = ok[1:-1]
        # Central differences on a 7.5 kHz grid: O(dk^2) error, tiny except at the A1 cut-off.
        rel = np.abs(slope[inner] / d.group_velocity[mode][1:-1][inner] - 1)
        assert np.median(rel) < 1e-4


def test_branches_are_continuous_and_monotonic(fig9):
    """No branch jumps: A0 phase rises, S0 and A1 phase fall, with bounded log-log slopes.

    Between grid points d ln c / d ln f must stay in [0, 1/2] for A0 (its group velocity lies
    between c and 2 c) and in [-1.5, 0] for S0 (normal dispersion; the steepest drop is about
    -1.24 for Al); a jump to a neighbouring mode would break these on a 7.5 kHz grid.
    """
    for d in fig9.values():
        ln_f = np.log(d.frequency_hz)
        a0, s0, a1 = (d.phase_velocity[m] for m in ("A0", "S0", "A1"))
        slope_a0 = np.diff(np.log(a0)) / np.diff(ln_f)
        slope_s0 = np.diff(np.log(s0)) / np.diff(ln_f)
        assert np.all((slope_a0 > 0) & (slope_a0 <= 0.5))
        assert np.all((slope_s0 < 0) & (slope_s0 >= -1.5))
        a1 = a1[np.isfinite(a1)]
        assert a1.size > 10 and np.all(np.diff(a1) < 0)
        for m in lamb.MODES:
            g = d.group_velocity[m]
            assert np.all(g[np.isfinite(g)] > 0)
        assert np.all(a0 < lamb.rayleigh_velocity(AL))


def test_dispersion_depends_on_frequency_times_thickness(fig9):
    """The three plates fall on one curve against f t."""
    f = np.linspace(2e3, 1.5e6, 50)
    thin = lamb.lamb_dispersion(2.29e-3, AL, f)
    thick = lamb.lamb_dispersion(4.58e-3, AL, f / 2)
    for m in lamb.MODES:
        np.testing.assert_allclose(thin.phase_velocity[m], thick.phase_velocity[m], rtol=1e-9)


def test_result_does_not_depend_on_frequency_grid():
    """Coarse and fine grids give the same roots at common frequencies (no path dependence)."""
    coarse = lamb.lamb_dispersion(T, AL, np.linspace(5e4, 3e6, 60))
    fine = lamb.lamb_dispersion(T, AL, np.linspace(5e4, 3e6, 60 * 7 - 6))
    for m in lamb.MODES:
        np.testing.assert_allclose(coarse.phase_velocity[m], fine.phase_velocity[m][::7],
                                   rtol=1e-9)


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="frequencies"):
        lamb.lamb_dispersion(T, AL, [2e3, 1e3])
    with pytest.raises(ValueError, match="frequencies"):
        lamb.lamb_dispersion(T, AL, [0.0, 1e3])
    with pytest.raises(ValueError, match="thickness"):
        lamb.lamb_dispersion(0.0, AL, [1e3])


def test_tracing_refuses_a_branch_it_cannot_follow(monkeypatch):
    """If the root finder misses A0 at one frequency, tracing stops instead of taking A1."""
    real_roots = lamb._roots
    target = 2 * np.pi * 1.5e6 * (T / 2) / AL.shear_velocity

    def lossy(family, W, kappa, k_max, n):
        out = real_roots(family, W, kappa, k_max, n)
        return [r[1:] if family == "A" and abs(w - target) < 1e-12 else r
                for r, w in zip(out, W, strict=True)]

    monkeypatch.setattr(lamb, "_roots", lossy)
    with pytest.raises(SimulationError, match="lost a branch"):
        lamb.lamb_dispersion(T, AL, np.linspace(1.4e6, 1.6e6, 21))


def test_coarse_grid_is_walked_in_small_steps():
    """A coarse frequency grid is traced through internal substeps and gives the fine answer."""
    coarse = lamb.lamb_dispersion(T, AL, np.array([1e3, 1e6, 2e6, 3e6]))
    fine = lamb.lamb_dispersion(T, AL, np.concatenate([[1e3], np.linspace(1e4, 3e6, 300)]))
    for m in lamb.MODES:
        np.testing.assert_allclose(coarse.phase_velocity[m][1:], fine.phase_velocity[m][100::100],
                                   rtol=1e-9)
