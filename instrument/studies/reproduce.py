"""Regenerate the paper's Figs. 3-10 from the model: a PNG and the CSV behind each, and a summary.

The set-up and the plan live in :mod:`.paper_setup`, the simulated points in :mod:`.paper_points`,
the checks in :mod:`.paper_checks`, the figures in :mod:`.paper_figures`; this module runs them.

Every simulated point goes through :func:`solitonde.model.simulate.simulate` and its sensor trace
through :func:`solitonde.signal.features.extract`, the same extractor measured shots go through.
Points near a support use the ``greens`` plate (the spectral-element plate's cached contact
response; the disk cache of :mod:`~solitonde.instrument.tables.greens_cache` makes a second run
reuse every plate run); the 3 x 3 grid at the centre is also run on the ``infinite`` plate (chain
on Zener's dashpot).

``summary.json`` holds the checks the paper's statements imply (its Secs. 4 and 5) with the
numbers behind them:

- ``arr_falls_with_d_over_t``: Spearman rank correlation of simulated ARR with D/t <= -0.9 and
  every ARR (or, without a detectable reflection, its upper bound) <=
  :data:`~.paper_checks.NEAR_ZERO_ARR` above D/t = 5;
- ``tof_over_d_collapses``: TOF/D on one curve of D/t: the three sphere sizes run at the same D/t
  values (:data:`~.paper_setup.COLLAPSE_D_OVER_T`, infinite plate) give TOF/D within
  :data:`~.paper_checks.COLLAPSE_LIMIT` of each other, while their TOFs differ by the ratio of the
  diameters;
- ``near_support_arr_exceeds_centre``: ARR at the first distance > 0 exceeds the centre's for every
  swept (D, t);
- ``critical_distance_grows_as_plate_thins``: the simulated critical distance (defined in
  :func:`~.paper_checks.settled_distance`) decreases strictly with thickness for every swept D,
  over the plates with D/t <= :data:`~.paper_checks.REFLECTION_D_OVER_T` (above it the paper's ARR
  is "near 0": the far-field reflection is a train at the detection floor whose TOF does not
  settle; those plates are listed with their values, not scored).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import TypedDict

import numpy as np
import pandas as pd

from solitonde.instrument.parallel import default_workers
from solitonde.instrument.studies.figures import save_json
from solitonde.instrument.studies.paper_checks import (
    Check,
    PaperStatements,
    check_arr_falls,
    check_collapse,
    check_critical_distance,
    check_near_support,
    critical_distances,
    paper_statements,
)
from solitonde.instrument.studies.paper_figures import fig3, fig4, fig5, fig6, fig7_8, fig9, fig10
from solitonde.instrument.studies.paper_points import cache_for, measure, run_sweep, theory_curve
from solitonde.instrument.studies.paper_setup import (
    CENTRE_M,
    COLLAPSE_D_OVER_T,
    DIAMETERS_M,
    PLATES_M,
    TRACE_DIAMETER_M,
    Plan,
    SemSettings,
    make_plan,
    scene_for,
)
from solitonde.instrument.tables.greens_cache import LayeredCache


class Summary(TypedDict):
    """``summary.json``: what was computed, how long it took, the checks and our numbers for the
    paper's statements."""

    quick: bool
    mesh: SemSettings
    distances_m: list[float]
    sweep_diameters_m: list[float]
    notes: list[str]
    wall_s: float
    timings_s: dict[str, float]
    workers: int
    checks: dict[str, Check]
    all_passed: bool
    paper: PaperStatements
    files: list[str]


