"""Synthetic validation: random plates simulated, measured as real shots are, and inverted.

For each of ``n`` scenes (seeded): a thickness drawn log-uniformly and a distance to the support
drawn uniformly inside the table's range (so almost surely between its grid points), and a plate
material drawn from the spread of the table's (:func:`draw_plate_materials`: a plate of the grade,
as a user's is, not the table's exact properties; ``--exact-material`` turns it off), simulated
for every sphere size of the table with the plate model ``auto`` picks and with a known
dissipation the table does not have (Kuwabara-Kono contact damping, :data:`DAMPING_S`). Each
size's noise-free trace becomes :data:`SHOTS` shots with white noise at :data:`SNR_DB`, measured
and aggregated exactly as measured files of a stated sphere size are
(:func:`~solitonde.instrument.inference.chain_geometry.measure_shot`: the drift fitted on the gap
against the relaxation of the table family's chain, undamped, while the truth's chain is damped:
a model error the answers must carry like a real chain's); the sizes with a detected
reflection are inverted together. The dissipation is compensated as an operator would: a
calibration fitted by :func:`~solitonde.instrument.inference.calibration_fit.fit_calibration`
from shots simulated the same way on two reference plates far from the supports
(:data:`REFERENCE_THICKNESS_M`, :data:`REFERENCE2_THICKNESS_M` at :data:`REFERENCE_DISTANCE_M`):
against a table with a dissipation layer (the bundled ones, whose slices are at 7e-8, 1.2e-7
and 2e-7 s, so the truths' damping lies between two of them) the chain's damping, then an ARR
factor and TOF offset per size for what it leaves, with their uncertainty; against a table
without one the factor and offset alone, whose spread between the two plates (the dissipation's
effect is not a constant factor and delay) is what the calibration states as its transfer
uncertainty.

Scored: relative thickness error of the posterior median (median and 90th percentile, over the
plates where thickness comes back ``constrained``); ``coverage_95``, the fraction of thickness
answers whose 95 % bounds hold the truth, every answer counted with its bounds (a one-sided
``lower_bound_only`` / ``upper_bound_only`` answer covers when its bound holds), and
``coverage_95_two_sided`` over the two-sided ones alone; ``answered``, the fraction of plates
with any answer (a thickness with at least one bound, not flagged); ``interval_width_median``,
the median width of the two-sided 95 % intervals relative to the truth; ``inconsistent_rate``,
the fraction flagged ``inconsistent`` or ``out_of_range`` (on the table's own family: false
alarms); ``missed_unflagged``, the fraction whose answer (two-sided or one-sided) misses with no
flag, and ``missed_unwarned`` those of them with no warning of another reading either
(``other_reading_rate``: how often that warning comes); ``ambiguous_rate``, the fraction answered
``ambiguous`` (separate readings along the thickness-distance ridge, instrument.inference.ridge),
which counts as covered when one of its readings covers the truth and as flagged otherwise;
``by_distance``, these scores per bin of the true distance to the support
(:data:`DISTANCE_BINS_M`); the distance's coverage (one-sided
bounds counted as such); and the status. A size whose shots show no reflection enters with its
ARR bound (instrument.inference.inversion).
The expected status is what the noise-free model says the data can tell. For each end of each
parameter's range, ``d`` is how many standard errors (the inversion's own sigmas,
:func:`separations`) separate the truth's features from the closest table point on that end: along
a slice (the other parameter at its true value) and along the profile (any value of the other
parameter). A side is open (the parameter is not bounded there) when ``d < 1.5``, closed when ``d >
3``, either in between. The slice misses joint (t, L) degeneracies (a thin plate near a support can
mimic a thicker one far from it); the profile flags every one however little posterior mass it
carries; a status supported by either counts as right (``status_accuracy``), and each is scored on
its own as well (``status_accuracy_slice``, ``status_accuracy_profile``).
L = 0 is a physical end and never open. So far from the support the distance must come back
``lower_bound_only``, and right at the support, where TOF and ARR no longer depend on the plate,
thickness may honestly come back unbounded.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np

from solitonde.instrument.errors import InstrumentError
from solitonde.instrument.inference.calibration import (
    Calibration,
    calibrated_table,
    calibration_along,
)
from solitonde.instrument.inference.calibration_fit import Reference, fit_calibration
from solitonde.instrument.inference.chain_geometry import measure_shot
from solitonde.instrument.inference.inversion import FeatureSummary, fine_grid, invert
from solitonde.instrument.inference.material_spread import spread_of
from solitonde.instrument.inference.pipeline import SizeSummary
from solitonde.instrument.tables.measured import as_measured
from solitonde.instrument.tables.table import ModelTable
from solitonde.instrument.tables.table_build import run_tasks
from solitonde.model.scene import apply_overrides, scene_from_dict
from solitonde.model.simulate import simulate
from solitonde.signal.atomic import write_text
from solitonde.signal.errors import WaveformError
from solitonde.signal.features import EXTRACTOR_VERSION, aggregate
from solitonde.signal.synth import degrade

DAMPING_S = 1e-7
"""Known dissipation added to every validation shot: Kuwabara-Kono time constant tau, s (lowers
ARR by about 13 % for D = 4.76 mm, 7 % for 9.53 mm, 2 % for 19.05 mm)."""
SHOTS = 5
SNR_DB = 40.0
REFERENCE_THICKNESS_M = 5.5e-3
REFERENCE2_THICKNESS_M = 2.5e-3
REFERENCE_DISTANCE_M = 0.457
OPEN_BELOW = 1.5
CLOSED_ABOVE = 3.0
STATUSES = ("constrained", "lower_bound_only", "upper_bound_only", "unconstrained")
ANSWERS = ("constrained", "lower_bound_only", "upper_bound_only", "ambiguous")
"""Thickness statuses that are an answer (with at least one bound; an ``ambiguous`` one with
its readings)."""
OTHER_READING_WARNING = "another reading fits as well"
"""How the warning of another reading near a support starts (a widened answer's or an ambiguous
one's: instrument.inference.adequacy)."""
DISTANCE_BINS_M = (0.0, 0.015, 0.03, 0.06, 0.12, None)
"""Edges of the distance bins ``by_distance`` scores (m; the last bin open)."""


class ValidationInputError(InstrumentError, ValueError):
    """A validation request that cannot be run; ``field`` names what is wrong."""



def _scene_dict(base: Mapping[str, Any], d: float, t: float, length: float) -> dict[str, Any]:
    return apply_overrides(dict(base), {
        "chain.diameter": d, "plate.thickness": t, "plate.distance_to_support": length,
        "effects.dissipation": True, "effects.damping": DAMPING_S,
    })


def measure_plate(base: Mapping[str, Any], diameters: Sequence[float], thickness_m: float,
                  distance_m: float, seed: int, shots: int = SHOTS,
                  snr_db: float = SNR_DB) -> dict[str, Any]:
    """Simulate one plate for every sphere size (largest first, one Green's function) and measure
    ``shots`` noisy shots of each: per-size summaries (None where no reflection was detected)."""
    from solitonde.model import greens

    rng = np.random.default_rng(seed)
    family = scene_from_dict(dict(base))
    plate_cache = greens.MemoryCache()  # one response serves every sphere size of this plate
    summaries: dict[float, dict[str, Any] | None] = {}
    started = time.perf_counter()
    for d in sorted(diameters, reverse=True):
        result = simulate(scene_from_dict(_scene_dict(base, d, thickness_m, distance_m)),
                          greens_cache=plate_cache)
        recorded = as_measured(result)
        reference = float(result.samples.max() - result.samples[0])
        feats = []
        for _ in range(shots):
            # white noise over the whole record, its pre-trigger included; measured as analyze
            # measures a shot of a stated size: the drift on the gap against the relaxation of
            # the family's chain, which knows nothing of the truth's dissipation
            noisy = degrade(recorded.samples, snr_db, rng, reference)
            try:
                feats.append(measure_shot(recorded.with_samples(noisy), d, family))
            except WaveformError:
                continue
        # what the inversion reads of these shots (no reflection: the ARR bound alone), or
        # None where they give nothing (SizeSummary.skip_reason says why)
        size = SizeSummary(d, aggregate(feats)) if feats else None
        summaries[d] = None if size is None or size.skip_reason() is not None else {
            **asdict(size.inputs()), "plate_model": result.plate_model}
    return {"thickness_m": thickness_m, "distance_m": distance_m, "summaries": summaries,
            "wall_s": time.perf_counter() - started}


def draw_plate_materials(table: ModelTable, spread: Mapping[str, float], n: int,
                         rng: np.random.Generator) -> list[dict[str, Any]]:
    """``n`` plates of the table's plate material as a grade's plates come: E, nu and rho each
    drawn from a normal distribution about the table's value with the grade's spread (relative
    sd for E and rho, sd for nu), as property mappings for ``plate.material``. Normal, with the
    spread the intervals state, so a coverage measured on them tests that statement."""
    props = (table.family or {}).get("plate_material")
    if not props:
        raise ValidationInputError("draw_material", "the table records no plate material to "
                                   "draw about (rebuild it, or validate with exact material)")
    z = rng.standard_normal((n, 3))
    e, nu, rho = (float(props[k]) for k in ("youngs_modulus", "poisson_ratio", "density"))
    return [{"name": f"{props['name']} (drawn)",
             "youngs_modulus": e * (1.0 + spread["youngs_modulus_rel_sd"] * ze),
             "poisson_ratio": nu + spread["poisson_ratio_sd"] * zn,
             "density": rho * (1.0 + spread["density_rel_sd"] * zr)}
            for ze, zn, zr in z.tolist()]


def _inputs(summaries: Mapping[float, Any]) -> list[FeatureSummary]:
    return [FeatureSummary(s["diameter_m"], s["tof_s"], s["arr"], s["tof_std_s"], s["arr_std"],
                           int(s["n_shots"]), s.get("arr_upper_bound"))
            for s in summaries.values() if s is not None]


def separations(table: ModelTable, inputs: Sequence[FeatureSummary], thickness_m: float,
                distance_m: float, calibration: Calibration | None) -> dict[str, np.ndarray]:
    """How far, in standard errors, the features of the closest point at each table end are
    from the truth's (profile over the other parameter).

    ``d(t, L) = sqrt(sum over sizes of (dTOF/sigma_tof)^2 + (dARR/sigma_arr)^2)`` between the
    noise-free model at the truth and at (t, L), with the inversion's own sigmas; for thickness
    the ends are the smallest ``d`` along t = t_min and t = t_max (any L), for distance along
    L = L_min and L = L_max (any t). Returns ``{"thickness_m": [d_low, d_high],
    "distance_m": [...]}``.
    """
    d2: np.ndarray | None = None
    table = calibrated_table(table, calibration)
    for item in inputs:
        g = fine_grid(table, table.diameter_index(item.diameter_m))
        i = int(np.argmin(np.abs(np.log(g.thickness_m / thickness_m))))
        j = int(np.argmin(np.abs(g.distance_m - distance_m)))
        # numbers, or rows over the grid's distances where the calibration follows distance
        factor, offset, f_std, o_std = calibration_along(calibration, g.diameter_m,
                                                         g.distance_m[None, :])
        s_tof, s_arr = item.sigmas()
        var_tof = s_tof**2 + o_std**2 + g.model_tof_var
        var_arr = s_arr**2 + factor**2 * g.model_arr_var + (f_std * g.arr) ** 2
        if np.ndim(factor) == 0:
            term = (g.tof_s - g.tof_s[i, j]) ** 2 / var_tof
            term += (factor * (g.arr - g.arr[i, j])) ** 2 / var_arr
        else:  # the calibrated model at (t, L) against the calibrated truth at its own L
            term = (g.tof_s + offset - g.tof_s[i, j] - offset[0, j]) ** 2 / var_tof
            term += (factor * g.arr - factor[0, j] * g.arr[i, j]) ** 2 / var_arr
        term[~g.valid] = np.inf
        d2 = term if d2 is None else d2 + term
        truth = (i, j)
    assert d2 is not None
    i, j = truth
    d = np.sqrt(d2)
    return {"thickness_m": np.array([d[0].min(), d[-1].min()]),
            "distance_m": np.array([d[:, 0].min(), d[:, -1].min()]),
            "thickness_m_slice": np.array([d[0, j], d[-1, j]]),
            "distance_m_slice": np.array([d[i, 0], d[i, -1]])}


def expected_statuses(d: np.ndarray, lower_physical: bool) -> set[str]:
    """Statuses the data support, from the separations at the two ends (:func:`separations`):
    an end is open below :data:`OPEN_BELOW` standard errors, closed above :data:`CLOSED_ABOVE`,
    and either in between."""
    def states(x: float, physical: bool) -> set[bool]:
        if physical or x > CLOSED_ABOVE:
            return {False}
        return {True} if x < OPEN_BELOW else {True, False}

    names = {(False, False): "constrained", (False, True): "lower_bound_only",
             (True, False): "upper_bound_only", (True, True): "unconstrained"}
    return {names[(lo, hi)] for lo in states(float(d[0]), lower_physical)
            for hi in states(float(d[1]), False)}


@dataclass
class ValidationReport:
    """Scores and per-scene rows."""

    metrics: dict[str, Any]
    scenes: list[dict[str, Any]]
    calibration: Calibration


def validate(table: ModelTable, n: int, seed: int = 0, *, workers: int = 1,
             scheduler: str | None = None, progress: bool = False,
             diameters: Sequence[float] | None = None,
             measurements: str | Path | None = None,
             truth_plate_theory: str = "auto",
             wrong_family: str | None = None,
             draw_material: bool = True,
             shots: int = SHOTS,
             near_support_m: float | None = None) -> ValidationReport:
    """Run the synthetic validation on ``table`` (see the module doc).

    ``diameters`` restricts the sphere sizes (default: all of the table's). ``measurements``
    names a JSON file that keeps the simulated, measured plates: when it holds the same draw
    (n, seed, sizes, table grid range and scene) they are reused and only the inversion runs.
    ``truth_plate_theory`` (``sem.plate_theory`` of the simulated plates: auto, 3d, mindlin)
    lets the truths come from another plate model than the table's, e.g. the 3-D plate behind a
    table built on the Mindlin plate, so the model's own error shows in the scores.
    ``wrong_family`` (a library material) simulates the truths on a plate of that material
    while the table is of its own: the reference plates (the calibration) stay of the table's
    family, as a user's reference block would be, and the scores say how often the answer is
    flagged (``inconsistent`` or ``out_of_range``) or covers the truth anyway
    (``flagged_or_covered``), and how often a constrained interval misses with no flag
    (``missed_unflagged``).
    ``draw_material`` gives each plate its own material, drawn from the spread of the table's
    plate material (:func:`draw_plate_materials`): the plates a user measures are of a grade,
    not of the table's exact properties, and the intervals carry that spread, so only plates
    drawn from it test that they carry it rightly. Off, every plate is the table's material
    exactly. The reference plates stay the table's material (a reference block's properties are
    known), and so do ``wrong_family`` truths (the library's value of that material).
    ``shots`` is the number of shots per plate and sphere size (a lab reading one shot at a time:
    1); the reference plates keep :data:`SHOTS`. ``near_support_m`` draws the distances
    uniformly between the table's nearest distance and this far from the support instead of over
    the whole table: the plates a scan next to a clamp measures.

    Raises
    ------
    ValidationInputError
        (``seed``, ``diameters``, ``measurements``, ``shots``, ``near_support_m``) A negative
        seed, a sphere size listed twice, a measurements file that is not one this function
        wrote, fewer than one shot, or a near-support band that holds no table distance.
    TableError
        (``diameter_m``) A sphere size the table does not hold.
    """
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValidationInputError("seed", f"must be an integer >= 0, got {seed!r}")
    rng = np.random.default_rng(seed)
    t_axis, l_axis = table.axes["thickness_m"], table.axes["distance_m"]
    if diameters is None:
        diameters = [float(d) for d in table.axes["diameter_m"]]
    else:
        diameters = [float(table.axes["diameter_m"][table.diameter_index(d)]) for d in diameters]
        if len(set(diameters)) < len(diameters):
            raise ValidationInputError("diameters", "a sphere size is listed twice (each table "
                                       "size at most once)")
    if truth_plate_theory not in ("auto", "3d", "mindlin"):
        raise ValidationInputError("truth_plate_theory", f"must be auto, 3d or mindlin, got "
                                   f"{truth_plate_theory!r}")
    from solitonde.model.materials import MATERIALS

    if wrong_family is not None and wrong_family not in MATERIALS:
        raise ValidationInputError("wrong_family", f"unknown material {wrong_family!r} (known: "
                                   f"{', '.join(sorted(MATERIALS))})")
    reference_base = table.sweep.get("scene", {})
    if truth_plate_theory != "auto":
        reference_base = apply_overrides(dict(reference_base),
                                         {"sem.plate_theory": truth_plate_theory})
    base = reference_base
    if wrong_family is not None:
        base = apply_overrides(dict(base), {"plate.material": wrong_family})
    if isinstance(shots, bool) or not isinstance(shots, int | np.integer) or shots < 1:
        raise ValidationInputError("shots", f"must be an integer >= 1, got {shots!r}")
    l_far = float(l_axis[-1])
    if near_support_m is not None:
        if not (isinstance(near_support_m, int | float) and math.isfinite(near_support_m)
                and near_support_m > l_axis[0]):
            raise ValidationInputError("near_support_m", f"must be a distance in m beyond the "
                                       f"table's nearest ({float(l_axis[0]):g} m), got "
                                       f"{near_support_m!r}")
        l_far = min(l_far, float(near_support_m))
    lo, hi = math.log(t_axis[0] * 1.01), math.log(t_axis[-1] / 1.01)
    draws = [(float(math.exp(rng.uniform(lo, hi))), float(rng.uniform(l_axis[0], l_far)))
             for _ in range(n)]
    seeds = rng.integers(0, 2**31, size=n + 1)
    t_ref = float(np.clip(REFERENCE_THICKNESS_M, t_axis[0], t_axis[-1]))
    l_ref = float(np.clip(REFERENCE_DISTANCE_M, l_axis[0], l_axis[-1]))
    spread = spread_of(table) if draw_material and wrong_family is None else None
    materials = (draw_plate_materials(table, spread, n, np.random.default_rng([seed, 3]))
                 if spread is not None else [None] * n)
    # the reference's task, then each plate's (with its shot count)
    tasks: list[tuple[Any, ...]] = [(reference_base, diameters, t_ref, l_ref, int(seeds[0]))]
    tasks += [(base if mat is None else apply_overrides(dict(base), {"plate.material": mat}),
               diameters, t, length, int(s), shots)
              for (t, length), s, mat in zip(draws, seeds[1:], materials, strict=True)]
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(tasks), unit="plate", desc="validate")
    key = {"n": n, "seed": seed, "diameters_m": diameters, "scene": base,
           "thickness_range_m": [float(t_axis[0]), float(t_axis[-1])],
           "distance_range_m": [float(l_axis[0]), float(l_axis[-1])],
           "damping_s": DAMPING_S, "shots": shots, "snr_db": SNR_DB,
           "wrong_family": wrong_family, "material_spread_drawn": spread,
           "reading_version": EXTRACTOR_VERSION}
    if near_support_m is not None:  # absent from the default draw's key: its files stay valid
        key["near_support_m"] = l_far
    stored = _load_measurements(measurements, key)
    started = time.perf_counter()
    if stored is not None:
        measured, wall = stored
    else:
        measured = []
        for res in run_tasks(measure_plate, tasks, workers, scheduler):
            measured.append(res)
            if bar is not None:
                bar.update(1)
        wall = time.perf_counter() - started
        if measurements is not None:
            _save_measurements(measurements, key, measured, wall)
    if bar is not None:
        bar.close()
    ref = next(m for m in measured if m["thickness_m"] == t_ref and m["distance_m"] == l_ref)
    measured.remove(ref)
    # the second reference plate (far from the supports: a cheap run) shows how far the fitted
    # factor and offset carry over between plates
    t_ref2 = float(np.clip(REFERENCE2_THICKNESS_M, t_axis[0], t_axis[-1]))
    ref2 = measure_plate(reference_base, diameters, t_ref2, l_ref,
                         int(np.random.default_rng([seed, 2]).integers(0, 2**31)))
    refs = [Reference(t_ref, l_ref, s) for s in _inputs(ref["summaries"]) if not s.hidden]
    refs += [Reference(t_ref2, l_ref, s) for s in _inputs(ref2["summaries"]) if not s.hidden]
    calibration = fit_calibration(table, refs)
    order = {(t, length): i for i, (t, length) in enumerate(draws)}
    drawn = {(t, length): mat for (t, length), mat in zip(draws, materials, strict=True)}
    measured.sort(key=lambda m: order[(m["thickness_m"], m["distance_m"])])

    rows = []
    for m in measured:
        inputs = _inputs(m["summaries"])
        row: dict[str, Any] = {"thickness_m": m["thickness_m"], "distance_m": m["distance_m"],
                               "n_sizes": len(inputs), "wall_s": m["wall_s"],
                               "plate_material": drawn[(m["thickness_m"], m["distance_m"])]}
        if not inputs:
            row.update(status_ok=False, reason="no reflection detected for any sphere size")
            rows.append(row)
            continue
        est = invert(table, inputs, calibration)
        t_est, l_est = est.thickness_m, est.distance_m
        true_l = m["distance_m"]
        true_t = m["thickness_m"]
        # What the data the inversion used can tell: a size it left out as disagreeing with the
        # others (see :func:`invert`) does not count towards the expected status either.
        excluded = est.extra.get("excluded_diameters_m", [])
        used = [i for i in inputs if i.diameter_m not in excluded and not i.hidden]
        phys = bool(l_axis[0] <= 0.0)
        ambiguous = t_est.status == "ambiguous"
        # an ambiguous answer covers when one of its readings does, and is flagged otherwise
        reading_covered = ambiguous and any(
            _covered(r.thickness_m.ci95, true_t) for r in est.readings)
        flagged = est.inconsistent or (ambiguous and not reading_covered)
        answered = t_est.status in ANSWERS and not flagged
        row.update(thickness=t_est.to_dict(), distance=l_est.to_dict(),
                   excluded_diameters_m=excluded, fit=est.fit, warnings=est.warnings,
                   hidden_diameters_m=[i.diameter_m for i in inputs if i.hidden],
                   flagged=flagged, answered=answered, ambiguous=ambiguous,
                   readings=[r.to_dict() for r in est.readings],
                   other_reading=est.extra.get("other_reading"))
        if used:
            sep = separations(table, used, true_t, true_l, calibration)
            # a slice (the other parameter at its true value) misses joint (t, L)
            # degeneracies, the profile flags every one however little posterior mass it
            # carries: both are answers the noise-free model supports, and both are scored
            # separately too
            exp_ts = expected_statuses(sep["thickness_m_slice"], lower_physical=False)
            exp_ls = expected_statuses(sep["distance_m_slice"], lower_physical=phys)
            exp_tp = expected_statuses(sep["thickness_m"], lower_physical=False)
            exp_lp = expected_statuses(sep["distance_m"], lower_physical=phys)
            row["separations"] = {k: v.tolist() for k, v in sep.items()}
        else:  # no reflection at all: the bound is what the data can tell
            exp_ts = exp_tp = {"upper_bound_only"}
            exp_ls = exp_lp = set(STATUSES)
        exp_t, exp_l = exp_ts | exp_tp, exp_ls | exp_lp
        two = _two_sided(t_est) if answered else None
        row.update(
            expected_thickness_status=sorted(exp_t), expected_distance_status=sorted(exp_l),
            status_ok=t_est.status in exp_t and l_est.status in exp_l,
            status_ok_slice=t_est.status in exp_ts and l_est.status in exp_ls,
            status_ok_profile=t_est.status in exp_tp and l_est.status in exp_lp,
            thickness_error=(abs(t_est.median - true_t) / true_t
                             if t_est.median is not None and not flagged else None),
            # every answer with its bounds: a one-sided one covers when its bound holds
            thickness_covered=(reading_covered if ambiguous else _covered(t_est.ci95, true_t))
            if answered else None,
            thickness_covered_two_sided=two[0] <= true_t <= two[1] if two else None,
            thickness_width=(two[1] - two[0]) / true_t if two else None,
            distance_covered=_covered(l_est.ci95, true_l) if not flagged else None,
        )
        rows.append(row)
    errors = np.array([r["thickness_error"] for r in rows if r.get("thickness_error") is not None])
    t_cov = [r["thickness_covered"] for r in rows if r.get("thickness_covered") is not None]
    t_cov2 = [r["thickness_covered_two_sided"] for r in rows
              if r.get("thickness_covered_two_sided") is not None]
    widths = [r["thickness_width"] for r in rows if r.get("thickness_width") is not None]
    l_cov = [r["distance_covered"] for r in rows if r.get("distance_covered") is not None]
    flags = [bool(r.get("flagged")) for r in rows]
    # a wrong family is handled when the answer is flagged or covers the truth anyway
    handled = [bool(r.get("flagged")) or bool(r.get("thickness_covered")) for r in rows]
    missed = [_missed_unflagged(r) for r in rows]
    # ... and of those, the ones no warning of another reading came with
    warned = [any(w.startswith(OTHER_READING_WARNING) for w in r.get("warnings") or [])
              for r in rows]
    unwarned = [m and not w for m, w in zip(missed, warned, strict=True)]
    metrics = {
        "n": n,
        "seed": seed,
        "thickness_error_median": float(np.median(errors)) if errors.size else None,
        "thickness_error_p90": float(np.percentile(errors, 90)) if errors.size else None,
        "coverage_95": float(np.mean(t_cov)) if t_cov else None,
        "coverage_95_two_sided": float(np.mean(t_cov2)) if t_cov2 else None,
        "answered": float(np.mean([bool(r.get("answered")) for r in rows])) if rows else None,
        "interval_width_median": float(np.median(widths)) if widths else None,
        "inconsistent_rate": float(np.mean(flags)) if rows else None,
        "flagged_or_covered": float(np.mean(handled)) if rows else None,
        "missed_unflagged": float(np.mean(missed)) if rows else None,
        "missed_unwarned": float(np.mean(unwarned)) if rows else None,
        "other_reading_rate": float(np.mean(warned)) if rows else None,
        "ambiguous_rate": float(np.mean([bool(r.get("ambiguous")) for r in rows]))
        if rows else None,
        "by_distance": by_distance(rows),
        "wrong_family": wrong_family,
        "material_spread_drawn": spread,
        "distance_coverage_95": float(np.mean(l_cov)) if l_cov else None,
        "status_accuracy": float(np.mean([r["status_ok"] for r in rows])) if rows else None,
        "status_accuracy_slice": float(np.mean([r.get("status_ok_slice", False) for r in rows])),
        "status_accuracy_profile": float(np.mean([r.get("status_ok_profile", False)
                                                  for r in rows])),
        "thickness_constrained": float(np.mean([r.get("thickness", {}).get("status")
                                                == "constrained" for r in rows])),
        "thickness_status_counts": _counts(r.get("thickness", {}).get("status") for r in rows),
        "distance_status_counts": _counts(r.get("distance", {}).get("status") for r in rows),
        "n_estimated": int(errors.size),
        "damping_s": DAMPING_S,
        "shots": shots,
        "near_support_m": None if near_support_m is None else l_far,
        "snr_db": SNR_DB,
        "reference": {"thickness_m": [t_ref, t_ref2], "distance_m": l_ref},
        "calibration": calibration.to_dict()["per_diameter"],
        "diameters_m": diameters,
        "truth_plate_theory": truth_plate_theory,
        "simulation_wall_s": wall,
        "table": str(table.path) if table.path else None,
    }
    return ValidationReport(metrics, rows, calibration)


