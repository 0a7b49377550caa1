"""Where a 2-D plate suffices: the Mindlin plate against the 3-D spectral elements, scene by scene.

For each sphere size, plate thickness and chain position, the same scene runs on the 3-D plate and
on the Mindlin plate (the same in-plane mesh machinery, :mod:`solitonde.model.mindlin`), each with
a fresh plate and a fresh response cache, so each wall time is a first shot at a new plate: what a
table build pays per plate. TOF and ARR come from the sensor trace through the extractor, as for
measurements; the errors are relative to the 3-D plate. A scene is within the table budget when
both errors are (:data:`solitonde.instrument.studies.accuracy.BUDGETS`).

The Mindlin plate takes more in-plane elements than ``sem.elements`` on thin plates (one per
flexural wavelength, :func:`solitonde.model.tiers.meshed.mindlin_elements`). The 3-D reference runs
either on that same in-plane mesh (``same-mesh``: the two plate theories compared, nothing else)
or on its own default mesh (``default-mesh``: what the 3-D tier gives out of the box).

The pair of models is either the Green's functions (``greens`` / ``mindlin_greens``: what tables
use) or the coupled runs (``sem`` / ``mindlin``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from itertools import product
from typing import TypedDict, cast

from solitonde.instrument.studies.accuracy import BUDGETS, Budget, first_shot
from solitonde.model import greens
from solitonde.model.scene import Scene, load_scene, scene_from_dict
from solitonde.model.simulate import simulate
from solitonde.model.tiers.meshed import mindlin_elements

PAIRS = {"greens": ("greens", "mindlin_greens"), "coupled": ("sem", "mindlin")}
"""The 3-D model and its Mindlin counterpart, per kind of run."""
REFERENCES = ("same-mesh", "default-mesh")
"""The 3-D reference's in-plane mesh: the Mindlin plate's, or the 3-D tier's own default."""

DIAMETERS_M = (4.76e-3, 9.53e-3, 19.05e-3)
THICKNESSES_M = (1.5e-3, 2.29e-3, 3.18e-3, 4.83e-3, 6.0e-3)
"""The paper's three plates and the default table's thinnest and thickest."""
DISTANCES_M = (0.02, 0.457)
"""Near the clamped support and at the centre."""


@dataclass(frozen=True)
class Point:
    """One scene of the map."""

    diameter_m: float
    thickness_m: float
    distance_m: float

    def scene(self, plate_model: str, overrides: Sequence[str] = ()) -> Scene:
        """The scene on ``plate_model``; ``overrides`` (``key=value``, as ``--set``) go first,
        so the point's own size, thickness and position win."""
        return load_scene(None, [*overrides, f"chain.diameter={self.diameter_m!r}",
                                 f"plate.thickness={self.thickness_m!r}",
                                 f"plate.distance_to_support={self.distance_m!r}",
                                 f"effects.plate_model={plate_model}"])


def default_points(quick: bool = False) -> list[Point]:
    """The map: every sphere size x thickness x position (``quick``: two cheap scenes)."""
    if quick:
        return [Point(9.53e-3, 4.83e-3, 0.02), Point(4.76e-3, 6.0e-3, 0.457)]
    return [Point(d, t, l) for d, t, l in product(DIAMETERS_M, THICKNESSES_M, DISTANCES_M)]


def _warm_up(pair: tuple[str, str]) -> None:
    """Compile every kernel of both models once on a small scene, so no timing includes numba."""
    for tier in pair:
        scene = scene_from_dict({"plate": {"distance_to_support": 0.3},
                                 "effects": {"plate_model": tier},
                                 "sem": {"elements": [2, 2, 1], "order": [2, 2, 1]}})
        simulate(scene, greens_cache=greens.MemoryCache())


class TheoryRow(TypedDict):
    """One point on both plate models: the errors of the Mindlin plate against the 3-D one,
    whether they are within the table budget, and what each cost."""

    diameter_m: float
    thickness_m: float
    distance_m: float
    d_over_t: float
    elements_mindlin: list[int]
    tof_3d_s: float
    arr_3d: float
    tof_mindlin_s: float
    arr_mindlin: float
    tof_error: float
    arr_error: float
    within_budget: bool
    wall_3d_s: float
    wall_mindlin_s: float
    speedup: float
    dofs_3d: int
    dofs_mindlin: int
    dt_3d_s: float | None
    dt_mindlin_s: float | None
    energy_drift_3d: float
    energy_drift_mindlin: float


