"""simulate(): the result's contract, stopping rules, plate-model resolution, errors, batch."""

from __future__ import annotations

import math

import numpy as np
import pytest

from solitonde.model import tiers
from solitonde.model.batch import scene_grid, simulate_many
from solitonde.model.contact import hertz_sphere_flat
from solitonde.model.errors import SceneError, SimulationError
from solitonde.model.plan import auto_duration
from solitonde.model.scene import scene_from_dict
from solitonde.model.simulate import simulate
from solitonde.model.zener import predict


def test_result_contract_default_scene():
    """Default scene: auto -> infinite with a reason, float64 samples at the sample rate."""
    scene = scene_from_dict({})
    r = simulate(scene)
    assert r.plate_model == "infinite"
    assert "auto" in r.plate_model_reason
    assert r.samples.dtype == np.float64
    assert r.t0 == 0.0
    assert r.dt == pytest.approx(1.0 / scene.output.sample_rate, rel=1e-12)
    assert r.traces is None
    d = r.diagnostics
    assert d["status"] == "reflection_passed"
    assert d["steps"] > 0 and d["dt_s"] > 0 and d["wall_s"] > 0
    assert d["duration_s"] >= auto_duration(scene)
    # The reflection (and a tail behind it) lies inside the record.
    assert r.truth["reflected_time_s"] < 0.9 * r.time[-1]
    assert r.truth["incident_time_s"] < r.truth["bottom_peak_time_s"] < r.truth["reflected_time_s"]


def test_auto_duration_follows_theory():
    """The run stops a margin after theory's reflection, not after a fixed long time."""
    for thickness in (2.29e-3, 4.83e-3):
        scene = scene_from_dict({"plate": {"thickness": thickness}})
        p = predict(scene)
        incident = (scene.chain.sensor_index + 1) * scene.chain.diameter / p.solitary_wave_speed_m_s
        duration = simulate(scene).diagnostics["duration_s"]
        assert incident + p.tof_s < duration < incident + 2.0 * p.tof_s


def test_explicit_duration_and_traces():
    """An explicit duration gives duration_reached; traces have one row per sample."""
    scene = scene_from_dict({"output": {"duration": 2e-4, "traces": True, "sample_rate": 1e6}})
    r = simulate(scene)
    assert r.diagnostics["status"] == "duration_reached"
    assert r.samples.size == 201
    n = scene.chain.n_particles
    assert r.traces["u_m"].shape == (201, n + 1)
    assert r.traces["v_m_s"].shape == (201, n + 1)
    assert r.traces["contact_force_N"].shape == (201, n + 1)
    assert r.traces["plate_deflection_m"].shape == (201,)
    assert r.traces["v_m_s"][0, 0] == pytest.approx(scene.impact_velocity)


def test_rigid_wall_uses_sphere_material():
    """rigid: Hertz sphere-on-flat with the sphere material on both sides; halfspace: A_p."""
    scene = scene_from_dict({"effects": {"plate_model": "rigid"}})
    b = tiers.make_boundary(scene)
    steel = scene.sphere_material
    assert b.a_bottom == hertz_sphere_flat(scene.chain.diameter, steel, steel)
    assert b.a_bottom > scene.a_p
    half = tiers.make_boundary(scene.with_overrides({"effects.plate_model": "halfspace"}))
    assert half.a_bottom == scene.a_p


def test_truth_matches_sampled_trace():
    """The step-resolution truth agrees with the sampled trace to within one sample."""
    r = simulate(scene_from_dict({"output": {"sample_rate": 2e7}}))
    t, s = r.time, r.samples
    k = int(np.argmax(np.where(t < r.truth["bottom_peak_time_s"], s, -np.inf)))
    assert abs(t[k] - r.truth["incident_time_s"]) <= r.dt
    assert s[k] <= r.truth["incident_peak_N"] * (1 + 1e-9)
    assert s[k] == pytest.approx(r.truth["incident_peak_N"], rel=1e-4)


def test_step_budget_is_a_clear_error():
    """A duration needing more steps than the budget raises before running."""
    scene = scene_from_dict({"output": {"duration": 10.0}})
    with pytest.raises(SimulationError, match="step_budget_exceeded"):
        simulate(scene)
    with pytest.raises(SimulationError, match="budget"):
        simulate(scene_from_dict({}), max_steps=1000)


def test_unavailable_plate_model_is_a_scene_error(monkeypatch):
    """A plate model without a registered tier names the field and the available ones."""
    monkeypatch.delitem(tiers.TIERS, "halfspace")
    with pytest.raises(SceneError) as err:
        simulate(scene_from_dict({"effects": {"plate_model": "halfspace"}}))
    assert err.value.field == "effects.plate_model"
    assert "rigid" in str(err.value)


def test_dissipation_needs_a_coefficient():
    """dissipation on with damping 0 is refused, naming effects.damping."""
    with pytest.raises(SceneError) as err:
        scene_from_dict({"effects": {"dissipation": True}})
    assert err.value.field == "effects.damping"


def test_batch_matches_serial_in_order():
    """simulate_many over 2 workers returns the same results, in input order, as simulate."""
    scenes = scene_grid(None, {"chain.diameter": [4.76e-3, 9.53e-3],
                               "plate.thickness": [2.29e-3, 4.83e-3]})
    assert [s.chain.diameter for s in scenes] == [4.76e-3] * 2 + [9.53e-3] * 2
    many = simulate_many(scenes, workers=2, chunk_size=1)
    for scene, result in zip(scenes, many, strict=True):
        one = simulate(scene)
        np.testing.assert_array_equal(result.samples, one.samples)
        assert result.truth == one.truth


def test_batch_collects_errors_when_asked():
    """raise_errors=False keeps going and puts the exception in the failed scene's slot."""
    scenes = [scene_from_dict({}), scene_from_dict({"output": {"duration": 10.0}})]
    out = simulate_many(scenes, workers=1, raise_errors=False)
    assert math.isfinite(out[0].truth["arr"])
    assert isinstance(out[1], SimulationError)
    with pytest.raises(SimulationError):
        simulate_many(scenes, workers=1)
    with pytest.raises(SceneError):
        scene_grid(None, {"plate.thickness": 3e-3})


def test_batch_collects_a_scene_error_over_processes():
    """One scene failing with a SceneError in a worker process fills its own slot, field intact.

    A SceneError could not be unpickled (its three-argument __init__), so the process pool broke
    and every result of the batch was lost.
    """
    good = scene_from_dict({"effects": {"plate_model": "infinite"}})
    bad = scene_from_dict({"effects": {"plate_model": "sem"}, "solver": {"integrator": "dopri5"}})
    out = simulate_many([good, bad, good], workers=2, chunk_size=1, raise_errors=False,
                        backend="processes")
    assert isinstance(out[1], SceneError)
    assert out[1].field == "solver.integrator"
    assert "dopri5" in str(out[1])
    np.testing.assert_array_equal(out[0].samples, out[2].samples)
    assert out[0].scene is good and out[2].scene is good
    with pytest.raises(SceneError):
        simulate_many([good, bad], workers=2, chunk_size=1, backend="processes")


def test_batch_refuses_a_chunk_size_below_one() -> None:
    """A non-positive chunk size is named (it ended in the process pool's own max_workers
    error)."""
    with pytest.raises(ValueError, match="chunk_size must be >= 1"):
        simulate_many([scene_from_dict({})] * 2, workers=2, chunk_size=-1, backend="processes")
