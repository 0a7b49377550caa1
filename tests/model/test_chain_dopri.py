"""The adaptive Dormand-Prince chain driver (``solver.integrator: dopri5``) against velocity
Verlet, analytic limits, conservation and its own convergence in rtol."""

from __future__ import annotations

import numpy as np
import pytest
from chain_checks import check_chatterjee, check_nesterenko

from solitonde.model.errors import SceneError, SimulationError
from solitonde.model.scene import STANDARD_GRAVITY, scene_from_dict
from solitonde.model.simulate import simulate

INFINITE = {"effects": {"plate_model": "infinite"}}


def _dopri(data: dict, rtol: float, **options) -> object:
    scene = scene_from_dict({**data, "solver": {"integrator": "dopri5", "rtol": rtol}})
    return simulate(scene, **options)


@pytest.fixture(scope="module")
def verlet_fine():
    """The default scene on the infinite plate with Verlet at 4x the default steps per period
    (its peaks converge as dt^2: about 1e-8 relative off)."""
    return simulate(scene_from_dict(INFINITE), steps_per_period=6400)


@pytest.fixture(scope="module")
def dopri_reference():
    """The same scene with dopri5 at rtol 1e-12, the reference of the convergence test."""
    return _dopri(INFINITE, 1e-12)


def test_default_is_verlet_and_diagnostics():
    """Scenes default to Verlet; a dopri5 run reports its integrator, rtol and step counts."""
    scene = scene_from_dict({})
    assert scene.solver.integrator == "verlet"
    r = _dopri(INFINITE, 1e-6)
    d = r.diagnostics
    assert d["integrator"] == "dopri5" and d["rtol"] == 1e-6
    assert d["steps"] == d["steps_accepted"] > 10
    assert d["rhs_evaluations"] == 6 * (d["steps_accepted"] + d["steps_rejected"]) + 2
    assert r.samples.shape == r.energy.shape and r.traces is None
    assert r.dt == pytest.approx(0.5e-6) and r.samples.size > 1000


@pytest.mark.parametrize("rtol", [1e-7, 1e-9])
def test_peaks_and_trace_match_fine_verlet(verlet_fine, rtol):
    """Peaks, their times and the sampled trace agree with fine Verlet within C x rtol.

    The global error of a tolerance-proportional method is the per-step tolerance times an
    amplification of order the number of steps (hundreds here): peaks within 300 rtol (plus the
    Verlet reference's own 1e-7), peak times within 300 rtol of the TOF, the whole trace within
    1000 rtol of its maximum (steep fronts turn a small time error into a larger force error).
    """
    r = _dopri(INFINITE, rtol)
    ref = verlet_fine
    tof = ref.truth["tof_s"]
    for key in ("incident", "reflected"):
        assert r.truth[f"{key}_peak_N"] == pytest.approx(ref.truth[f"{key}_peak_N"],
                                                         rel=300 * rtol + 1e-7)
        assert abs(r.truth[f"{key}_time_s"] - ref.truth[f"{key}_time_s"]) < 300 * rtol * tof
    assert r.truth["arr"] == pytest.approx(ref.truth["arr"], rel=300 * rtol + 1e-7)
    err = np.abs(r.samples - ref.samples).max() / ref.samples.max()
    assert err < 1000 * rtol + 1e-6


def test_error_falls_with_rtol(dopri_reference):
    """Trace error and energy drift fall steadily as rtol falls (fitted exponents 0.5..1.2)."""
    rtols = np.array([1e-5, 1e-6, 1e-7, 1e-8, 1e-9])
    errors, drifts = [], []
    for rtol in rtols:
        r = _dopri(INFINITE, rtol)
        errors.append(np.abs(r.samples - dopri_reference.samples).max()
                      / dopri_reference.samples.max())
        drifts.append(r.diagnostics["energy_drift"])
    assert np.all(np.diff(errors) < 0)
    for values in (errors, drifts):
        slope = np.polyfit(np.log(rtols), np.log(values), 1)[0]
        assert 0.5 < slope < 1.2
    assert drifts[-1] < 1e-6