class OutsideBudget(TypedDict):
    diameter_m: float
    thickness_m: float
    distance_m: float
    d_over_t: float
    tof_error: float
    arr_error: float


class TheorySummary(TypedDict, total=False):
    """The worst errors, the speed-up range and the points outside the budget (empty without
    points)."""

    points: int
    within_budget: int
    max_tof_error: float
    max_arr_error: float
    speedup_min: float
    speedup_median: float
    outside_budget: list[OutsideBudget]


class Comparison(TypedDict):
    """What :func:`compare` returns (``bench-plates --json``)."""

    kind: str
    models: dict[str, str]
    reference_mesh: str
    budget: Budget
    overrides: list[str]
    rows: list[TheoryRow]
    summary: TheorySummary


def compare(points: Sequence[Point], kind: str = "greens",
            tick: Callable[[str], None] | None = None,
            overrides: Sequence[str] = (), reference_mesh: str = "same-mesh") -> Comparison:
    """Run every point on both models of ``PAIRS[kind]``; rows, the budget, a summary.

    ``overrides`` (``key=value``) describe the user's set-up (plate material, sphere material,
    plate size); they are checked before any run (SceneError names the key). ``reference_mesh``
    is one of :data:`REFERENCES`."""
    if kind not in PAIRS:
        raise ValueError(f"kind must be one of {', '.join(PAIRS)}, got {kind!r}")
    if reference_mesh not in REFERENCES:
        raise ValueError(f"reference_mesh must be one of {', '.join(REFERENCES)}, "
                         f"got {reference_mesh!r}")
    tick = tick or (lambda _label: None)
    reference, mindlin = PAIRS[kind]
    for p in points:
        p.scene(mindlin, overrides)
    _warm_up(PAIRS[kind])
    budget = BUDGETS["table_build"]
    rows: list[TheoryRow] = []
    for p in points:
        scene = p.scene(mindlin, overrides)
        elements = mindlin_elements(scene)
        mesh = ([f"sem.elements=[{elements[0]},{elements[1]},{elements[2]}]"]
                if reference_mesh == "same-mesh" else [])
        ref = first_shot(p.scene(reference, [*overrides, *mesh]))
        new = first_shot(scene)
        tof_error = abs(new["tof_s"] - ref["tof_s"]) / ref["tof_s"]
        arr_error = abs(new["arr"] - ref["arr"]) / ref["arr"]
        rows.append({
            "diameter_m": p.diameter_m, "thickness_m": p.thickness_m, "distance_m": p.distance_m,
            "d_over_t": p.diameter_m / p.thickness_m,
            "elements_mindlin": list(elements[:2]),
            "tof_3d_s": ref["tof_s"], "arr_3d": ref["arr"],
            "tof_mindlin_s": new["tof_s"], "arr_mindlin": new["arr"],
            "tof_error": tof_error, "arr_error": arr_error,
            "within_budget": bool(tof_error <= budget["tof"] and arr_error <= budget["arr"]),
            "wall_3d_s": ref["wall_s"], "wall_mindlin_s": new["wall_s"],
            "speedup": ref["wall_s"] / new["wall_s"],
            "dofs_3d": ref["dofs"], "dofs_mindlin": new["dofs"],
            "dt_3d_s": ref["plate_dt_s"], "dt_mindlin_s": new["plate_dt_s"],
            "energy_drift_3d": ref["energy_drift"], "energy_drift_mindlin": new["energy_drift"],
        })
        tick(f"D {p.diameter_m * 1e3:.2f} t {p.thickness_m * 1e3:.2f} L {p.distance_m * 1e3:.0f}")
    return {"kind": kind, "models": {"3d": reference, "mindlin": mindlin},
            "reference_mesh": reference_mesh, "budget": budget,
            "overrides": list(overrides), "rows": rows, "summary": summary(rows)}


def summary(rows: Sequence[TheoryRow]) -> TheorySummary:
    """Worst errors, the speed-up range and the scenes outside the budget."""
    if not rows:
        return {}
    return {
        "points": len(rows),
        "within_budget": sum(r["within_budget"] for r in rows),
        "max_tof_error": max(r["tof_error"] for r in rows),
        "max_arr_error": max(r["arr_error"] for r in rows),
        "speedup_min": min(r["speedup"] for r in rows),
        "speedup_median": sorted(r["speedup"] for r in rows)[len(rows) // 2],
        "outside_budget": [
            cast(OutsideBudget, {k: r[k] for k in ("diameter_m", "thickness_m", "distance_m",
                                                   "d_over_t", "tof_error", "arr_error")})
            for r in rows if not r["within_budget"]],
    }
