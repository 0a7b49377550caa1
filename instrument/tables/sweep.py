"""What a model table covers: the grid of sphere sizes, thicknesses and distances, the scene every
point starts from, and the default table's grid."""

from __future__ import annotations

import copy
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from solitonde.instrument.tables.table import SweepDict, TableError
from solitonde.model.scene import Scene, SceneDict, apply_overrides, scene_from_dict
from solitonde.model.tiers import MESHED_PLATE_MODELS, resolve_plate_model
from solitonde.signal.pulses import DetectKeywords

#: The paper's sphere sizes (3/16, 3/8, 3/4 in).
PAPER_DIAMETERS_M = (4.76e-3, 9.53e-3, 19.05e-3)


@dataclass
class Sweep:
    """What a table covers: the grid axes and the scene every point starts from.

    Attributes
    ----------
    diameters_m, thicknesses_m, distances_m: grid axes, m (sorted, distinct).
    scene: base scene as a nested dict (any scene keys; the axes override ``chain.diameter``,
        ``plate.thickness``, ``plate.distance_to_support``).
    traces: also store each point's sensor trace.
    detect: options passed to :func:`solitonde.signal.features.extract`.
    """

    diameters_m: list[float]
    thicknesses_m: list[float]
    distances_m: list[float]
    scene: SceneDict = field(default_factory=SceneDict)
    traces: bool = False
    detect: DetectKeywords = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in ("diameters_m", "thicknesses_m", "distances_m"):
            values = [float(v) for v in getattr(self, name)]
            if not values:
                raise TableError(name, "needs at least one value")
            if any(not math.isfinite(v) or v < 0 for v in values):
                raise TableError(name, f"values must be finite and >= 0, got {values}")
            if len(set(values)) != len(values):
                raise TableError(name, f"values must be distinct, got {values}")
            setattr(self, name, sorted(values))
        if min(self.diameters_m) <= 0 or min(self.thicknesses_m) <= 0:
            raise TableError("diameters_m", "diameters and thicknesses must be > 0")
        self.base_scene()  # validate once, here, naming the bad field

    def to_dict(self) -> SweepDict:
        """The sweep as stored in a table file (attribute ``sweep``, JSON): copies throughout."""
        return {"diameters_m": list(self.diameters_m), "thicknesses_m": list(self.thicknesses_m),
                "distances_m": list(self.distances_m), "scene": copy.deepcopy(self.scene),
                "traces": self.traces, "detect": copy.deepcopy(self.detect)}

    @classmethod
    def from_dict(cls, data: SweepDict | Mapping[str, Any]) -> Sweep:
        return cls(**dict(data))

    @property
    def shape(self) -> tuple[int, int, int]:
        return len(self.diameters_m), len(self.thicknesses_m), len(self.distances_m)

    def base_scene(self) -> Scene:
        return scene_from_dict(self.scene)

    def scene_at(self, i_d: int, i_t: int, i_l: int) -> Scene:
        """The scene of one grid point."""
        data = apply_overrides(self.scene, {
            "chain.diameter": self.diameters_m[i_d],
            "plate.thickness": self.thicknesses_m[i_t],
            "plate.distance_to_support": self.distances_m[i_l],
        })
        return scene_from_dict(data)

    def groups(self) -> list[tuple[int, int]]:
        """Plates ``(i_t, i_l)``, the likely costly (finite-plate, thin) ones first."""
        def cost(key: tuple[int, int]) -> tuple[int, float]:
            i_t, i_l = key
            finite = resolve_plate_model(self.scene_at(len(self.diameters_m) - 1, i_t, i_l))[0]
            return (0 if finite in MESHED_PLATE_MODELS else 1, self.thicknesses_m[i_t])
        keys = [(i, j) for i in range(len(self.thicknesses_m))
                for j in range(len(self.distances_m))]
        return sorted(keys, key=cost)


def default_distances_m() -> list[float]:
    """L for the default table: dense within 200 mm (where the support matters), then to the
    plate centre (457 mm). 2.5 mm apart next to the clamp and 5 mm to 70 mm:

    * next to the clamp ARR rises steeply and bends toward it: with nodes 10 mm apart, linear
      interpolation read ARR up to 0.08 low at 3-5 mm (up to 7 times the error the table
      stated) and TOF up to 10 us late, against the model simulated there (the error falls as
      the square of the spacing);
    * from 30 to 70 mm a weak reflection oscillates with distance (about 25 mm long: the
      clamp's echo against the direct reflection), and nodes at 35, 50 and 70 mm sat on its
      mean: each lay on the line through its neighbours, so the table stated 0.0003 in ARR
      where it missed by up to 0.0036 (10 times). Nodes 5 mm apart follow it.
    """
    near = [0.0, 0.0025, 0.005, 0.0075, 0.01, 0.015, 0.02, 0.025, 0.03, 0.035, 0.04, 0.045,
            0.05, 0.055, 0.06, 0.065, 0.07, 0.08, 0.09, 0.115, 0.14, 0.17, 0.2]
    far = [0.26, 0.34, 0.457]
    return near + far


THICKNESS_NODES = 16


def default_thicknesses_m() -> list[float]:
    """t for the default table: 1.5 to 6 mm, geometric (ARR is a function of D/t), 16 nodes
    (10 % apart): TOF bends sharply where the reflection weakens (D/t 3-4), and with 8 nodes
    linear interpolation there erred by 13 us (a 2.5 mm plate read with 9.53 mm spheres), more
    than every other term of the error budget; the error falls as the square of the spacing."""
    return [float(round(x, 6)) for x in np.geomspace(1.5e-3, 6e-3, THICKNESS_NODES)]


def default_sweep() -> Sweep:
    return Sweep(list(PAPER_DIAMETERS_M), default_thicknesses_m(), default_distances_m())


def damped_scene(scene: Mapping[str, Any], damping_s: float) -> SceneDict:
    """A sweep's base scene (nested dict) with Kuwabara-Kono damping ``damping_s`` switched on."""
    data: SceneDict = json.loads(json.dumps(dict(scene)))
    effects = data.setdefault("effects", {})
    effects["dissipation"] = True
    effects["damping"] = float(damping_s)
    return data
