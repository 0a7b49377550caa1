"""Review findings on the spectral-element tiers: a mesh that cannot hold the chain's node."""

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
