"""The map study's summary (:func:`summarise`): per answer kind, the thickness coverage and the
widths near the edge, the located edge's coverage and error, and, where positions were added one
by one, how fast each strategy brought the edge's error under the target. ``validate-map
--json`` prints these metrics; the docs quote them."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Literal, NotRequired, TypedDict

import numpy as np

from solitonde.instrument.inference.calibration import DiameterRecord
from solitonde.instrument.inference.joint_summary import WIDE_ANGLE_DEG
from solitonde.instrument.studies.map_rows import (
    AnswerKind,
    EdgeScore,
    ScanRow,
    SequenceScore,
)
from solitonde.instrument.studies.map_scan import MAX_POSITIONS

START_POSITIONS = 3
"""Positions every scan starts with, before a strategy adds more."""
NEAR_EDGE_M = 0.03
"""Positions this close to the edge make the near-edge widths."""
TARGET_ERROR_M = 0.005
"""The edge error a strategy is asked to reach."""
Strategy = Literal["suggested", "random_near_edge", "random_on_plate"]
STRATEGIES: tuple[Strategy, ...] = ("suggested", "random_near_edge", "random_on_plate")
"""How the positions after the first three are chosen: the joint posterior's suggestion;
at random as the first ones were (near the true edge: an operator who already knows roughly
where the support is); at random anywhere on the plate."""


class ThicknessMetrics(TypedDict):
    """One answer kind's thickness answers over every position of every scan."""

    coverage_95: float | None
    answers: int
    positions: int
    statuses: dict[str, int]
    near_edge_width_median_rel: float | None
    near_edge_width_median_m: float | None
    near_edge_positions: int


class EdgeMetrics(TypedDict):
    """One answer kind's located edges against the true ones; the angle and at-scan keys only
    where the kind locates the edge's direction too."""

    coverage_95: float | None
    located: int
    scans: int
    error_median_m: float | None
    ci95_width_median_m: float | None
    coverage_95_se: float | None
    """How sure a coverage over this many scans is (binomial, at the coverage seen)."""
    offset_z_rms: float | None
    angle_coverage_95: NotRequired[float]
    angle_ci95_width_median_deg: NotRequired[float]
    at_scan_coverage_95: NotRequired[float]
    at_scan_ci95_width_median_m: NotRequired[float]
    lever_median_m: NotRequired[float]
    angle_z_rms: NotRequired[float | None]
    at_scan_z_rms: NotRequired[float | None]
    direction_fixed_scans: NotRequired[int]
    at_scan_coverage_95_direction_fixed: NotRequired[float | None]
    at_scan_z_rms_direction_fixed: NotRequired[float | None]


class SequenceMetrics(TypedDict):
    """One strategy's runs: the median edge error after each count of positions, and how many
    scans reached the target and after how many positions."""

    edge_error_median_m_by_positions: dict[str, float]
    reached_target: int
    scans: int
    positions_to_target_median: float
    positions_to_target_mean_reached: float | None
    target_m: float


MapSummary = TypedDict("MapSummary", {
    "thickness_alone": ThicknessMetrics,
    "thickness_free": ThicknessMetrics,
    "thickness_common": ThicknessMetrics,
    "edge_alone": EdgeMetrics,
    "edge_free": EdgeMetrics,
    "edge_common": EdgeMetrics,
    "joint_fit_p_below_0.001": float | None,
    "sequence_suggested": NotRequired[SequenceMetrics],
    "sequence_random_near_edge": NotRequired[SequenceMetrics],
    "sequence_random_on_plate": NotRequired[SequenceMetrics],
    "suggested_fewer_than_random_near_edge": NotRequired[int],
    "suggested_more_than_random_near_edge": NotRequired[int],
    "suggested_fewer_than_random_on_plate": NotRequired[int],
    "suggested_more_than_random_on_plate": NotRequired[int],
})
"""What :func:`summarise` makes of the scans' rows."""


class MapMetrics(MapSummary):
    """The study's metrics: the summary and how it was run."""

    n_scans: int
    seed: int
    diameter_m: float
    shared_calibration: bool
    coordinate_sd_m: float
    truth_plate_theory: str
    simulated_positions: int
    simulation_wall_s: float
    wall_s: float
    calibration: list[DiameterRecord]
    table: str | None


class StudyResult(TypedDict):
    """The study (:func:`.map_study.run`): the summary metrics and the scans' rows."""

    metrics: MapMetrics
    scans: list[ScanRow]


def summarise(rows: Sequence[ScanRow]) -> MapSummary:
    """Coverage, widths near the edge, and the edge's error against the number of positions."""
    free = [e["fit"]["p_value"] for r in rows if (e := r.get("edge_free")) and "fit" in e]
    out: MapSummary = {
        "thickness_alone": _thickness(rows, "alone"),
        "thickness_free": _thickness(rows, "free"),
        "thickness_common": _thickness(rows, "common"),
        "edge_alone": _edges(rows, "alone"),
        "edge_free": _edges(rows, "free"),
        "edge_common": _edges(rows, "common"),
        "joint_fit_p_below_0.001": float(np.mean([p < 1e-3 for p in free])) if free else None}
    seqs = [r["sequence"] for r in rows if "sequence" in r]
    if seqs:
        out["sequence_suggested"] = _sequence(seqs, "suggested")
        out["sequence_random_near_edge"] = _sequence(seqs, "random_near_edge")
        out["sequence_random_on_plate"] = _sequence(seqs, "random_on_plate")
        fewer, more = _against(seqs, "random_near_edge")
        out["suggested_fewer_than_random_near_edge"] = fewer
        out["suggested_more_than_random_near_edge"] = more
        fewer, more = _against(seqs, "random_on_plate")
        out["suggested_fewer_than_random_on_plate"] = fewer
        out["suggested_more_than_random_on_plate"] = more
    return out


