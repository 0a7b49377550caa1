"""The scan as one unknown, validated: simulated scans of random plates inverted jointly
(instrument.inference.joint_map) against position by position, and the next position chosen by
the joint posterior (instrument.inference.suggest) against at random.

Each scan (seeded): a plate of the table's family, its thickness drawn log-uniformly inside the
table's range as :mod:`.validate` draws it; the plate's rectangle is the scan's frame
``[0, a] x [0, b]`` (the family's size), and its clamped edge a line near one of the
rectangle's sides (which side at random), tilted by up to :data:`TILT_DEG` and set in by up to
:data:`INSET_M`: a random angle and offset; the opposite clamped edge lies the plate's length
``a`` from it. Positions stand at distances from the edge drawn log-uniformly in
:data:`DISTANCE_RANGE_M` (an operator looking for the support measures near it, some further
away) and anywhere along it inside the rectangle. Its chain stands off those recorded
coordinates by the joint map's stated coordinate error (a normal draw of
:data:`~solitonde.instrument.inference.joint_likelihood.POSITION_SD_M` per coordinate; off with
``exact_positions``), and there every position is simulated, measured and
calibrated exactly as :func:`.validate.measure_plate` does (the tier ``auto`` picks, or the 3-D
plate where it would pick the 2-D one with ``truth_plate_theory="3d"``, a
Kuwabara-Kono dissipation the elastic table lacks, 5 shots at 40 dB, one sphere size, the
chain's damping (with the table's dissipation layer), an ARR factor and TOF offset fitted on two
reference plates).

Scored per scan with 3-10 positions (:data:`POSITIONS`):

* thickness coverage of every position's 95 % answer (one-sided bounds count when they hold, as
  in :mod:`.validate`), joint (thickness free per position; and tied with a common mean, 5 %
  spread) against position by position;
* the edge offset's 95 % coverage: the joint posterior's against the per-position fit of
  :mod:`~solitonde.instrument.inference.edge_fit`, with its binomial standard error and each
  miss in the sds its interval states (:func:`_z`; the angle's and the edge's at the scan too):
  30 scans tell a coverage of 0.967 from 1.000 and nothing finer;
* the width of the thickness interval at positions within :data:`NEAR_EDGE_M` of the edge (an
  open side reaches the table's end, so a bound or no answer is as wide as the table allows);
* the edge's error against the number of positions: starting from the scan's first three, one
  position added at a time, up to :data:`MAX_POSITIONS`: the suggestion of the joint posterior
  (objective ``edge``), or a random one drawn as the first three were (near the true edge: an
  operator who already knows roughly where the support is), or a random one anywhere on the
  plate. The error is the largest distance between
  the located edge (the joint posterior's best) and the true one along the true edge's span
  inside the rectangle; the count is the number of positions at which it first falls below
  :data:`TARGET_ERROR_M`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Literal, TypedDict, cast

import numpy as np

from solitonde.instrument.inference import joint_map, suggest
from solitonde.instrument.inference.calibration import Calibration
from solitonde.instrument.inference.edge_fit import locate
from solitonde.instrument.inference.inversion import invert
from solitonde.instrument.inference.inversion_inputs import FeatureSummary
from solitonde.instrument.inference.joint_likelihood import POSITION_SD_M
from solitonde.instrument.inference.joint_summary import JointAnswer
from solitonde.instrument.studies import validate as single  # noqa: F401 (measures the positions)
from solitonde.instrument.studies.map_measurer import (
    Measurer,
    StudyInputError,
    reference_calibration,
    references,
)
from solitonde.instrument.studies.map_metrics import (
    NEAR_EDGE_M,
    START_POSITIONS,
    STRATEGIES,
    TARGET_ERROR_M,
    MapMetrics,
    StudyResult,
    summarise,
)
from solitonde.instrument.studies.map_rows import (
    EdgeAtScan,
    EdgeScore,
    PositionScore,
    ScanRow,
    SequenceScore,
    SplitRow,
    ThicknessScore,
)
from solitonde.instrument.studies.map_scan import (
    DISTANCE_RANGE_M,
    MAX_POSITIONS,
    POSITIONS,
    TILT_DEG,
    Scan,
    stood,
)
from solitonde.instrument.studies.validate_scores import ANSWERS
from solitonde.instrument.tables.table import ModelTable
from solitonde.model.scene import SceneDict, apply_overrides

COMMON_SPREAD = 0.05
TRUTH_PLATE_THEORIES = ("auto", "3d", "mindlin")
"""``sem.plate_theory`` of the simulated plates (:func:`run`)."""


def _covered(ci: Sequence[float | None] | None, truth: float) -> bool:
    lo, hi = ci or (None, None)
    return (lo is None or lo <= truth) and (hi is None or truth <= hi)


def _answered(p: Mapping[str, Any]) -> bool:
    return p.get("status") in ANSWERS


def _width(p: Mapping[str, Any], t_range: tuple[float, float]) -> float:
    """The 95 % interval's width with an open side at the table's end (no answer: the table)."""
    lo, hi = (p.get("ci95") or (None, None)) if _answered(p) else (None, None)
    return (hi if hi is not None else t_range[1]) - (lo if lo is not None else t_range[0])


def _scan_positions(scan: Scan, xy: Sequence[tuple[float, float]], measure: Measurer,
                    cal: Calibration) -> list[joint_map.ScanPosition]:
    out = []
    for k, ((x, y), (length, seed)) in enumerate(zip(xy, stood(scan, xy), strict=True)):
        inputs = measure(scan.diameter_m, scan.thickness_m, length, seed)
        out.append(joint_map.ScanPosition(f"P{k + 1:02d}", x, y, inputs, cal))
    return out


def _joint_edge(table: ModelTable, positions: Sequence[joint_map.ScanPosition],
                shared_calibration: bool = False
                ) -> tuple[joint_map.JointPosterior | None, float, float]:
    try:
        post = joint_map.posterior(table, positions, shared_calibration=shared_calibration)
    except joint_map.JointMapError:
        return None, math.nan, math.nan
    theta, offset = joint_map.median_edge(post)
    return post, theta, offset


def score_scan(table: ModelTable, scan: Scan, measure: Measurer, cal: Calibration,
               sequential: bool = True, shared_calibration: bool = False) -> ScanRow:
    """One scan's rows: per position the three answers against the truth, the edge's coverage,
    and (``sequential``) the edge's error as positions are added, suggested or random."""
    t_range = (float(table.axes["thickness_m"][0]), float(table.axes["thickness_m"][-1]))
    xy = scan.random_positions[:scan.n_positions]
    positions = _scan_positions(scan, xy, measure, cal)
    alone: list[Mapping[str, Any] | None] = []
    for p in positions:
        found = invert(table, p.inputs, cal) if p.inputs else None
        alone.append(None if found is None else found.to_dict())
    joint: dict[str, JointAnswer | None] = {}
    at_scan: dict[str, EdgeAtScan] = {}
    for kind in ("free", "common"):
        try:
            post = joint_map.posterior(table, positions, joint_map.ThicknessPrior(
                kind, COMMON_SPREAD), shared_calibration=shared_calibration)
            joint[kind] = joint_map.summary(post)
            at_scan[kind] = _edge_at_scan(post, scan)
        except joint_map.JointMapError:
            joint[kind] = None
    fit, reason = locate([{"x_m": p.x_m, "y_m": p.y_m, "distance_m": (e or {}).get("distance_m")}
                          for p, e in zip(positions, alone, strict=True)])
    edge_alone: EdgeScore = {"reason": reason} if fit is None else {
        "ci95_offset_m": list(fit.ci95_offset_m), "offset_m": fit.offset_m,
        "normal_angle_deg": fit.normal_angle_deg,
        "covered": _offset_covered(fit.to_dict(), scan),
        "offset_z": _offset_z(fit.to_dict(), scan),
        "error_m": scan.edge_error(math.radians(fit.normal_angle_deg), fit.offset_m)}
    row: ScanRow = {
        "seed": scan.seed, "thickness_m": scan.thickness_m,
        "normal_angle_deg": math.degrees(scan.theta), "offset_m": scan.offset_m,
        "n_positions": scan.n_positions,
        "positions": _position_scores(scan, positions, alone, joint, t_range),
        # the edge's offset: joint against the per-position fit
        "edge_free": _joint_edge_score(joint["free"], at_scan.get("free"), scan),
        "edge_common": _joint_edge_score(joint["common"], at_scan.get("common"), scan),
        "edge_alone": edge_alone}
    if sequential:
        row["sequence"] = _sequence(table, scan, measure, cal, shared_calibration)
    return row


