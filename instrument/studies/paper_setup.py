"""The paper's set-up (its plates, sphere sizes and positions) and how much of it a reproduction
computes (:class:`Plan`): the full sweep or the coarse ``--quick`` one."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TypedDict

from solitonde.model.scene import Scene, SceneDict, scene_from_dict

PLATES_M = (2.29e-3, 3.18e-3, 4.83e-3)
"""The paper's three Al 6061 plates."""
DIAMETERS_M = (4.76e-3, 9.53e-3, 19.05e-3)
"""The paper's three sphere sizes (3/16, 3/8, 3/4 in)."""
TRACE_DIAMETER_M = 9.53e-3
THICK_PLATE_M = 9.52e-3
"""Fig. 3's thick plate (paper: t = 9.52 mm, D/t = 1)."""
CENTRE_M = 0.457
COLLAPSE_D_OVER_T = (1.0, 2.0, 3.0, 4.0)
"""D/t values at which every sphere size is run for the collapse check (reflection detectable)."""


class SemSettings(TypedDict):
    """The plate's contact model and mesh, as the scene's ``sem`` section takes them."""

    preset: str
    elements: list[int]
    order: list[int]


@dataclass(frozen=True)
class Plan:
    """How much to compute: the mesh, the distances and sphere sizes swept, curve resolutions."""

    quick: bool
    elements: tuple[int, int, int]
    order: tuple[int, int, int]
    distances_m: tuple[float, ...]
    sweep_diameters_m: tuple[float, ...]
    theory_points: int
    lamb_points: int
    notes: list[str] = field(default_factory=list)
    preset: str = "resolved"

    def sem(self) -> SemSettings:
        """The plate's mesh settings (the scene's ``sem`` section) of the distance sweep."""
        # Default: the converged contact patch ('resolved', the product's default plate model).
        # 'paper' is the paper's single-node load on the same element grid: 4-7x cheaper, but its
        # ARR has no mesh limit and its far-field TOF scatters on the thin plate.
        return {"preset": self.preset, "elements": list(self.elements), "order": list(self.order)}



def make_plan(quick: bool, preset: str = "resolved") -> Plan:
    """The full reproduction or its coarse ``--quick`` version (CI).

    Full: the paper's 16 x 16 x 1 element grid of order 4 x 4 x 2 (with ``preset='resolved'`` the
    contact patch of radius t and its local refinement on top; ``'paper'``: the paper's
    single-node load on that grid), 11 distances from 0 to the centre, all three sphere sizes.
    Quick: a coarse 8 x 8 x 1 grid of order 3 x 3 x 2, 7 distances, D = 9.53 mm only; the
    near-support trends survive but the numbers are not converged.
    """
    if quick:
        return Plan(
            quick=True, elements=(8, 8, 1), order=(3, 3, 2),
            distances_m=(0.0, 0.01, 0.02, 0.04, 0.08, 0.15, CENTRE_M),
            sweep_diameters_m=(9.53e-3,), theory_points=60, lamb_points=120,
            notes=["quick: coarse 8 x 8 x 1 mesh of order 3 x 3 x 2; numbers are not converged"],
            preset=preset,
        )
    return Plan(
        quick=False, elements=(16, 16, 1), order=(4, 4, 2),
        distances_m=(0.0, 0.01, 0.02, 0.03, 0.05, 0.075, 0.1, 0.15, 0.2, 0.3, CENTRE_M),
        sweep_diameters_m=DIAMETERS_M, theory_points=200, lamb_points=400, preset=preset,
    )


def scene_for(diameter: float, thickness: float, distance: float = CENTRE_M,
              plate_model: str = "auto", sem: SemSettings | None = None) -> Scene:
    """The paper's scene with the given sphere, plate, position and plate model."""
    data: SceneDict = {
        "chain": {"diameter": diameter},
        "plate": {"thickness": thickness, "distance_to_support": distance},
        "effects": {"plate_model": plate_model},
    }
    if sem:
        data["sem"] = dict(sem)
    return scene_from_dict(data)
