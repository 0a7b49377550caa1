"""The chain's bottom boundary: one interface (:mod:`.base`), several plate models ("tiers"),
the ODE ones in :mod:`.dashpot` (rigid, halfspace, Zener's infinite plate) and the meshed ones in
:mod:`.meshed` (3-D spectral elements and Mindlin, stepped or as a cached Green's function),
listed with their capabilities in :mod:`.registry`, which also decides ``auto``."""

from .base import BottomBoundary, ChainRun, StepPlan, Tier
from .registry import (
    CONVOLVED_PLATE_MODELS,
    DOPRI5_PLATE_MODELS,
    MESHED_PLATE_MODELS,
    STATIC_PLATE_MODELS,
    TIERS,
    make_boundary,
    names_with,
    nearest_edge_distance,
    resolve_plate_model,
)

__all__ = [
    "CONVOLVED_PLATE_MODELS",
    "DOPRI5_PLATE_MODELS",
    "MESHED_PLATE_MODELS",
    "STATIC_PLATE_MODELS",
    "TIERS",
    "BottomBoundary",
    "ChainRun",
    "StepPlan",
    "Tier",
    "make_boundary",
    "names_with",
    "nearest_edge_distance",
    "resolve_plate_model",
]