def _load_measurements(path: str | Path | None,
                       key: Mapping[str, Any]) -> tuple[list[dict[str, Any]], float] | None:
    """The stored plates when ``path`` holds this draw; None when absent or another draw (it is
    then overwritten). Anything else is an error, never silently replaced: the file may be the
    user's."""
    if path is None:
        return None
    path = Path(path)
    if path.is_dir():
        raise ValidationInputError("measurements", f"{str(path)!r} is a directory; give the "
                                   "name of a JSON file")
    if not path.exists():
        return None

    def bad(why: str) -> ValidationInputError:
        return ValidationInputError("measurements", f"{str(path)!r} is not a measurements file "
                                    f"written by `solitonde validate` ({why}); delete it or "
                                    "give another path")

    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ValidationInputError("measurements", f"cannot read {str(path)!r}: "
                                   f"{exc.strerror or exc}") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise bad(f"not JSON: {exc}") from None
    if not isinstance(data, Mapping) or not {"key", "plates", "wall_s"} <= set(data):
        raise bad("needs the keys key, plates, wall_s")
    if data["key"] != json.loads(json.dumps(key)):
        return None
    plates = data["plates"]
    try:
        if not isinstance(plates, list) or len(plates) != int(key["n"]) + 1:
            raise TypeError(f"plates must be a list of {int(key['n']) + 1}")
        for m in plates:  # JSON keys are strings
            float(m["thickness_m"]), float(m["distance_m"])
            m["summaries"] = {float(d): s for d, s in m["summaries"].items()}
            for s in m["summaries"].values():
                if s is not None:
                    FeatureSummary.from_any({k: s.get(k) for k in (
                        "diameter_m", "tof_s", "arr", "arr_upper_bound")})
        wall = float(data["wall_s"])
    except (TypeError, ValueError, KeyError, AttributeError) as exc:
        raise bad(f"{type(exc).__name__}: {exc}") from None
    return plates, wall


