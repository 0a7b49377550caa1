"""Review findings on simulate(): the auto duration of the static plate tiers."""

from __future__ import annotations

import pytest

from solitonde.model.scene import scene_from_dict
from solitonde.model.simulate import auto_duration, simulate


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
