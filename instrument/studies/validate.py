"""Synthetic validation: random plates simulated, measured as real shots are, and inverted.

For each of ``n`` scenes (seeded): a thickness drawn log-uniformly and a distance to the support
drawn uniformly inside the table's range (so almost surely between its grid points), and a plate
material drawn from the spread of the table's (:func:`draw_plate_materials`: a plate of the grade,
as a user's is, not the table's exact properties; ``--exact-material`` turns it off), simulated
for every sphere size of the table with the plate model ``auto`` picks and with a known
dissipation the table does not have (Kuwabara-Kono contact damping, :data:`DAMPING_S`). Each
size's noise-free trace becomes :data:`SHOTS` shots with white noise at :data:`SNR_DB`, measured
and aggregated exactly as measured files of a stated sphere size are
(:func:`~solitonde.instrument.inference.shot_measure.measure_shot`: the drift fitted on the gap
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
(:data:`~.validate_scores.DISTANCE_BINS_M`); the distance's coverage (one-sided
bounds counted as such); and the status. A size whose shots show no reflection enters with its
ARR bound (instrument.inference.inversion).
The expected status is what the noise-free model says the data can tell. For each end of each
parameter's range, ``d`` is how many standard errors (the inversion's own sigmas,
:func:`~.validate_scores.separations`) separate the truth's features from the closest table point on
that end: along a slice (the other parameter at its true value) and along the profile (any value of
the other parameter). A side is open (the parameter is not bounded there) when ``d < 1.5``, closed
when ``d > 3``, either in between. The slice misses joint (t, L) degeneracies (a thin plate near a
support can mimic a thicker one far from it); the profile flags every one however little posterior
mass it carries; a status supported by either counts as right (``status_accuracy``), and each is
scored on its own as well (``status_accuracy_slice``, ``status_accuracy_profile``).
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
from pathlib import Path
from typing import Any, NotRequired, TypedDict, cast

import numpy as np

from solitonde.instrument.errors import InstrumentError
from solitonde.instrument.inference.calibration import Calibration, DiameterRecord
from solitonde.instrument.inference.calibration_fit import Reference, fit_calibration
from solitonde.instrument.inference.inversion_inputs import FeatureSummary
from solitonde.instrument.inference.material_spread import spread_of
from solitonde.instrument.inference.pipeline import SizeSummary
from solitonde.instrument.inference.shot_measure import measure_shot
from solitonde.instrument.parallel import run_tasks
from solitonde.instrument.studies.validate_scores import (
    OTHER_READING_WARNING,
    DistanceBinScore,
    DrawnMaterial,
    MeasuredPlate,
    MeasuredSize,
    PlateScore,
    by_distance,
    counts,
    missed_unflagged,
    plate_inputs,
    score_plate,
)
from solitonde.instrument.tables.measured import as_measured
from solitonde.instrument.tables.table import ModelTable
from solitonde.model.scene import SceneDict, apply_overrides, scene_from_dict
from solitonde.model.simulate import simulate
from solitonde.signal.atomic import write_text
from solitonde.signal.errors import WaveformError
from solitonde.signal.features import AGGREGATE_VERSION, EXTRACTOR_VERSION, aggregate
from solitonde.signal.synth import degrade

DAMPING_S = 1e-7
"""Known dissipation added to every validation shot: Kuwabara-Kono time constant tau, s (lowers
ARR by about 13 % for D = 4.76 mm, 7 % for 9.53 mm, 2 % for 19.05 mm)."""
SHOTS = 5
SNR_DB = 40.0
REFERENCE_THICKNESS_M = 5.5e-3
REFERENCE2_THICKNESS_M = 2.5e-3
REFERENCE_DISTANCE_M = 0.457


class ValidationInputError(InstrumentError, ValueError):
    """A validation request that cannot be run; ``field`` names what is wrong."""



TRUTH_MESH = "wavelength"
"""How a truth on the 3-D plate is meshed (in a stored draw's key): in-plane elements by the
flexural wavelength, as many as the Mindlin plate takes (``sem.elements_per_wavelength``), not
the 3-D plate's default ``sem.elements``."""


def plate_theory(scene: Mapping[str, Any]) -> str:
    """A scene dict's ``sem.plate_theory`` ("auto" where it names none)."""
    return str((scene.get("sem") or {}).get("plate_theory", "auto"))


def _scene_dict(base: Mapping[str, Any], d: float, t: float, length: float) -> SceneDict:
    """The scene of one plate and sphere size; on the 3-D plate with the Mindlin plate's
    in-plane elements (:data:`TRUTH_MESH`).

    The 3-D plate's default 16 x 16 elements do not resolve a thin plate's flexural waves:
    a 1.99 mm plate 47 mm from the clamp read ARR 0.110 on them, 0.081 and 0.080 on 36 x 18
    and 51 x 25 elements, where the Mindlin plate reads 0.081-0.083. A truth coarser than the
    table it tests would charge the table with the truth's own error."""
    scene = apply_overrides(dict(base), {
        "chain.diameter": d, "plate.thickness": t, "plate.distance_to_support": length,
        "effects.dissipation": True, "effects.damping": DAMPING_S,
    })
    if plate_theory(scene) == "3d":
        from solitonde.model.tiers.meshed import mindlin_elements

        scene = apply_overrides(scene, {
            "sem.elements": list(mindlin_elements(scene_from_dict(dict(scene))))})
    return scene


def measure_plate(base: Mapping[str, Any], diameters: Sequence[float], thickness_m: float,
                  distance_m: float, seed: int, shots: int = SHOTS,
                  snr_db: float = SNR_DB) -> MeasuredPlate:
    """Simulate one plate for every sphere size (largest first, one Green's function) and measure
    ``shots`` noisy shots of each: per-size summaries (None where no reflection was detected)."""
    from solitonde.model import greens

    rng = np.random.default_rng(seed)
    family = scene_from_dict(dict(base))
    plate_cache = greens.MemoryCache()  # one response serves every sphere size of this plate
    summaries: dict[float, MeasuredSize | None] = {}
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
        summaries[d] = None if size is None or size.skip_reason() is not None else cast(
            MeasuredSize, {**asdict(size.inputs()), "plate_model": result.plate_model})
    return {"thickness_m": thickness_m, "distance_m": distance_m, "summaries": summaries,
            "wall_s": time.perf_counter() - started}


def draw_plate_materials(table: ModelTable, spread: Mapping[str, float], n: int,
                         rng: np.random.Generator) -> list[DrawnMaterial]:
    """``n`` plates of the table's plate material as a grade's plates come: E, nu and rho each
    drawn from a normal distribution about the table's value with the grade's spread (relative
    sd for E and rho, sd for nu), as property mappings for ``plate.material``. Normal, with the
    spread the intervals state, so a coverage measured on them tests that statement."""
    props = table.family["plate_material"] if table.family else None
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


class ReferencePlates(TypedDict):
    """The reference plates the calibration was fitted on."""

    thickness_m: list[float]
    distance_m: float


class ValidationMetrics(TypedDict):
    """The scores of a validation run and what it ran with (``validate --json``, keys in
    order)."""

    n: int
    seed: int
    thickness_error_median: float | None
    thickness_error_p90: float | None
    coverage_95: float | None
    coverage_95_two_sided: float | None
    answered: float | None
    interval_width_median: float | None
    inconsistent_rate: float | None
    flagged_or_covered: float | None
    missed_unflagged: float | None
    missed_unwarned: float | None
    other_reading_rate: float | None
    ambiguous_rate: float | None
    by_distance: list[DistanceBinScore]
    wrong_family: str | None
    material_spread_drawn: dict[str, float] | None
    distance_coverage_95: float | None
    status_accuracy: float | None
    status_accuracy_slice: float
    status_accuracy_profile: float
    thickness_constrained: float
    thickness_status_counts: dict[str, int]
    distance_status_counts: dict[str, int]
    n_estimated: int
    damping_s: float
    shots: int
    near_support_m: float | None
    snr_db: float
    reference: ReferencePlates
    calibration: list[DiameterRecord]  # the calibration's own form (Calibration.to_dict)
    diameters_m: list[float]
    truth_plate_theory: str
    simulation_wall_s: float
    table: str | None


class DrawKey(TypedDict):
    """What a stored measurements file must match to be reused: the draw and how its shots were
    simulated and read."""

    n: int
    seed: int
    diameters_m: list[float]
    scene: SceneDict  # the table's scene, as its sweep stores it
    thickness_range_m: list[float]
    distance_range_m: list[float]
    damping_s: float
    shots: int
    snr_db: float
    wrong_family: str | None
    material_spread_drawn: dict[str, float] | None
    reading_version: Any
    aggregate_version: int
    near_support_m: NotRequired[float]
    truth_mesh: NotRequired[str]


@dataclass(frozen=True)
class Draw:
    """The plates of one run: each one's truth (thickness, distance) and material, the seeds of
    their noise (the first the reference plate's), and the reference plate."""

    plates: list[tuple[float, float]]
    seeds: list[int]
    materials: list[DrawnMaterial | None]
    spread: dict[str, float] | None
    t_ref: float
    l_ref: float
    l_far: float


@dataclass
class ValidationReport:
    """Scores and per-scene rows."""

    metrics: ValidationMetrics
    scenes: list[PlateScore]
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
    table built on the Mindlin plate, so the model's own error shows in the scores (the 3-D
    truths meshed as finely as the Mindlin plate: :func:`_scene_dict`).
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
    _check_count("seed", seed, 0)
    sizes = _sizes(table, diameters)
    reference_base, base = _bases(table, truth_plate_theory, wrong_family)
    _check_count("shots", shots, 1)
    draw = _draw(table, n, seed, _far_end(table, near_support_m),
                 draw_material and wrong_family is None)
    # the reference's task, then each plate's (with its shot count)
    tasks: list[tuple[Any, ...]] = [(reference_base, sizes, draw.t_ref, draw.l_ref,
                                     draw.seeds[0])]
    tasks += [(base if mat is None else apply_overrides(dict(base), {"plate.material": mat}),
               sizes, t, length, s, shots)
              for (t, length), s, mat in zip(draw.plates, draw.seeds[1:], draw.materials,
                                             strict=True)]
    key = _draw_key(table, n, seed, sizes, base, shots, wrong_family, draw,
                    near_support_m is not None)
    measured, wall = _measured(tasks, key, measurements, workers, scheduler, progress)
    ref = next(m for m in measured
               if m["thickness_m"] == draw.t_ref and m["distance_m"] == draw.l_ref)
    measured.remove(ref)
    calibration, t_ref2 = _calibration(table, ref, reference_base, sizes, draw, seed)
    order = {plate: i for i, plate in enumerate(draw.plates)}
    drawn = dict(zip(draw.plates, draw.materials, strict=True))
    measured.sort(key=lambda m: order[(m["thickness_m"], m["distance_m"])])
    rows = [score_plate(table, m, calibration, drawn[(m["thickness_m"], m["distance_m"])])
            for m in measured]
    run = Run(n, seed, shots, None if near_support_m is None else draw.l_far, wrong_family,
              draw.spread, [draw.t_ref, t_ref2], draw.l_ref, sizes, truth_plate_theory, wall,
              str(table.path) if table.path else None)
    return ValidationReport(_metrics(rows, run, calibration), rows, calibration)


