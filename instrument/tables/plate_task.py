"""One table build task: a plate's points, every sphere size simulated and read as from a
measurement (:func:`run_plate`, what each worker runs), and the values a point writes to the
table (:func:`point_record`). The build around them: :mod:`.table_build`."""

from __future__ import annotations

import math
import sys
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from solitonde.instrument.tables.greens_cache import (
    DEFAULT_STORE,
    DiskGreensCache,
    LayeredCache,
)
from solitonde.instrument.tables.measured import as_measured, detect_options
from solitonde.instrument.tables.sweep import Sweep
from solitonde.instrument.tables.table import (
    MAX_SECONDARY,
    SCALAR_FEATURES,
    STATUS_FAILED,
    STATUS_NO_REFLECTION,
    STATUS_OK,
    SweepDict,
)
from solitonde.instrument.tables.table_file import PlateResult, PointRecord
from solitonde.model import greens
from solitonde.model.errors import SceneError, SimulationError
from solitonde.model.greens import GreensCache
from solitonde.model.scene import Scene
from solitonde.model.simulate import SimulationResult, simulate
from solitonde.signal import kernel_choice
from solitonde.signal.errors import WaveformError
from solitonde.signal.features import Features, extract
from solitonde.signal.pulses import FLAGS


def point_record(features: Features | None, result: SimulationResult | None,
                 error: str | None, traces: bool) -> PointRecord:
    """The per-point values written to the table."""
    diag = result.diagnostics if result is not None else {}
    nan = math.nan
    rec: PointRecord = {
        "tof_s": nan, "arr": nan, "incident_time_s": nan, "incident_peak_N": nan,
        "reflected_peak_N": nan, "snr_db": nan, "arr_upper_bound": nan,
        "secondary_times_s": [nan] * MAX_SECONDARY, "secondary_ratios": [nan] * MAX_SECONDARY,
        "flags": 0, "error": error or "",
        "plate_model": result.plate_model if result is not None else "unknown",
        "wall_s": float(diag.get("wall_s", nan)) if result else nan,
        "energy_drift": float(diag.get("energy_drift", nan)) if result else nan,
        "dt_s": float(diag.get("dt_s", nan)) if result else nan,
        "mesh": diag.get("mesh") if result else None,
        "trace": None, "status": STATUS_FAILED,
    }
    if traces and result is not None:
        rec["trace"] = (float(result.t0), float(result.dt), np.asarray(result.samples, dtype=float))
    if features is None:
        return rec
    for k in SCALAR_FEATURES:
        value = getattr(features, k)
        rec[k] = math.nan if value is None else float(value)
    rec["secondary_times_s"] = _padded(features.secondary_times_s)
    rec["secondary_ratios"] = _padded(features.secondary_ratios)
    rec["flags"] = sum(1 << FLAGS.index(f) for f in features.flags if f in FLAGS)
    ok = features.tof_s is not None and features.arr is not None
    rec["status"] = STATUS_OK if ok else STATUS_NO_REFLECTION
    return rec


def _padded(values: Iterable[float]) -> list[float]:
    """The first :data:`MAX_SECONDARY` values, NaN-padded to that length."""
    vals = list(values)[:MAX_SECONDARY]
    return vals + [math.nan] * (MAX_SECONDARY - len(vals))


def simulate_point(scene: Scene, detect: Mapping[str, Any] | None = None,
                   traces: bool = False, greens_cache: GreensCache | None = None
                   ) -> PointRecord:
    """Simulate one scene and extract its features as from a measurement."""
    try:
        result = simulate(scene, greens_cache=greens_cache)
    except (SimulationError, SceneError) as exc:
        return point_record(None, None, f"simulation: {exc}", traces)
    # a table's points are read by the compiled extractor only (never the interpreted kernels
    # that bridge a background compile): the same bits whenever the table is built
    kernel_choice.finish()
    try:
        features = extract(as_measured(result), **{**detect_options(scene), **dict(detect or {})})
    except WaveformError as exc:
        return point_record(None, result, f"features: {exc}", traces)
    return point_record(features, result, None, traces)


def run_plate(sweep: SweepDict, i_t: int, i_l: int,
              diameters: Sequence[int] | None = None, responses: str | None = None
              ) -> PlateResult:
    """One task: every sphere size (largest first) on plate ``(i_t, i_l)``.

    The sizes share a task-local cache of plate responses: where the response does not depend on
    the sphere (the 3-D plate's), the largest sphere's record is the longest and its response
    covers the others; the Mindlin plate computes one response per distinct mesh. With
    ``responses`` (a folder, or :data:`~.greens_cache.DEFAULT_STORE` for this machine's), the
    response store there stands behind it: a response another build, layer or worker computed
    is read, not computed again, and the new ones are kept.
    ``greens_computed`` counts the responses this task computed.
    """
    spec = Sweep.from_dict(sweep)
    order = sorted(range(len(spec.diameters_m)) if diameters is None else diameters, reverse=True)
    # This task's responses, dropped when it ends; unbounded, so that its size counts them.
    task_cache = greens.MemoryCache(max_bytes=sys.maxsize)
    cache: greens.GreensCache = task_cache
    if responses is not None:
        folder = None if responses == DEFAULT_STORE else responses
        cache = LayeredCache(DiskGreensCache(folder), memory=task_cache)
    points = {i_d: simulate_point(spec.scene_at(i_d, i_t, i_l), spec.detect, spec.traces,
                                  cache) for i_d in order}
    computed = cache.computed if isinstance(cache, LayeredCache) else len(task_cache)
    return {"i_t": i_t, "i_l": i_l, "points": points, "greens_computed": computed}