def _thickness_score(answer: Mapping[str, Any], scan: Scan,
                     t_range: tuple[float, float]) -> ThicknessScore:
    return {"status": answer.get("status"), "ci95": answer.get("ci95"),
            "covered": (_covered(answer.get("ci95"), scan.thickness_m)
                        if _answered(answer) else None),
            "width_m": _width(answer, t_range)}


def _position_scores(scan: Scan, positions: Sequence[joint_map.ScanPosition],
                     alone: Sequence[Mapping[str, Any] | None],
                     joint: Mapping[str, JointAnswer | None],
                     t_range: tuple[float, float]) -> list[PositionScore]:
    """Each position's three thickness answers (its own, the joint map's free and common)
    against the plate's thickness."""
    by_name = {k: {p["position"]: p for p in (j["positions"] if j else [])}
               for k, j in joint.items()}
    none = {"status": "none"}
    out: list[PositionScore] = []
    for p, est in zip(positions, alone, strict=True):
        answers = {"alone": (est or {}).get("thickness_m") or none}
        for kind in joint:
            row = by_name[kind].get(p.name)
            answers[kind] = (row["thickness_m"] if row else None) or none
        scores = {k: _thickness_score(a, scan, t_range) for k, a in answers.items()}
        out.append({"x_m": p.x_m, "y_m": p.y_m, "distance_m": scan.distance(p.x_m, p.y_m),
                    "alone": scores["alone"], "free": scores["free"],
                    "common": scores["common"]})
    return out