def _check_count(field: str, value: int, least: int) -> None:
    """An integer (not a bool) of at least ``least``, else a ValidationInputError naming
    ``field``."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < least:
        raise ValidationInputError(field, f"must be an integer >= {least}, got {value!r}")


def _sizes(table: ModelTable, diameters: Sequence[float] | None) -> list[float]:
    """The table's sphere sizes closest to ``diameters`` (all of them when None), each at most
    once."""
    if diameters is None:
        return [float(d) for d in table.axes["diameter_m"]]
    sizes = [float(table.axes["diameter_m"][table.diameter_index(d)]) for d in diameters]
    if len(set(sizes)) < len(sizes):
        raise ValidationInputError("diameters", "a sphere size is listed twice (each table "
                                   "size at most once)")
    return sizes


def _bases(table: ModelTable, truth_plate_theory: str,
           wrong_family: str | None) -> tuple[SceneDict, SceneDict]:
    """The scenes of the reference plates and of the truths: the table's, on the plate theory
    asked for, the truths on ``wrong_family``'s material where given."""
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
    return reference_base, base


def _far_end(table: ModelTable, near_support_m: float | None) -> float:
    """The largest distance drawn: the table's, or ``near_support_m`` where nearer."""
    l_axis = table.axes["distance_m"]
    l_far = float(l_axis[-1])
    if near_support_m is None:
        return l_far
    if not (isinstance(near_support_m, int | float) and math.isfinite(near_support_m)
            and near_support_m > l_axis[0]):
        raise ValidationInputError("near_support_m", f"must be a distance in m beyond the "
                                   f"table's nearest ({float(l_axis[0]):g} m), got "
                                   f"{near_support_m!r}")
    return min(l_far, float(near_support_m))


