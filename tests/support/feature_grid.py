"""The scenes of issue 17's grid, shared by the clean-trace and the noise tests: D 4.76, 9.53,
19.05 mm x D/t 0.5, 1.5, 3, 4 x gravity on and off on Zener's infinite plate (sampled at 1, 2, 5
and 10 MHz in rotation), and the greens tier near a clamped support."""

from __future__ import annotations

from typing import Any

from solitonde.model.scene import Scene, scene_from_dict

DIAMETERS = (4.76e-3, 9.53e-3, 19.05e-3)
D_OVER_T = (0.5, 1.5, 3.0, 4.0)
RATES = (1e6, 2e6, 5e6, 10e6)
COARSE = {"elements": [8, 8, 1], "order": [4, 4, 2], "contact_refinement": 0}
GREENS = (  # thickness, distance to the support, gravity, sample rate
    (2.29e-3, 0.02, True, 5e6),
    (3.18e-3, 0.03, False, 2e6),
    (4.83e-3, 0.01, True, 1e6),
)


def grid_scenes(output: dict[str, Any] | None = None) -> list[Scene]:
    """The grid's scenes, each with its sample rate; ``output`` overrides the output block
    (e.g. a fine rate to sample from)."""
    cells = []
    for gravity in (True, False):
        for i, d in enumerate(DIAMETERS):
            for j, ratio in enumerate(D_OVER_T):
                cells.append(({"chain": {"diameter": d}, "plate": {"thickness": d / ratio},
                               "effects": {"plate_model": "infinite", "gravity": gravity}},
                              RATES[(i + j) % len(RATES)]))
    for thickness, distance, gravity, rate in GREENS:
        cells.append(({"plate": {"thickness": thickness, "distance_to_support": distance},
                       "effects": {"plate_model": "greens", "gravity": gravity}, "sem": COARSE},
                      rate))
    return [scene_from_dict({**spec, "output": output or {"sample_rate": rate}})
            for spec, rate in cells]


def grid_rates() -> list[float]:
    """Each grid scene's own sample rate, in :func:`grid_scenes`'s order."""
    return [float(s.output.sample_rate) for s in grid_scenes()]