@pytest.mark.parametrize("plate_model", ["rigid", "halfspace", "infinite"])
@pytest.mark.parametrize("gravity", [False, True])
def test_each_tier_conserves_and_matches_verlet(plate_model, gravity):
    """Every ODE tier: drift below 5e-6 at rtol 1e-9 and 10x below that at 1e-6; plate work and
    ARR as Verlet's (default step) within 1e-5."""
    data = {"effects": {"plate_model": plate_model, "gravity": gravity}}
    verlet = simulate(scene_from_dict(data))
    fine = _dopri(data, 1e-9)
    coarse = _dopri(data, 1e-6)
    assert fine.diagnostics["energy_drift"] < 5e-6
    assert fine.diagnostics["energy_drift"] < coarse.diagnostics["energy_drift"] / 10
    assert fine.plate_model == plate_model
    assert fine.truth["arr"] == pytest.approx(verlet.truth["arr"], rel=1e-5)
    if plate_model == "infinite":
        assert fine.diagnostics["plate_work_J"] == pytest.approx(
            verlet.diagnostics["plate_work_J"], rel=1e-5)
    else:
        assert fine.diagnostics["plate_work_J"] == 0.0


@pytest.fixture(scope="module")
def long_chain_dopri():
    """test_chain_physics's long chain (100 particles on a wall, traces at 20 MHz), dopri5."""
    scene = scene_from_dict({
        "chain": {"n_particles": 100, "sensor_index": 50},
        "effects": {"plate_model": "rigid", "gravity": False},
        "output": {"duration": 1.7e-3, "traces": True, "sample_rate": 2e7},
        "solver": {"integrator": "dopri5", "rtol": 1e-8},
    })
    return simulate(scene)


def test_chatterjee_peak_velocity(long_chain_dopri):
    """Peak particle velocity 0.682 v_imp, the same on every particle (test_chain_physics)."""
    check_chatterjee(long_chain_dopri)


def test_nesterenko_speed_and_width(long_chain_dopri):
    """Nesterenko's speed within 2 %, width about five diameters (test_chain_physics)."""
    check_nesterenko(long_chain_dopri)


def test_dissipation_matches_verlet():
    """Kuwabara-Kono damping: dissipated energy and ARR as Verlet's; the balance still closes."""
    data = {"effects": {"plate_model": "halfspace", "dissipation": True, "damping": 2e-6}}
    verlet = simulate(scene_from_dict(data))
    r = _dopri(data, 1e-9)
    assert r.diagnostics["dissipated_J"] > 0.0
    assert r.diagnostics["dissipated_J"] == pytest.approx(verlet.diagnostics["dissipated_J"],
                                                          rel=1e-5)
    assert r.truth["arr"] == pytest.approx(verlet.truth["arr"], rel=1e-5)
    assert r.diagnostics["energy_drift"] < 5e-6


def test_traces_and_sensor_definition():
    """Traces come from the dense output: sensor = mean of its two contacts at every sample, and
    the plate follows the dashpot law."""
    r = _dopri({**INFINITE, "output": {"traces": True}}, 1e-8)
    f = r.traces["contact_force_N"]
    s = r.scene.chain.sensor_index
    np.testing.assert_allclose(r.samples, 0.5 * (f[:, s - 1] + f[:, s]), rtol=0, atol=1e-12)
    assert r.traces["u_m"].shape == (r.samples.size, r.scene.chain.n_particles + 1)
    # The dashpot law w' = (F_b - N m g) / Z, read off the sampled plate deflection.
    w = r.traces["plate_deflection_m"]
    law = (f[1:-1, -1] - r.scene.chain.n_particles * r.scene.sphere_mass * STANDARD_GRAVITY) \
        / r.scene.plate_impedance
    w_dot = (w[2:] - w[:-2]) / (2 * r.dt)
    assert np.max(np.abs(w_dot - law)) < 1e-3 * np.max(np.abs(law))


