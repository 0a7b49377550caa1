"""The reproduction's simulated points: one scene simulated and measured as a shot is
(:func:`measure`), the distance sweep on the ``greens`` plate run through the instrument's
executor (:func:`run_sweep`), Zener's theory curves, and the data frames they make.

Every simulated point goes through :func:`solitonde.model.simulate.simulate` and its sensor trace
through :func:`solitonde.signal.features.extract`, the same extractor measured shots go through.
Plate responses are kept in the disk cache of :mod:`~solitonde.instrument.tables.greens_cache`, one
per process and folder (:func:`cache_for`), so that a second run reuses every plate run.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from typing import NotRequired, TypedDict

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from solitonde.instrument.parallel import run_tasks
from solitonde.instrument.studies.paper_setup import PLATES_M, Plan, SemSettings, scene_for
from solitonde.instrument.tables import greens_cache
from solitonde.instrument.tables.measured import as_measured, detect_options
from solitonde.model import zener
from solitonde.model.errors import SimulationError
from solitonde.model.scene import Scene
from solitonde.model.simulate import simulate
from solitonde.signal.errors import WaveformError
from solitonde.signal.features import extract


class PointRow(TypedDict):
    """One simulated point as a row of the reproduction's frames (and CSVs). A point whose
    simulation failed carries only the keys every row has, its reason in ``flags``."""

    diameter_m: float
    thickness_m: float
    distance_m: float
    d_over_t: float
    plate_model: str
    truth_tof_s: NotRequired[float]
    truth_arr: NotRequired[float]
    energy_drift: NotRequired[float]
    tof_s: float
    arr: float
    arr_upper_bound: NotRequired[float]
    incident_time_s: NotRequired[float]
    flags: str
    wall_s: NotRequired[float]


def groups(frame: pd.DataFrame, by: str) -> Iterator[tuple[float, pd.DataFrame]]:
    """``frame.groupby(by)`` with each key as a float (the sweep's axes are numbers)."""
    for key, g in frame.groupby(by):
        yield float(key), g  # type: ignore[arg-type]


def pairs(frame: pd.DataFrame, by: list[str]) -> Iterator[tuple[tuple[float, float], pd.DataFrame]]:
    """``frame.groupby(by)`` over two columns, each key a pair of floats."""
    for (a, b), g in frame.groupby(by):
        yield (float(a), float(b)), g  # type: ignore[arg-type]


def floats(column: pd.Series) -> list[float]:
    """A numeric column as floats."""
    return [float(v) for v in column.to_numpy(dtype=float)]


def arr_or_bound(frame: pd.DataFrame) -> np.ndarray:
    arr = frame["arr"].to_numpy(dtype=float)
    bound = frame["arr_upper_bound"].to_numpy(dtype=float)
    return np.where(np.isfinite(arr), arr, bound)


def cache_for(folder: str | None) -> greens_cache.LayeredCache:
    """This process's plate-response cache on ``folder`` (None: the default folder), opened once
    per process and folder."""
    if folder not in _CACHES:
        _CACHES[folder] = greens_cache.disk_cache(folder)
    return _CACHES[folder]


_CACHES: dict[str | None, greens_cache.LayeredCache] = {}


def measure(scene: Scene, cache: greens_cache.LayeredCache) -> PointRow:
    """Simulate ``scene`` and extract TOF and ARR from its sensor trace with the signal package.

    A shot without a detectable reflection has NaN TOF and ARR and carries ``arr_upper_bound``.
    """
    started = time.perf_counter()
    result = simulate(scene, greens_cache=cache)
    try:
        f = extract(as_measured(result), **detect_options(result.scene))
        tof, arr = math.nan if f.tof_s is None else f.tof_s, math.nan if f.arr is None else f.arr
        bound = math.nan if f.arr_upper_bound is None else f.arr_upper_bound
        incident, flags = f.incident_time_s, ";".join(f.flags)
    except WaveformError as exc:
        tof = arr = bound = incident = math.nan
        flags = f"no_pulse: {exc}"
    return {
        "diameter_m": scene.chain.diameter,
        "thickness_m": scene.plate.thickness,
        "distance_m": scene.plate.distance_to_support,
        "d_over_t": scene.d_over_t,
        "plate_model": result.plate_model,
        "truth_tof_s": result.truth["tof_s"],
        "truth_arr": result.truth["arr"],
        "energy_drift": result.diagnostics["energy_drift"],
        "tof_s": tof, "arr": arr, "arr_upper_bound": bound, "incident_time_s": incident,
        "flags": flags,
        "wall_s": time.perf_counter() - started,
    }


def sweep_position(thickness: float, distance: float, diameters: tuple[float, ...],
                   sem: SemSettings, cache_folder: str | None) -> list[PointRow]:
    """All sphere sizes at one plate and distance, largest D first (one task of the sweep).

    The 3-D plate's contact response depends on the plate, mesh, position and step only; the step
    is set by the plate and the sample rate, not by D. The largest sphere needs the longest
    record, so running it first leaves a response in the cache that the smaller spheres reuse.
    """
    cache = cache_for(cache_folder)
    rows: list[PointRow] = []
    for d in sorted(diameters, reverse=True):
        try:
            rows.append(measure(scene_for(d, thickness, distance, "greens", sem), cache))
        except SimulationError as exc:
            rows.append({"diameter_m": d, "thickness_m": thickness, "distance_m": distance,
                         "d_over_t": d / thickness, "plate_model": "greens", "tof_s": math.nan,
                         "arr": math.nan, "flags": f"simulation_error: {exc}"})
    return rows


def run_sweep(plan: Plan, workers: int, cache_folder: str | None,
              tick: Callable[[str], None]) -> pd.DataFrame:
    """The distance sweep on the ``greens`` plate, in parallel over (plate, distance)."""
    tasks = [(t, L, plan.sweep_diameters_m, plan.sem(), cache_folder)
             for t in PLATES_M for L in plan.distances_m]
    # Thin plates and the centre need the longest plate runs: start them first.
    tasks.sort(key=lambda a: (a[0], -a[1]))
    rows: list[PointRow] = []
    for position in run_tasks(sweep_position, tasks, workers, None):
        rows.extend(position)
        tick("distance sweep")
    # results come back in finishing order: one order whatever the worker count
    return (pd.DataFrame(rows).sort_values(["diameter_m", "thickness_m", "distance_m"])
            .reset_index(drop=True))


def theory_curve(diameter: float, thicknesses: ArrayLike) -> pd.DataFrame:
    """Zener theory (infinite plate) for one sphere over many thicknesses: D/t, lambda, e, ARR, TOF.

    The same formulas as :func:`solitonde.model.zener.predict` (Eq. 9, 14-15), with the restitution
    from the tabulated fast path so a curve of hundreds of points costs milliseconds.
    """
    scenes = [scene_for(diameter, float(t)) for t in np.ravel(np.asarray(thicknesses, float))]
    lams = np.array([zener.inelasticity(s) for s in scenes])
    e, tau_c = zener.restitution_and_contact_time_many(lams)
    rows = []
    for s, lam, ei, ti in zip(scenes, lams, e, tau_c, strict=True):
        m, d = s.sphere_mass, s.chain.diameter
        v_in = zener.incident_velocity(s)
        trip = zener.travel_diameters(s) * d
        down = trip / zener.solitary_wave_speed(d, s.a_s, m, v_in)
        up = trip / zener.solitary_wave_speed(d, s.a_s, m, ei * v_in) if ei > 0 else math.inf
        contact = ti * zener.time_scale(m, s.a_p, v_in)
        rows.append({"diameter_m": d, "thickness_m": s.plate.thickness, "d_over_t": s.d_over_t,
                     "lambda": lam, "e": ei, "tau_c": ti, "arr": ei**1.2,
                     "tof_s": down + up + contact, "tof_over_d_s_per_m": (down + up + contact) / d})
    return pd.DataFrame(rows)