def reproduce(out: str | Path, quick: bool = False, *, workers: int | None = None,
              cache_folder: str | Path | None = None, progress: bool = True,
              preset: str = "resolved") -> Summary:
    """Regenerate Figs. 3-10 into ``out`` (PNG + CSV each) and write ``summary.json``.

    Parameters
    ----------
    out: output folder (created).
    quick: coarse version for CI (:func:`~.paper_setup.make_plan`).
    workers: processes for the distance sweep (default: the usable cores).
    cache_folder: where the plate responses are cached (default:
        :func:`~solitonde.instrument.tables.greens_cache.cache_dir`).
    progress: show a progress bar.
    preset: plate contact model of the distance sweep, ``"paper"`` (single-node load, the
        paper's model) or ``"resolved"`` (mesh-convergent contact patch; slower).

    Returns
    -------
    The summary (also written to ``out/summary.json``).
    """
    from tqdm import tqdm

    started = time.perf_counter()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    plan = make_plan(quick, preset)
    workers = default_workers() if workers is None else max(1, int(workers))
    folder = None if cache_folder is None else str(cache_folder)
    cache = cache_for(folder)
    n_sweep = len(PLATES_M) * len(plan.distances_m)
    bar = tqdm(total=n_sweep + 6, disable=not progress, desc="reproduce", unit="step")

    def tick(stage: str) -> None:
        bar.set_postfix_str(stage)
        bar.update(1)

    timings: dict[str, float] = {}
    mark = time.perf_counter()
    grid_theory = pd.concat([theory_curve(d, PLATES_M) for d in DIAMETERS_M], ignore_index=True)
    dt_axis = np.linspace(0.3, 12.0, plan.theory_points)
    curves = pd.concat([theory_curve(d, d / dt_axis) for d in DIAMETERS_M], ignore_index=True)
    curve = curves[np.isclose(curves["diameter_m"], TRACE_DIAMETER_M)]
    fig4(out, grid_theory, plan.theory_points)
    tick("theory")
    trace_info = fig3(out, cache)
    tick("fig 3")
    grid_inf, collapse = _infinite_plate_points(cache)
    tick("grid on the infinite plate")
    fig9(out, plan.lamb_points)
    tick("fig 9")
    timings["theory_chain_lamb_s"] = time.perf_counter() - mark

    mark = time.perf_counter()
    sweep = run_sweep(plan, workers, folder, tick)
    timings["distance_sweep_s"] = time.perf_counter() - mark
    centre = sweep[np.isclose(sweep["distance_m"], CENTRE_M)].copy()
    fig5(out, curve, grid_inf, centre)
    fig6(out, curves, grid_inf, centre, collapse)
    fig7_8(out, sweep, grid_theory)
    crit = critical_distances(sweep)
    fig10(out, crit)
    tick("figures 5-8, 10")
    bar.close()

    checks: dict[str, Check] = {
        "arr_falls_with_d_over_t": check_arr_falls(grid_inf),
        "arr_falls_with_d_over_t_sem_centre": check_arr_falls(centre),
        "tof_over_d_collapses": check_collapse(collapse),
        "near_support_arr_exceeds_centre": check_near_support(sweep),
        "critical_distance_grows_as_plate_thins": check_critical_distance(crit),
    }
    summary = _summary(plan, started, timings, workers, checks,
                       paper_statements(trace_info, sweep, crit), out)
    save_json(summary, out / "summary.json")
    return summary


def _infinite_plate_points(cache: LayeredCache) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The 3 x 3 grid at the centre on the infinite plate, and the equal-D/t runs of the collapse
    check (every sphere size at :data:`~.paper_setup.COLLAPSE_D_OVER_T`, gravity on and off)."""
    grid_inf = pd.DataFrame([measure(scene_for(d, t, CENTRE_M, "infinite"), cache)
                             for d in DIAMETERS_M for t in PLATES_M])
    collapse = pd.DataFrame([
        {**measure(scene_for(d, d / r, CENTRE_M, "infinite").with_overrides(
            {"effects.gravity": gravity}), cache), "gravity": gravity}
        for gravity in (True, False) for d in DIAMETERS_M for r in COLLAPSE_D_OVER_T])
    return grid_inf, collapse


def _summary(plan: Plan, started: float, timings: dict[str, float], workers: int,
             checks: dict[str, Check], paper: PaperStatements, out: Path) -> Summary:
    """The summary of a finished reproduction (the figures already in ``out``)."""
    return {
        "quick": plan.quick,
        "mesh": plan.sem(),
        "distances_m": list(plan.distances_m),
        "sweep_diameters_m": list(plan.sweep_diameters_m),
        "notes": plan.notes,
        "wall_s": time.perf_counter() - started,
        "timings_s": timings,
        "workers": workers,
        "checks": checks,
        "all_passed": all(c["passed"] for c in checks.values()),
        "paper": paper,
        "files": sorted(p.name for p in out.iterdir() if p.suffix in (".png", ".csv")),
    }
