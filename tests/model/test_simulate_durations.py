"""simulate(): auto durations of the static plate tiers, and what a record too long to run says."""

from __future__ import annotations

import pytest

from solitonde.model.plan import auto_duration
from solitonde.model.scene import scene_from_dict
from solitonde.model.simulate import simulate


@pytest.mark.parametrize("plate_model", ["rigid", "halfspace"])
def test_wall_duration_ignores_plate_thickness(plate_model: str) -> None:
    """A wall's auto duration came from Zener's infinite plate of the scene's thickness: 0.42 s
    instead of 1 ms for a 0.1 mm plate, and a step-budget error at 30 um. The wall's reflection
    does not depend on the thickness, nor now its duration, and it lies inside the record."""
    durations = []
    for thickness in (3.18e-3, 3e-5):
        scene = scene_from_dict({"plate": {"thickness": thickness},
                                 "effects": {"plate_model": plate_model}})
        r = simulate(scene)
        duration = r.diagnostics["duration_s"]
        assert duration == pytest.approx(auto_duration(scene), rel=1e-9, abs=r.dt)
        assert r.truth["reflected_time_s"] < 0.9 * duration
        assert 0.9 < r.truth["arr"] <= 1.0
        durations.append(duration)
    assert durations[0] == durations[1] < 1.5e-3


def test_a_rate_too_low_to_sample_a_pulse_is_a_scene_error_and_a_long_record_says_shorten():
    """Below 1 kHz (a sample per millisecond, ten times a solitary pulse's width) the scene is
    refused naming output.sample_rate: at 0.001 Hz one sample interval ran for 1000 s of
    simulated time. A long record at a fine rate says to shorten it or lower the rate."""
    from solitonde.model.errors import SceneError, SimulationError

    with pytest.raises(SceneError, match=r"output.sample_rate: must be >= 1000"):
        scene_from_dict({"output": {"sample_rate": 1e-3}})
    with pytest.raises(SimulationError, match=r"shorten output.duration, lower output.sample_rate"):
        simulate(scene_from_dict({"output": {"sample_rate": 1e9, "duration": 1.0}}))


def test_auto_record_without_a_found_reflection_does_not_claim_to_pass_it() -> None:
    """At the 100 m/s limit the simulated reflection (ARR ~0.01) comes far later than Zener's
    estimate that sizes an auto record: the truth has no reflection, and the status says so
    instead of ``reflection_passed``."""
    r = simulate(scene_from_dict({"striker": {"velocity": 100.0}}))
    assert r.truth["tof_s"] != r.truth["tof_s"]  # NaN: not in the record
    assert r.diagnostics["status"] == "reflection_not_found"
    ok = simulate(scene_from_dict({"striker": {"velocity": 1.0}}))
    assert ok.diagnostics["status"] == "reflection_passed" and ok.truth["arr"] > 0.1