def _joint_edge_score(answer: JointAnswer | None, at_scan: EdgeAtScan | None,
                      scan: Scan) -> EdgeScore | None:
    """The joint map's located edge against the true one (None where it gave no answer)."""
    if answer is None:
        return None
    s = answer["support"]
    score: EdgeScore = {
        "ci95_offset_m": s["ci95_offset_m"], "offset_m": s["offset_m"],
        "normal_angle_deg": s["normal_angle_deg"],
        "covered": _offset_covered(s, scan), "offset_z": _offset_z(s, scan),
        "fit": answer["fit"],
        "error_m": scan.edge_error(math.radians(s["normal_angle_deg"]), s["offset_m"])}
    if at_scan is not None:
        score.update(at_scan)
    return score


def _edge_at_scan(post: joint_map.JointPosterior, scan: Scan) -> EdgeAtScan:
    """The edge's two parameters as the scan sees them: its direction (the 95 % interval of
    the normal's angle) and where it lies at the scan (the 95 % interval of the positions'
    centroid's distance from it), each with whether it holds the truth. The offset in the
    frame mixes both: at the frame's origin, far along the edge from the scan, an angle's error
    moves it by the lever arm times the angle."""
    theta_b = float(post.cells.theta[post.best])
    flip = math.cos(theta_b - scan.theta) < 0  # the located edge seen from the other side
    n_true = -scan.normal if flip else scan.normal
    truth_theta = (scan.theta + math.pi) if flip else scan.theta
    rel = (post.cells.theta - truth_theta + math.pi) % (2 * math.pi) - math.pi
    a_lo, a_hi = joint_map.weighted_quantiles(rel, post.mass, (0.025, 0.975))
    c_true = float(post.anchor @ n_true) - scan.true_offset(theta_b)
    c_lo, c_hi = joint_map.weighted_quantiles(post.cells.c, post.mass, (0.025, 0.975))
    return {"angle_ci95_width_deg": math.degrees(a_hi - a_lo),
            "angle_covered": bool(a_lo <= 0.0 <= a_hi), "angle_z": _z(0.0, a_lo, a_hi),
            "at_scan_ci95_width_m": c_hi - c_lo, "at_scan_covered": bool(c_lo <= c_true <= c_hi),
            "at_scan_z": _z(c_true, c_lo, c_hi),
            "lever_m": float(abs(post.anchor @ np.array([-n_true[1], n_true[0]])))}


def _offset_covered(support: Mapping[str, Any], scan: Scan) -> bool:
    """Whether the 95 % offset interval holds the true edge's offset (of the clamped edge the
    located one stands for)."""
    lo, hi = support["ci95_offset_m"]
    return bool(lo <= scan.true_offset(math.radians(support["normal_angle_deg"])) <= hi)


