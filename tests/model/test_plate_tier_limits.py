"""Spectral-element tiers at their limits: a mesh that cannot hold the chain's node, a bounded
response cache."""

from __future__ import annotations

import pytest

from solitonde.model.errors import SceneError
from solitonde.model.scene import scene_from_dict
from solitonde.model.simulate import simulate


@pytest.mark.parametrize("plate_model", ["sem", "greens"])
def test_mesh_without_a_node_under_the_chain_is_a_scene_error(plate_model: str) -> None:
    """One first-order element along x has nodes at the ends only: the chain at 0.3 m was a bare
    ValueError (HTTP 500 from /v1/simulate); now a SceneError naming sem.elements."""
    scene = scene_from_dict({
        "effects": {"plate_model": plate_model}, "plate": {"distance_to_support": 0.3},
        "sem": {"elements": [1, 1, 1], "order": [1, 1, 1], "contact_refinement": 0},
    })
    with pytest.raises(SceneError, match="GLL node") as info:
        simulate(scene)
    assert info.value.field == "sem.elements"


def test_memory_cache_of_plate_responses_is_bounded() -> None:
    """The process-wide response cache kept every response forever (a service fed distinct
    greens scenes grew by up to 16 MB a request); it now drops the least recently used ones
    beyond its byte bound and keeps the one just used."""
    import numpy as np

    from solitonde.model.greens import MemoryCache

    cache = MemoryCache(max_bytes=3 * 8000)
    for i in range(3):
        cache.store(f"k{i}", np.full(1000, float(i)))
    assert cache.load("k0") is not None  # k0 is now the most recently used
    cache.store("k3", np.zeros(1000))
    assert cache.load("k1") is None
    assert all(cache.load(k) is not None for k in ("k0", "k2", "k3"))
    cache.store("big", np.zeros(10_000))  # larger than the bound alone: kept, the rest dropped
    assert cache.load("big") is not None and cache.load("k3") is None