@pytest.mark.parametrize("rtol", [0.0, -1e-6, 0.5, "tight"])
def test_bad_rtol_is_refused(rtol):
    """rtol outside 1e-12..1e-2 is a SceneError naming solver.rtol."""
    with pytest.raises(SceneError) as info:
        scene_from_dict({"solver": {"integrator": "dopri5", "rtol": rtol}})
    assert info.value.field == "solver.rtol"


def test_unknown_integrator_is_refused():
    with pytest.raises(SceneError) as info:
        scene_from_dict({"solver": {"integrator": "rk4"}})
    assert info.value.field == "solver.integrator"
    assert "dopri5" in str(info.value)


@pytest.mark.parametrize("plate_model", ["sem", "greens"])
def test_plate_tiers_without_dopri5_are_refused(plate_model):
    """sem and greens step the plate with the chain: dopri5 cannot run them, and says so."""
    scene = scene_from_dict({"effects": {"plate_model": plate_model},
                             "solver": {"integrator": "dopri5"}})
    with pytest.raises(SceneError) as info:
        simulate(scene)
    assert info.value.field == "solver.integrator"
    assert plate_model in str(info.value) and "rigid, halfspace, infinite" in str(info.value)


def test_step_budget_is_reported():
    with pytest.raises(SimulationError, match="step_budget_exceeded"):
        _dopri(INFINITE, 1e-8, max_steps=20)


def test_energy_is_interpolated_between_step_ends():
    """The balance comes from the integrator's state at step ends and is linear in time between
    them: second differences of the sampled balance vanish (to rounding) except at the two
    samples around each step end. The drift is measured at the step ends, so it bounds every
    sampled deviation, and the last sample (the last step end) gives the final error."""
    r = _dopri(INFINITE, 1e-5)
    d = r.diagnostics
    scale = d["energy_scale_J"]
    assert r.energy.size > 10 * d["steps_accepted"]  # many samples per step: the check bites
    kinks = np.abs(np.diff(r.energy, 2)) > 1e-12 * scale
    assert np.count_nonzero(kinks) <= 2 * d["steps_accepted"]
    deviation = np.abs(r.energy - r.energy[0]) / scale
    assert d["energy_drift"] >= deviation.max() * (1 - 1e-12)  # lerp rounding at a maximum
    assert d["energy_drift"] == pytest.approx(deviation.max(), rel=0.1)  # samples near step ends
    assert d["energy_error_final"] == deviation[-1]


@pytest.mark.parametrize("data", [
    INFINITE,
    {"effects": {"plate_model": "halfspace", "dissipation": True, "damping": 2e-6}},
    {"chain": {"n_particles": 12, "sensor_index": 12},
     "effects": {"plate_model": "rigid", "dissipation": True, "damping": 2e-6}},
], ids=["infinite", "damped", "sensor-at-bottom"])
def test_sensor_only_sampling_matches_traces(data):
    """Without traces a sample evaluates only the sensor's neighbours, u[N] and w (and their
    velocities when damped); with traces every particle. Readings, peaks, the energy balance and
    the drift are the same either way, to rounding.

    Readings and balance are compared to 1e-11 of their scale, five decades below the drift
    the integrator itself makes here (5e-6): the two runs are bit-equal on most machines, but
    one CI machine gave a 2e-13 relative difference in the balance, which is rounding in the
    state, not a change of the solve."""
    off = _dopri(data, 1e-7)
    on = _dopri({**data, "output": {"traces": True}}, 1e-7)
    np.testing.assert_allclose(off.samples, on.samples, rtol=0, atol=1e-11 * on.samples.max())
    scale = on.diagnostics["energy_scale_J"]
    np.testing.assert_allclose(off.energy, on.energy, rtol=0, atol=1e-11 * scale)
    assert off.diagnostics["energy_drift"] == pytest.approx(on.diagnostics["energy_drift"],
                                                            rel=0, abs=1e-11)
    for key in ("incident_peak_N", "reflected_peak_N", "bottom_peak_N", "incident_time_s"):
        assert off.truth[key] == pytest.approx(on.truth[key], rel=1e-9, nan_ok=True)