def _z(truth: float, lo: float, hi: float) -> float:
    """The truth's distance from a 95 % interval's middle in the sds the interval states (its
    half-width over 1.96): over many answers whose intervals are as wide as their errors, an
    rms of 1, and 95 % of them within 1.96. A coverage counts only whether |z| < 1.96."""
    half = 0.5 * (hi - lo)
    return float((truth - 0.5 * (lo + hi)) / (half / 1.96)) if half > 0 else math.nan


def _offset_z(support: Mapping[str, Any], scan: Scan) -> float:
    lo, hi = support["ci95_offset_m"]
    return _z(scan.true_offset(math.radians(support["normal_angle_deg"])), lo, hi)


def _sequence(table: ModelTable, scan: Scan, measure: Measurer, cal: Calibration,
              shared_calibration: bool = False) -> dict[str, SequenceScore]:
    """Per strategy (:data:`STRATEGIES`), the edge's error as positions are added to the
    scan's first three."""
    out: dict[str, SequenceScore] = {}
    for strategy in STRATEGIES:
        xy = list(scan.random_positions[:START_POSITIONS])
        fallback = (scan.plate_positions if strategy == "random_on_plate"
                    else scan.random_positions)
        errors: list[float] = []
        while True:
            positions = _scan_positions(scan, xy, measure, cal)
            post, theta, offset = _joint_edge(table, positions, shared_calibration)
            errors.append(math.inf if post is None else scan.edge_error(theta, offset))
            if len(xy) >= MAX_POSITIONS:
                break
            if strategy != "suggested" or post is None:
                xy.append(fallback[len(xy)])
                continue
            nxt = suggest.suggest(post, 1, objective="edge", region=(0.0, scan.a, 0.0, scan.b))
            if not nxt["suggestions"]:
                xy.append(scan.random_positions[len(xy)])
                continue
            s = nxt["suggestions"][0]
            xy.append((s["x_m"], s["y_m"]))
        reached = next((START_POSITIONS + k for k, e in enumerate(errors)
                        if e <= TARGET_ERROR_M), None)
        out[strategy] = {"errors_m": errors, "positions_to_target": reached,
                         "xy": [list(p) for p in xy]}
    return out


