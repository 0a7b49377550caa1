"""POST /v1/simulate limits: pricing of the greens convolution, no per-particle traces."""

from __future__ import annotations

from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from solitonde.instrument.app import build_app
from solitonde.instrument.routes_compute import simulation_cost
from solitonde.instrument.settings import Settings
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
        seen.append(scene.output.traces)
        return original(scene, **kwargs)

    monkeypatch.setattr(sim, "simulate", spy)
    scene = {"effects": {"plate_model": "halfspace"}, "output": {"traces": True}}
    with TestClient(build_app(Settings(store_path=tmp_path / "s.sqlite"))) as client:
        r = client.post("/v1/simulate", json={"scene": scene, "include_trace": False})
    assert r.status_code == 200, r.text
    assert seen == [False]