def _draw(table: ModelTable, n: int, seed: int, l_far: float, draw_material: bool) -> Draw:
    """``n`` plates drawn from ``seed``: thickness log-uniform and distance uniform inside the
    table's range, each plate's material from the table material's spread (with
    ``draw_material``), and the reference plate."""
    rng = np.random.default_rng(seed)
    t_axis, l_axis = table.axes["thickness_m"], table.axes["distance_m"]
    lo, hi = math.log(t_axis[0] * 1.01), math.log(t_axis[-1] / 1.01)
    plates = [(float(math.exp(rng.uniform(lo, hi))), float(rng.uniform(l_axis[0], l_far)))
              for _ in range(n)]
    seeds = [int(s) for s in rng.integers(0, 2**31, size=n + 1)]
    spread = spread_of(table) if draw_material else None
    materials: list[DrawnMaterial | None] = (
        list(draw_plate_materials(table, spread, n, np.random.default_rng([seed, 3])))
        if spread is not None else [None] * n)
    return Draw(plates, seeds, materials, spread,
                t_ref=float(np.clip(REFERENCE_THICKNESS_M, t_axis[0], t_axis[-1])),
                l_ref=float(np.clip(REFERENCE_DISTANCE_M, l_axis[0], l_axis[-1])), l_far=l_far)


