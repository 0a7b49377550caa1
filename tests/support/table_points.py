"""The model run at one point of a table's family, between its nodes: what a table's read there
is checked against (its interpolation, its dissipation layer)."""

from __future__ import annotations

from typing import Any

from solitonde.instrument.tables import plate_task
from solitonde.instrument.tables.table import STATUS_OK, ModelTable
from solitonde.model.scene import apply_overrides, scene_from_dict


def simulated_at(table: ModelTable, diameter_m: float, thickness_m: float, distance_m: float,
                 **overrides: Any) -> dict[str, Any]:
    """The table's scene at (D, t, L), with scene ``overrides`` (dotted keys), simulated and
    measured as a table point is; asserts the model detects a reflection there."""
    scene = scene_from_dict(apply_overrides(dict(table.sweep["scene"]), {
        "chain.diameter": diameter_m, "plate.thickness": thickness_m,
        "plate.distance_to_support": distance_m, **overrides}))
    point = plate_task.simulate_point(scene, table.sweep.get("detect"))
    assert point["status"] == STATUS_OK, point["error"]
    return point
