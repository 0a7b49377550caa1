"""POST /v1/simulate limits: pricing of the greens convolution, no per-particle traces."""

from __future__ import annotations

from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from solitonde.instrument.service.app import build_app
from solitonde.instrument.service.routes_compute import simulation_cost
from solitonde.instrument.service.settings import Settings
from solitonde.model.scene import scene_from_dict

# A coarse greens plate whose plate step is far below the sample interval, so that plate steps
# equal samples: 4e5 of them took 39 s of convolution (quadratic in the steps) while the old
# price, linear in the steps, was 6.6e7 (an eighth of the default budget).
LONG_GREENS = {
    "effects": {"plate_model": "greens"},
    "plate": {"distance_to_support": 0.3},
    "sem": {"elements": [2, 2, 1], "order": [1, 1, 1], "contact_refinement": 0},
    "output": {"sample_rate": 1e8, "duration": 4e-3},
}


def test_greens_price_counts_the_quadratic_convolution() -> None:
    """The greens convolution (plate_steps^2 / 2 multiply-adds) is priced: a long run on a tiny
    mesh is above the default budget, and the price grows fourfold when the run doubles."""
    budget = Settings().max_simulation_cost
    cost = simulation_cost(scene_from_dict(LONG_GREENS), budget)
    assert cost["plate_model"] == "greens" and cost["steps"] == 400_000
    assert cost["cost"] > budget
    short = scene_from_dict({**LONG_GREENS, "output": {"sample_rate": 1e8, "duration": 1e-3}})
    half = scene_from_dict({**LONG_GREENS, "output": {"sample_rate": 1e8, "duration": 2e-3}})
    c1, c2 = simulation_cost(short)["cost"], simulation_cost(half)["cost"]
    assert c2 / c1 == pytest.approx(4.0, rel=0.1)


def test_simulate_service_never_records_particle_traces(tmp_path: Path, monkeypatch) -> None:
    """output.traces is dropped by the service (it returns the sensor trace only): traces cost
    3 x samples x particles floats, gigabytes for a scene within the cost budget."""
    import solitonde.model.simulate as sim

    seen = []
    original = sim.simulate

    def spy(scene, **kwargs):
        seen.append((scene.effects.plate_model, scene.output.traces))
        return original(scene, **kwargs)

    monkeypatch.setattr(sim, "simulate", spy)
    scene = {"effects": {"plate_model": "halfspace"}, "output": {"traces": True}}
    with TestClient(build_app(Settings(store_path=tmp_path / "s.sqlite"))) as client:
        r = client.post("/v1/simulate", json={"scene": scene, "include_trace": False})
    assert r.status_code == 200, r.text
    # the request's scene, and the reference runs the extraction makes for itself (the chain's
    # relaxation on a rigid plate, cached per process: absent when an earlier test made them),
    # all without traces
    assert ("halfspace", False) in seen and not any(traces for _, traces in seen)


@pytest.mark.parametrize("sem", [
    {},  # the default mesh
    {"elements": [8, 8, 1], "order": [2, 2, 1], "contact_refinement": 0},
    {"elements": [2, 2, 2], "order": [5, 5, 3], "contact_refinement": 0},
])
@pytest.mark.parametrize("plate", [{"thickness": 3.18e-3}, {"thickness": 6e-3}])
@pytest.mark.parametrize("model", ["sem", "mindlin"])
def test_plate_step_floor_is_below_the_real_step_count(sem: dict, plate: dict,
                                                      model: str) -> None:
    """The floor priced before any mesh is built never exceeds the step count of the built
    mesh (else a feasible request would be refused), for either plate theory."""
    from solitonde.model.plan import _plate_steps_floor

    scene = scene_from_dict({"effects": {"plate_model": model}, "sem": sem,
                             "plate": {**plate, "distance_to_support": 0.05},
                             "output": {"sample_rate": 1e3, "duration": 2e-4}})
    real = simulation_cost(scene)["steps"]
    assert 1 <= _plate_steps_floor(scene, 2e-4, model) <= real


def test_a_huge_mesh_at_a_low_sample_rate_is_refused_before_it_is_built(monkeypatch) -> None:
    """[512, 512, 1] elements (19 million degrees of freedom, 1.1 GB and 4 s to build) at 1 kHz:
    one plate step per sample priced it under the budget, so the mesh was built to be refused."""
    from solitonde.model import plan, tiers
    from solitonde.model.tiers import meshed

    def refuse(*args, **kwargs):
        raise AssertionError("the plate mesh was built")

    for module in (plan, tiers, meshed):  # wherever a boundary or a plate could be made
        monkeypatch.setattr(module, "make_boundary" if module is not meshed else "plate_for",
                            refuse)
    scene = scene_from_dict({"effects": {"plate_model": "sem"},
                             "sem": {"elements": [512, 512, 1]},
                             "output": {"sample_rate": 1000.0}})
    budget = Settings().max_simulation_cost
    cost = simulation_cost(scene, budget)
    assert cost["cost"] > budget and cost["estimate"].startswith("floor")