def _save_measurements(path: str | Path, key: Mapping[str, Any], plates: list[dict[str, Any]],
                       wall: float) -> None:
    write_text(path, json.dumps({"key": key, "plates": plates, "wall_s": wall}))


def _missed_unflagged(row: Mapping[str, Any]) -> bool:
    """Whether a plate's answer misses its truth with nothing said: not flagged, not ambiguous,
    a thickness with bounds (two-sided or one-sided) that do not hold it."""
    status = row.get("thickness", {}).get("status")
    return (not row.get("flagged") and status in ANSWERS and status != "ambiguous"
            and row.get("thickness_covered") is False)


def by_distance(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """The scores per bin of the true distance to the support (:data:`DISTANCE_BINS_M`):
    plates, answered, the 95 % coverage, the unflagged misses and the ambiguous answers; a bin
    without plates is left out."""
    out = []
    for lo, hi in pairwise(DISTANCE_BINS_M):
        inside = [r for r in rows if r["distance_m"] >= lo and (hi is None or r["distance_m"] < hi)]
        if not inside:
            continue
        cov = [r["thickness_covered"] for r in inside if r.get("thickness_covered") is not None]
        out.append({"distance_m": [lo, hi], "n": len(inside),
                    "answered": float(np.mean([bool(r.get("answered")) for r in inside])),
                    "coverage_95": float(np.mean(cov)) if cov else None,
                    "missed_unflagged": float(np.mean([_missed_unflagged(r) for r in inside])),
                    "ambiguous_rate": float(np.mean([bool(r.get("ambiguous")) for r in inside]))})
    return out


def _two_sided(p: Any) -> tuple[float, float] | None:
    """A constrained answer's 95 % interval, or None for any other."""
    ci = p.ci95
    if p.status != "constrained" or ci is None or ci[0] is None or ci[1] is None:
        return None
    return float(ci[0]), float(ci[1])


def _covered(ci: Any, truth: float) -> bool | None:
    if ci is None:
        return None
    lo, hi = ci
    return (lo is None or lo <= truth) and (hi is None or truth <= hi)


def _counts(values: Any) -> dict[str, int]:
    out: dict[str, int] = {}
    for v in values:
        out[str(v)] = out.get(str(v), 0) + 1
    return out