def _draw_key(table: ModelTable, n: int, seed: int, sizes: list[float], base: SceneDict,
              shots: int, wrong_family: str | None, draw: Draw, near_support: bool) -> DrawKey:
    """What a stored measurements file must hold to be this run's."""
    t_axis, l_axis = table.axes["thickness_m"], table.axes["distance_m"]
    key: DrawKey = {"n": n, "seed": seed, "diameters_m": sizes, "scene": base,
                    "thickness_range_m": [float(t_axis[0]), float(t_axis[-1])],
                    "distance_range_m": [float(l_axis[0]), float(l_axis[-1])],
                    "damping_s": DAMPING_S, "shots": shots, "snr_db": SNR_DB,
                    "wrong_family": wrong_family, "material_spread_drawn": draw.spread,
                    "reading_version": EXTRACTOR_VERSION,
                    "aggregate_version": AGGREGATE_VERSION}
    if near_support:  # absent from the default draw's key: its files stay valid
        key["near_support_m"] = draw.l_far
    if plate_theory(base) == "3d":  # truths on the resolved 3-D plate
        key["truth_mesh"] = TRUTH_MESH
    return key


def _measured(tasks: list[tuple[Any, ...]], key: DrawKey, measurements: str | Path | None,
              workers: int, scheduler: str | None,
              progress: bool) -> tuple[list[MeasuredPlate], float]:
    """Every plate simulated and measured, or read back from ``measurements`` where it holds
    this draw (then written there); the simulations' wall time."""
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(tasks), unit="plate", desc="validate")
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
    return measured, wall


def _calibration(table: ModelTable, ref: MeasuredPlate, reference_base: SceneDict,
                 sizes: list[float], draw: Draw, seed: int) -> tuple[Calibration, float]:
    """The calibration fitted on the reference plate and a second one, thinner (far from the
    supports: a cheap run), which shows how far the fitted factor and offset carry over between
    plates; the second plate's thickness."""
    t_axis = table.axes["thickness_m"]
    t_ref2 = float(np.clip(REFERENCE2_THICKNESS_M, t_axis[0], t_axis[-1]))
    ref2 = measure_plate(reference_base, sizes, t_ref2, draw.l_ref,
                         int(np.random.default_rng([seed, 2]).integers(0, 2**31)))
    refs = [Reference(draw.t_ref, draw.l_ref, s) for s in plate_inputs(ref["summaries"])
            if not s.hidden]
    refs += [Reference(t_ref2, draw.l_ref, s) for s in plate_inputs(ref2["summaries"])
             if not s.hidden]
    return fit_calibration(table, refs), t_ref2