def run(table: ModelTable, n_scans: int, seed: int = 0, *, diameter_m: float | None = None,
        measurements: str | Path | None = None, sequential: bool = True,
        progress: Callable[[str, int, int], None] | None = None,
        shared_calibration: bool = False, exact_positions: bool = False,
        truth_plate_theory: str = "auto", workers: int = 1) -> StudyResult:
    """The study (see the module doc): per-scan rows and the summary metrics.
    ``shared_calibration``: the joint maps draw the calibration's TOF offset error once per
    scan (:func:`~solitonde.instrument.inference.joint_map.posterior`). Each position's chain
    stands off its recorded coordinates by the error the joint map states for them
    (:data:`~solitonde.instrument.inference.joint_likelihood.POSITION_SD_M` per coordinate), so the
    study tests that statement; ``exact_positions`` puts it exactly there.
    ``truth_plate_theory`` (``sem.plate_theory`` of every simulated plate, the reference plates
    included, as :func:`.validate.validate` does): ``3d`` simulates next to a support on the 3-D
    plate while the table holds the 2-D plate there, so the 2-D plate's own error, which the
    intervals state, is in the truths too. ``workers`` simulate the scans' first positions
    (all of them without ``sequential``) in parallel before the scans are scored."""
    if isinstance(n_scans, bool) or not isinstance(n_scans, int) or n_scans < 1:
        raise StudyInputError("scans", f"must be an integer >= 1, got {n_scans!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise StudyInputError("seed", f"must be an integer >= 0, got {seed!r}")
    sizes = [float(d) for d in table.axes["diameter_m"]]
    if diameter_m is None:
        diameter_m = min(sizes, key=lambda d: abs(d - 9.53e-3))
    else:
        diameter_m = float(table.axes["diameter_m"][table.diameter_index(diameter_m)])
    if truth_plate_theory not in TRUTH_PLATE_THEORIES:
        raise StudyInputError("truth_plate_theory", f"must be one of "
                              f"{', '.join(TRUTH_PLATE_THEORIES)}, got {truth_plate_theory!r}")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise StudyInputError("workers", f"must be an integer >= 1, got {workers!r}")
    base = SceneDict(**table.sweep.get("scene", {}))
    if truth_plate_theory != "auto":
        base = apply_overrides(base, {"sem.plate_theory": truth_plate_theory})
    measure = Measurer(base, measurements)
    started = time.perf_counter()
    coordinate_sd_m = 0.0 if exact_positions else POSITION_SD_M
    scans = [Scan(table, int(np.random.default_rng([seed, k]).integers(0, 2**31)), diameter_m,
                  coordinate_sd_m) for k in range(n_scans)]
    requests = references(table, diameter_m, seed * 1000 + 1)
    for scan in scans:
        lists = [scan.random_positions[:scan.n_positions]]
        if sequential:
            lists += [scan.random_positions,
                      scan.random_positions[:START_POSITIONS]
                      + scan.plate_positions[START_POSITIONS:]]
        for xy in lists:
            requests += [(diameter_m, scan.thickness_m, length, s)
                         for length, s in stood(scan, xy)]
    measure.prefetch(requests, workers, progress)
    measure.save()
    cal = reference_calibration(table, measure, diameter_m, seed * 1000 + 1)
    rows: list[ScanRow] = []
    for k, scan in enumerate(scans):
        rows.append(score_scan(table, scan, measure, cal, sequential, shared_calibration))
        measure.save()
        if progress is not None:
            progress("scans scored", k + 1, n_scans)
    metrics: MapMetrics = {
        **summarise(rows), "n_scans": n_scans, "seed": seed, "diameter_m": diameter_m,
        "shared_calibration": shared_calibration, "coordinate_sd_m": coordinate_sd_m,
        "truth_plate_theory": truth_plate_theory, "simulated_positions": measure.simulated,
        "simulation_wall_s": measure.wall_s, "wall_s": time.perf_counter() - started,
        "calibration": cal.to_dict()["per_diameter"],
        "table": str(table.path) if table.path else None}
    return {"metrics": metrics, "scans": rows}


SplitStep = Literal["alone", "distance_known", "no_material_spread",
                    "no_calibration_uncertainty", "no_table_error"]
SPLIT_STEPS: tuple[SplitStep, ...] = ("alone", "distance_known", "no_material_spread",
                                      "no_calibration_uncertainty", "no_table_error")
"""The near-edge width split, each step removing one more source of a position's thickness
interval: the distance (known exactly), the material's spread, the calibration's stated
uncertainty, the table's interpolation error; what is left is the shots' noise."""


def _width_at_distance(table: ModelTable, inputs: Sequence[FeatureSummary],
                       cal: Calibration | None, spread: Mapping[str, float] | None,
                       distance_m: float, t_range: tuple[float, float]) -> float:
    """The 95 % thickness interval's width (an open side to the table's end) of a position's
    own likelihood at a known distance, by a single inversion's rules."""
    from solitonde.instrument.inference.likelihood import cell_likelihood
    from solitonde.instrument.inference.marginals import summarise_marginal

    keep = cell_likelihood(table, inputs, cal, material_spread=spread)
    dev, g = keep["deviance"], keep["grid"]
    ok = np.isfinite(dev)
    if not ok.any():
        return t_range[1] - t_range[0]
    like = np.where(ok, np.exp(-0.5 * (np.where(ok, dev, 0.0) - dev[ok].min())), 0.0)
    grid = g.distance_m
    j = int(np.clip(np.searchsorted(grid, distance_m) - 1, 0, grid.size - 2))
    f = float(np.clip((distance_m - grid[j]) / (grid[j + 1] - grid[j]), 0.0, 1.0))
    col = (1.0 - f) * like[:, j] + f * like[:, j + 1]
    if col.max() <= 0:
        return t_range[1] - t_range[0]
    mass = col * g.weight_t
    est = summarise_marginal(np.log(g.thickness_m), mass / mass.sum(), g.weight_t,
                             lower_physical=False, transform=np.exp, profile=col / col.max())
    return _width(est.to_dict(), t_range)


class StepWidths(TypedDict):
    """Medians over the near-edge positions of their 95 % widths at one step of the split
    (None without positions)."""

    median_width_m: float | None
    median_width_rel_t: float | None
    median_ratio_to_alone: float | None


class WidthSplit(TypedDict):
    positions: int
    n_scans: int
    seed: int
    alone: StepWidths
    distance_known: StepWidths
    no_material_spread: StepWidths
    no_calibration_uncertainty: StepWidths
    no_table_error: StepWidths
"""What :func:`width_split` returns: the positions, scans and seed, then one
:class:`StepWidths` per step of :data:`SPLIT_STEPS`."""


def width_split(table: ModelTable, n_scans: int, seed: int = 0, *,
                diameter_m: float | None = None, measurements: str | Path | None = None
                ) -> WidthSplit:
    """What a near-edge position's thickness interval is made of: for every position of the
    study's scans within :data:`NEAR_EDGE_M` of the edge, the width of its own 95 % interval
    (:data:`SPLIT_STEPS`): alone, then with its distance known exactly, then without the
    material's spread, the calibration's stated uncertainty and the table's interpolation error
    in turn. Medians of the widths (m, and over the plate's thickness) and of their ratio to the
    width alone. The same scans, positions and measurements as :func:`run` (the measurements
    file it keeps is reused)."""
    from dataclasses import replace

    from solitonde.instrument.inference.fine_grid import fine_grid

    if isinstance(n_scans, bool) or not isinstance(n_scans, int) or n_scans < 1:
        raise StudyInputError("scans", f"must be an integer >= 1, got {n_scans!r}")
    sizes = [float(d) for d in table.axes["diameter_m"]]
    diameter_m = (min(sizes, key=lambda d: abs(d - 9.53e-3)) if diameter_m is None
                  else float(table.axes["diameter_m"][table.diameter_index(diameter_m)]))
    t_range = (float(table.axes["thickness_m"][0]), float(table.axes["thickness_m"][-1]))
    measure = Measurer(table.sweep.get("scene", {}), measurements)
    cal = reference_calibration(table, measure, diameter_m, seed * 1000 + 1)
    exact = cal.to_dict()
    for entry in exact["per_diameter"]:
        entry["arr_factor_std"] = entry["tof_offset_std_s"] = 0.0
    cal_exact = Calibration.from_any(exact)
    no_material = dict.fromkeys(("youngs_modulus_rel_sd", "poisson_ratio_sd",
                                 "density_rel_sd"), 0.0)
    rows: list[SplitRow] = []
    for k in range(n_scans):
        scan = Scan(table, int(np.random.default_rng([seed, k]).integers(0, 2**31)), diameter_m)
        for p in _scan_positions(scan, scan.random_positions[:scan.n_positions], measure, cal):
            dist = scan.distance(p.x_m, p.y_m)
            if dist > NEAR_EDGE_M or not p.inputs:
                continue
            est = invert(table, p.inputs, cal).to_dict()["thickness_m"]
            widths = [_width(est, t_range),
                      _width_at_distance(table, p.inputs, cal, None, dist, t_range),
                      _width_at_distance(table, p.inputs, cal, no_material, dist, t_range),
                      _width_at_distance(table, p.inputs, cal_exact, no_material, dist,
                                         t_range)]
            # the table's interpolation error set to zero on the fine grid, then restored
            key = f"fine:{table.diameter_index(diameter_m)}"
            g = fine_grid(table, table.diameter_index(diameter_m))
            table._cache[key] = replace(g, model_tof_var=np.zeros_like(g.model_tof_var),
                                        model_arr_var=np.zeros_like(g.model_arr_var))
            try:
                widths.append(_width_at_distance(table, p.inputs, cal_exact, no_material, dist,
                                                 t_range))
            finally:
                table._cache[key] = g
            rows.append({"thickness_m": scan.thickness_m, "distance_m": dist,
                         "widths_m": dict(zip(SPLIT_STEPS, widths, strict=True))})
    measure.save()
    out: dict[str, int | StepWidths] = {"positions": len(rows), "n_scans": n_scans,
                                        "seed": seed}
    for step in SPLIT_STEPS:
        w = np.array([r["widths_m"][step] for r in rows])
        t = np.array([r["thickness_m"] for r in rows])
        alone = np.array([r["widths_m"]["alone"] for r in rows])
        out[step] = {"median_width_m": float(np.median(w)) if rows else None,
                     "median_width_rel_t": float(np.median(w / t)) if rows else None,
                     "median_ratio_to_alone": float(np.median(w / alone)) if rows else None}
    return cast(WidthSplit, out)


__all__ = ["DISTANCE_RANGE_M", "MAX_POSITIONS", "POSITIONS", "SPLIT_STEPS", "TILT_DEG", "Measurer",
           "Scan", "StudyInputError", "run", "score_scan", "summarise", "width_split"]
