"""The one place where the service meets the model table and the inversion.

The service runs without a table (measurements come back with ``"estimate": null`` and a reason);
with one, :meth:`Estimator.estimate` turns per-sphere-size aggregates into the inversion's inputs
and calls :func:`solitonde.instrument.inference.inversion.invert`.
"""

from __future__ import annotations

import importlib
import logging
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from solitonde.signal.json_ready import json_ready

log = logging.getLogger("solitonde.instrument")


class EstimateUnavailable(RuntimeError):
    """No estimate can be made (no table loaded, or the inversion is not installed)."""


def _load_modules() -> tuple[Any, Any] | str:
    try:
        table_mod = importlib.import_module("solitonde.instrument.tables.table")
        inversion_mod = importlib.import_module("solitonde.instrument.inference.inversion")
    except ImportError as exc:
        return f"the table/inversion modules are not available ({exc})"
    if not hasattr(table_mod, "ModelTable") or not hasattr(inversion_mod, "invert"):
        return "the table/inversion modules lack ModelTable or invert"
    return table_mod, inversion_mod


class Estimator:
    """A loaded model table (or the reason there is none) and the inversion call.

    Parameters
    ----------
    table_path:
        HDF5 model table; ``None`` or a missing file gives an estimator without a table.
    """

    def __init__(self, table_path: str | Path | None, warm_up: bool = True) -> None:
        self.path = Path(table_path) if table_path is not None else None
        self.table: Any = None
        self._invert: Any = None
        self.reason: str | None = None
        if self.path is None:
            self.reason = "no model table configured (start with --table FILE)"
            return
        if not self.path.is_file():
            self.reason = f"model table {str(self.path)!r} does not exist"
            return
        modules = _load_modules()
        if isinstance(modules, str):
            self.reason = modules
            return
        table_mod, inversion_mod = modules
        try:
            self.table = table_mod.ModelTable.load(self.path)
        except Exception as exc:  # a broken table must not stop the service; report why
            self.reason = f"model table {str(self.path)!r} could not be loaded: {exc}"
            log.warning(self.reason)
            return
        self._invert = inversion_mod.invert
        if warm_up:  # a service does it once at start; a command line inverts once
            self._warm_up(inversion_mod)

    def _warm_up(self, inversion_mod: Any) -> None:
        """Build the inversion's fine grids now, not in the first request that needs them."""
        fine_grid = getattr(inversion_mod, "fine_grid", None)
        if fine_grid is None:
            return
        for i in range(len(self.table.axes["diameter_m"])):
            try:
                fine_grid(self.table, i)
            except Exception as exc:  # a sphere size the inversion cannot use: say so, go on
                log.warning("model table: no inversion grid for diameter index %d: %s", i, exc)

    @property
    def loaded(self) -> bool:
        return self.table is not None

    def plate_size(self) -> list[float] | None:
        """The plate size (m) of the table's scenes, or None without a table."""
        if not hasattr(self, "_plate_size"):
            plate = (((self.summary() or {}).get("provenance") or {}).get("scene_defaults")
                     or {}).get("plate") or {}
            size = plate.get("size")
            self._plate_size = [float(s) for s in size] if size else None
        return self._plate_size

    def summary(self) -> dict[str, Any] | None:
        """The table's axes and provenance, JSON-ready."""
        if self.table is None:
            return None
        return json_ready(self.table.summary())

    def invert(self, inputs: Sequence[Mapping[str, Any]],
               calibration: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """Estimate thickness and distance from per-sphere-size summaries.

        Raises
        ------
        EstimateUnavailable
            When no table is loaded.
        """
        if self.table is None:
            raise EstimateUnavailable(self.reason or "no model table loaded")
        result = self._invert(self.table, [dict(i) for i in inputs],
                              calibration=dict(calibration) if calibration else None)
        return json_ready(result.to_dict() if hasattr(result, "to_dict") else result)

    def estimate(self, aggregates: Sequence[Mapping[str, Any]]) -> tuple[dict[str, Any] | None,
                                                                         str | None]:
        """Estimate for a measurement's aggregates, or ``(None, reason)``."""
        if self.table is None:
            return None, self.reason
        inputs = []
        for agg in aggregates:
            item = inversion_input(agg)
            if isinstance(item, str):
                return None, item
            inputs.append(item)
        if not inputs:
            return None, "no shot gave a usable TOF"
        return self.invert(inputs), None


def inversion_input(agg: Mapping[str, Any]) -> dict[str, Any] | str:
    """One aggregate (``Aggregate.to_dict()`` plus ``sphere_diameter``, see
    :func:`solitonde.instrument.service.ingest.aggregate_groups`) as an inversion input, or the
    reason it cannot be one."""
    diameter = agg.get("sphere_diameter")
    if diameter is None:
        return "metadata.sphere_diameter is missing: the inversion needs the sphere size"
    tof, arr = _stat(agg, "tof_s"), _stat(agg, "arr")
    if tof.get("mean") is None or arr.get("mean") is None:
        return (f"no shot with D = {diameter} m has a detected reflection (no TOF, no ARR); "
                "see the aggregate's arr_upper_bound")
    return {
        "diameter_m": float(diameter),
        "tof_s": float(tof["mean"]),
        "tof_std_s": tof.get("std"),
        "arr": float(arr["mean"]),
        "arr_std": arr.get("std"),
        "n_shots": int(tof.get("count") or 1),
    }


def _stat(agg: Mapping[str, Any], name: str) -> Mapping[str, Any]:
    value = agg.get(name)
    return value if isinstance(value, Mapping) else {}