@dataclass(frozen=True)
class Run:
    """What a validation ran with, as its metrics state it."""

    n: int
    seed: int
    shots: int
    near_support_m: float | None
    wrong_family: str | None
    spread: dict[str, float] | None
    reference_thickness_m: list[float]
    reference_distance_m: float
    diameters_m: list[float]
    truth_plate_theory: str
    simulation_wall_s: float
    table: str | None


def _mean(values: Sequence[bool | float]) -> float | None:
    """The mean of ``values`` (booleans as 0 and 1), None when there are none."""
    return float(np.mean(values)) if values else None


def _metrics(rows: list[PlateScore], run: Run, calibration: Calibration) -> ValidationMetrics:
    """The scores over the plates (see the module doc) and what the run was."""
    errors = np.array([r["thickness_error"] for r in rows if r.get("thickness_error") is not None])
    t_cov = [c for r in rows if (c := r.get("thickness_covered")) is not None]
    t_cov2 = [c for r in rows if (c := r.get("thickness_covered_two_sided")) is not None]
    widths = [w for r in rows if (w := r.get("thickness_width")) is not None]
    l_cov = [c for r in rows if (c := r.get("distance_covered")) is not None]
    flags = [bool(r.get("flagged")) for r in rows]
    # a wrong family is handled when the answer is flagged or covers the truth anyway
    handled = [bool(r.get("flagged")) or bool(r.get("thickness_covered")) for r in rows]
    missed = [missed_unflagged(r) for r in rows]
    # ... and of those, the ones no warning of another reading came with
    warned = [any(w.startswith(OTHER_READING_WARNING) for w in r.get("warnings") or [])
              for r in rows]
    unwarned = [m and not w for m, w in zip(missed, warned, strict=True)]
    return {
        "n": run.n,
        "seed": run.seed,
        "thickness_error_median": float(np.median(errors)) if errors.size else None,
        "thickness_error_p90": float(np.percentile(errors, 90)) if errors.size else None,
        "coverage_95": _mean(t_cov),
        "coverage_95_two_sided": _mean(t_cov2),
        "answered": _mean([bool(r.get("answered")) for r in rows]),
        "interval_width_median": float(np.median(widths)) if widths else None,
        "inconsistent_rate": _mean(flags),
        "flagged_or_covered": _mean(handled),
        "missed_unflagged": _mean(missed),
        "missed_unwarned": _mean(unwarned),
        "other_reading_rate": _mean(warned),
        "ambiguous_rate": _mean([bool(r.get("ambiguous")) for r in rows]),
        "by_distance": by_distance(rows),
        "wrong_family": run.wrong_family,
        "material_spread_drawn": run.spread,
        "distance_coverage_95": _mean(l_cov),
        "status_accuracy": _mean([r["status_ok"] for r in rows]),
        "status_accuracy_slice": float(np.mean([r.get("status_ok_slice", False) for r in rows])),
        "status_accuracy_profile": float(np.mean([r.get("status_ok_profile", False)
                                                  for r in rows])),
        "thickness_constrained": float(np.mean([r.get("thickness", {}).get("status")
                                                == "constrained" for r in rows])),
        "thickness_status_counts": counts(r.get("thickness", {}).get("status") for r in rows),
        "distance_status_counts": counts(r.get("distance", {}).get("status") for r in rows),
        "n_estimated": int(errors.size),
        "damping_s": DAMPING_S,
        "shots": run.shots,
        "near_support_m": run.near_support_m,
        "snr_db": SNR_DB,
        "reference": {"thickness_m": run.reference_thickness_m,
                      "distance_m": run.reference_distance_m},
        "calibration": calibration.to_dict()["per_diameter"],
        "diameters_m": run.diameters_m,
        "truth_plate_theory": run.truth_plate_theory,
        "simulation_wall_s": run.simulation_wall_s,
        "table": run.table,
    }


def _load_measurements(path: str | Path | None,
                       key: DrawKey) -> tuple[list[MeasuredPlate], float] | None:
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


def _save_measurements(path: str | Path, key: DrawKey, plates: list[MeasuredPlate],
                       wall: float) -> None:
    write_text(path, json.dumps({"key": key, "plates": plates, "wall_s": wall}))