def _thickness(rows: Sequence[ScanRow], kind: AnswerKind) -> ThicknessMetrics:
    positions = [(r, p) for r in rows for p in r["positions"]]
    cov = [c for _, p in positions if (c := p[kind]["covered"]) is not None]
    near = [(p[kind]["width_m"], r["thickness_m"]) for r, p in positions
            if p["distance_m"] <= NEAR_EDGE_M]
    return {"coverage_95": float(np.mean(cov)) if cov else None, "answers": len(cov),
            "positions": len(positions),
            "statuses": _counts(p[kind]["status"] for _, p in positions),
            "near_edge_width_median_rel": float(np.median([w / t for w, t in near]))
            if near else None,
            "near_edge_width_median_m": float(np.median([w for w, _ in near])) if near else None,
            "near_edge_positions": len(near)}


def _edges(rows: Sequence[ScanRow], kind: AnswerKind) -> EdgeMetrics:
    located = [e for r in rows if (e := _edge_of(r, kind)) and "covered" in e]
    out: EdgeMetrics = {
        "coverage_95": float(np.mean([e["covered"] for e in located])) if located else None,
        "located": len(located), "scans": len(rows),
        "error_median_m": float(np.median([e["error_m"] for e in located])) if located else None,
        "ci95_width_median_m": float(np.median([e["ci95_offset_m"][1] - e["ci95_offset_m"][0]
                                                for e in located])) if located else None,
        # 30 scans resolve 0.967 from 1.000 and no finer
        "coverage_95_se": _binomial_se([e["covered"] for e in located]),
        "offset_z_rms": _rms([e.get("offset_z") for e in located])}
    seen = [e for e in located if "angle_covered" in e]
    if not seen:
        return out
    out.update({
        "angle_coverage_95": float(np.mean([e["angle_covered"] for e in seen])),
        "angle_ci95_width_median_deg": float(np.median([e["angle_ci95_width_deg"]
                                                        for e in seen])),
        "at_scan_coverage_95": float(np.mean([e["at_scan_covered"] for e in seen])),
        "at_scan_ci95_width_median_m": float(np.median([e["at_scan_ci95_width_m"]
                                                        for e in seen])),
        "lever_median_m": float(np.median([e["lever_m"] for e in seen])),
        "angle_z_rms": _rms([e.get("angle_z") for e in seen]),
        "at_scan_z_rms": _rms([e.get("at_scan_z") for e in seen])})
    # where the edge lies at the scan means something only where its direction is fixed: the
    # joint map warns beyond WIDE_ANGLE_DEG
    fixed = [e for e in seen if e["angle_ci95_width_deg"] <= WIDE_ANGLE_DEG]
    out.update({
        "direction_fixed_scans": len(fixed),
        "at_scan_coverage_95_direction_fixed": float(np.mean([e["at_scan_covered"]
                                                              for e in fixed]))
        if fixed else None,
        "at_scan_z_rms_direction_fixed": _rms([e.get("at_scan_z") for e in fixed])})
    return out


def _sequence(seqs: Sequence[dict[str, SequenceScore]], strategy: Strategy) -> SequenceMetrics:
    errors = np.array([s[strategy]["errors_m"] for s in seqs])
    counts = [s[strategy]["positions_to_target"] for s in seqs]
    reached = [c for c in counts if c is not None]
    return {
        "edge_error_median_m_by_positions": {
            str(START_POSITIONS + k): float(np.median(errors[:, k]))
            for k in range(errors.shape[1])},
        "reached_target": len(reached), "scans": len(seqs),
        # a scan that never reached it counts as needing more than the maximum
        "positions_to_target_median": float(np.median(
            [c if c is not None else MAX_POSITIONS + 1 for c in counts])),
        "positions_to_target_mean_reached": float(np.mean(reached)) if reached else None,
        "target_m": TARGET_ERROR_M}


def _against(seqs: Sequence[dict[str, SequenceScore]], other: Strategy) -> tuple[int, int]:
    """In how many scans the suggestion needed fewer positions than ``other``, and more."""
    big = MAX_POSITIONS + 1
    pairs = [(s["suggested"]["positions_to_target"] or big, s[other]["positions_to_target"] or big)
             for s in seqs]
    return sum(a < b for a, b in pairs), sum(a > b for a, b in pairs)


def _edge_of(row: ScanRow, kind: AnswerKind) -> EdgeScore | None:
    """The scan's edge as the answers of ``kind`` locate it."""
    if kind == "alone":
        return row.get("edge_alone")
    return row.get("edge_free") if kind == "free" else row.get("edge_common")


def _rms(values: Sequence[float | None]) -> float | None:
    v = np.array([x for x in values if x is not None and math.isfinite(x)], dtype=float)
    return float(np.sqrt(np.mean(v**2))) if v.size else None


def _binomial_se(hits: Sequence[bool]) -> float | None:
    if not hits:
        return None
    p = float(np.mean(hits))
    return math.sqrt(max(p * (1.0 - p), 1.0 / len(hits)) / len(hits))


def _counts(values: Iterable[object]) -> dict[str, int]:
    out: dict[str, int] = {}
    for v in values:
        out[str(v)] = out.get(str(v), 0) + 1
    return out
