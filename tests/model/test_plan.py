"""model.plan: the run simulate() carries out is the one the service prices, and nothing above
model/ re-derives a step or builds a plate to look inside it."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

from solitonde.instrument.service.routes_compute import simulation_cost
from solitonde.model.errors import SimulationError
from solitonde.model.plan import plan
from solitonde.model.scene import scene_from_dict
from solitonde.model.simulate import simulate

INSTRUMENT = Path(__file__).resolve().parents[2] / "instrument"
SMALL_SEM = {"elements": [2, 2, 1], "order": [2, 2, 1], "contact_refinement": 0}


@pytest.mark.parametrize("scene", [
    {"effects": {"plate_model": "infinite"}},
    {"effects": {"plate_model": "rigid"}, "output": {"duration": 3e-4, "sample_rate": 1e6}},
    {"effects": {"plate_model": "infinite"}, "solver": {"integrator": "dopri5"}},
    {"effects": {"plate_model": "sem"}, "sem": SMALL_SEM, "plate": {"thickness": 4.83e-3},
     "output": {"duration": 2e-4}},
])
def test_simulate_runs_the_plan(scene: dict) -> None:
    s = scene_from_dict(scene)
    p = plan(s)
    d = simulate(s).diagnostics
    assert d["duration_s"] == pytest.approx(p.interval_s * (p.n_samples - 1), rel=1e-12)
    assert p.duration_s * (1 - 1e-12) <= d["duration_s"] < p.duration_s + p.interval_s
    if p.integrator == "verlet":
        assert d["steps"] == p.chain_steps
        assert d.get("plate_steps", 0) == p.plate_steps
        if not p.plate_steps:
            assert d["dt_s"] == p.dt_s
    else:
        assert d["steps"] < p.chain_steps  # adaptive: verlet's count bounds it above
    assert simulation_cost(s) == p.cost_dict()


def test_the_price_of_an_absurd_mesh_is_a_floor_without_building_it() -> None:
    s = scene_from_dict({"effects": {"plate_model": "sem"},
                         "sem": {"elements": [400, 400, 8], "order": [6, 6, 4]}})
    p = plan(s, budget=1e9)
    assert p.estimate.startswith("floor") and p.cost > 1e9 and math.isnan(p.dt_s)


@pytest.mark.parametrize("duration, rate", [(1e300, 1e9), (1e302, 1e6), (1e12, 1e6)])
def test_a_duration_too_long_to_count_is_refused(duration: float, rate: float) -> None:
    """Sample counts that overflow (1e309), that a float cannot hold as a step count times the
    sub-steps (1e308), or that are merely absurd (1e18) are a SimulationError, never an
    OverflowError: the service answers 422, the command line an error line."""
    s = scene_from_dict({"effects": {"plate_model": "infinite"},
                         "output": {"duration": duration, "sample_rate": rate}})
    with pytest.raises(SimulationError, match="step_budget_exceeded"):
        plan(s, budget=5e8)
    with pytest.raises(SimulationError, match="step_budget_exceeded"):
        simulate(s)


def test_nothing_above_model_plans_a_run_itself() -> None:
    pattern = re.compile(r"\b(choose_time_step|auto_duration|make_boundary|n_dofs)\b")
    found = {str(p.relative_to(INSTRUMENT)) for p in INSTRUMENT.rglob("*.py")
             if pattern.search(p.read_text())}
    assert found == set(), found
