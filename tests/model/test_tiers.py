"""The plate-model registry: every name the scene accepts has a tier, capabilities are attributes,
and the name lists other modules use are asked of it (issue 30, item 4)."""

from __future__ import annotations

import typing

from solitonde.instrument.tables.table import PLATE_MODEL_NAMES
from solitonde.model.scene import PLATE_MODELS, EffectsSpec
from solitonde.model.tiers import (
    CONVOLVED_PLATE_MODELS,
    DOPRI5_PLATE_MODELS,
    MESHED_PLATE_MODELS,
    STATIC_PLATE_MODELS,
    TIERS,
    names_with,
)


def test_every_plate_model_the_scene_accepts_has_a_tier() -> None:
    assert set(TIERS) == set(PLATE_MODELS) - {"auto"}
    literal = typing.get_args(EffectsSpec.model_fields["plate_model"].annotation)
    assert literal == PLATE_MODELS
    assert PLATE_MODEL_NAMES[:-1] == tuple(m for m in PLATE_MODELS if m != "auto")


def test_capabilities_are_attributes_and_the_lists_follow_them() -> None:
    assert STATIC_PLATE_MODELS == ("rigid", "halfspace")
    assert DOPRI5_PLATE_MODELS == ("rigid", "halfspace", "infinite")
    assert MESHED_PLATE_MODELS == ("sem", "greens", "mindlin", "mindlin_greens")
    assert CONVOLVED_PLATE_MODELS == ("greens", "mindlin_greens")
    assert names_with(meshed=True, convolved=False) == ("sem", "mindlin")
    for name, tier in TIERS.items():
        assert tier.name == name
        assert not (tier.static and tier.meshed)
        assert not tier.convolved or tier.meshed
