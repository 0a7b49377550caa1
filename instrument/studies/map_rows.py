"""The map study's rows (:func:`.map_study.score_scan`): per scan its truth, every position's
three thickness answers against it, the located edges and, when asked, the edge's error as
positions are added. Written as JSON by ``validate-map --out``, keys in order."""

from __future__ import annotations

from typing import Literal, NotRequired, TypedDict

from solitonde.instrument.inference.joint_summary import JointFit

AnswerKind = Literal["alone", "free", "common"]
ANSWER_KINDS: tuple[AnswerKind, ...] = ("alone", "free", "common")
"""A position's thickness answers: its own inversion, and the joint map's with the thickness
free per position or tied to a common mean."""


class ThicknessScore(TypedDict):
    """One thickness answer against the plate's thickness (``covered`` None: no answer)."""

    status: str | None
    ci95: list[float | None] | None
    covered: bool | None
    width_m: float


class PositionScore(TypedDict):
    """A position: where it was recorded, its true distance from the edge, its answers."""

    x_m: float
    y_m: float
    distance_m: float
    alone: ThicknessScore
    free: ThicknessScore
    common: ThicknessScore


class EdgeAtScan(TypedDict):
    """The joint edge's direction and where it lies at the scan, against the truth
    (:func:`.map_study._edge_at_scan`)."""

    angle_ci95_width_deg: float
    angle_covered: bool
    angle_z: float
    at_scan_ci95_width_m: float
    at_scan_covered: bool
    at_scan_z: float
    lever_m: float


class EdgeScore(TypedDict, total=False):
    """A located edge against the true one: its offset's interval and coverage, its error
    (the joint map's with its fit and :class:`EdgeAtScan`'s keys); or, where the per-position
    fit located none, only the ``reason``."""

    reason: str | None
    ci95_offset_m: list[float]
    offset_m: float
    normal_angle_deg: float
    covered: bool
    offset_z: float
    fit: JointFit
    error_m: float
    angle_ci95_width_deg: float
    angle_covered: bool
    angle_z: float
    at_scan_ci95_width_m: float
    at_scan_covered: bool
    at_scan_z: float
    lever_m: float


class SequenceScore(TypedDict):
    """One strategy's run of added positions: the edge's error after each, the count at which
    it first fell below the target (None: never), and the positions in order."""

    errors_m: list[float]
    positions_to_target: int | None
    xy: list[list[float]]


class ScanRow(TypedDict):
    """One scan of the study (:func:`.map_study.score_scan`)."""

    seed: int
    thickness_m: float
    normal_angle_deg: float
    offset_m: float
    n_positions: int
    positions: list[PositionScore]
    edge_free: EdgeScore | None
    edge_common: EdgeScore | None
    edge_alone: EdgeScore
    sequence: NotRequired[dict[str, SequenceScore]]


class SplitRow(TypedDict):
    """A near-edge position of the width split: the plate's thickness, its distance, and its
    interval's width at each step of :data:`.map_study.SPLIT_STEPS`."""

    thickness_m: float
    distance_m: float
    widths_m: dict[str, float]
