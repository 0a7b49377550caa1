"""How the synthetic validation scores a plate's answer (instrument.studies.validate).

A plate's answer is scored against its truth: the error of the thickness, whether the 95 %
bounds hold the truth (an ``ambiguous`` answer by its readings), whether it is flagged, and
whether its status is one the noise-free model supports. That expected status comes from
:func:`separations`: how many standard errors separate the truth's features from the closest
table point at each end of a parameter's range, along a slice (the other parameter at its true
value) and along the profile (any value of the other parameter); a side is open below
:data:`OPEN_BELOW`, closed above :data:`CLOSED_ABOVE`, either in between.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from itertools import pairwise
from typing import TYPE_CHECKING, Any, NotRequired, TypedDict

import numpy as np

from solitonde.instrument.inference.calibration import (
    Calibration,
    calibrated_table,
    calibration_along,
)
from solitonde.instrument.inference.fine_grid import fine_grid
from solitonde.instrument.inference.inversion import invert
from solitonde.instrument.inference.inversion_inputs import FeatureSummary, FeatureSummaryDict
from solitonde.instrument.tables.table import ModelTable

if TYPE_CHECKING:
    from solitonde.instrument.inference.estimate import FitDict, OtherReading
    from solitonde.instrument.inference.marginals import ParameterDict, ParameterEstimate
    from solitonde.instrument.inference.ridge import ReadingDict

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


class DrawnMaterial(TypedDict):
    """A plate material drawn about the table's, as a property mapping for ``plate.material``."""

    name: str
    youngs_modulus: float
    poisson_ratio: float
    density: float


class MeasuredSize(FeatureSummaryDict):
    """What one sphere size's noisy shots gave: the inversion's inputs, and the plate model
    simulated."""

    plate_model: str


class MeasuredPlate(TypedDict):
    """One simulated plate and what its noisy shots gave per sphere size: the inversion's
    inputs (``FeatureSummary`` as a mapping, with the ``plate_model`` simulated) or None where
    no shot gave anything. Stored as JSON by ``--measurements``."""

    thickness_m: float
    distance_m: float
    summaries: dict[float, MeasuredSize | None]
    wall_s: float


class PlateScore(TypedDict):
    """One plate's truth, answer and scores (a scene of ``validate --out``, keys in order)."""

    thickness_m: float
    distance_m: float
    n_sizes: int
    wall_s: float
    plate_material: DrawnMaterial | None
    status_ok: bool
    reason: NotRequired[str]
    thickness: NotRequired[ParameterDict]
    distance: NotRequired[ParameterDict]
    excluded_diameters_m: NotRequired[list[float]]
    fit: NotRequired[FitDict]
    warnings: NotRequired[list[str]]
    hidden_diameters_m: NotRequired[list[float]]
    flagged: NotRequired[bool]
    answered: NotRequired[bool]
    ambiguous: NotRequired[bool]
    readings: NotRequired[list[ReadingDict]]
    other_reading: NotRequired[OtherReading | None]
    separations: NotRequired[dict[str, list[float]]]
    expected_thickness_status: NotRequired[list[str]]
    expected_distance_status: NotRequired[list[str]]
    status_ok_slice: NotRequired[bool]
    status_ok_profile: NotRequired[bool]
    thickness_error: NotRequired[float | None]
    thickness_covered: NotRequired[bool | None]
    thickness_covered_two_sided: NotRequired[bool | None]
    thickness_width: NotRequired[float | None]
    distance_covered: NotRequired[bool | None]


class DistanceBinScore(TypedDict):
    """The scores of the plates in one bin of the true distance to the support."""

    distance_m: list[float | None]
    n: int
    answered: float
    coverage_95: float | None
    missed_unflagged: float
    ambiguous_rate: float


def plate_inputs(summaries: Mapping[float, Mapping[str, Any] | None]) -> list[FeatureSummary]:
    """The inversion's inputs of a measured plate: one per sphere size that gave any."""
    return [FeatureSummary(s["diameter_m"], s["tof_s"], s["arr"], s["tof_std_s"], s["arr_std"],
                           int(s["n_shots"]), s.get("arr_upper_bound"))
            for s in summaries.values() if s is not None]


class Separations(TypedDict, total=False):
    """The separations a plate's expected statuses come from (absent where no size reflected)."""

    separations: dict[str, list[float]]


def score_plate(table: ModelTable, m: MeasuredPlate, calibration: Calibration,
                material: DrawnMaterial | None) -> PlateScore:
    """A plate inverted against ``table`` with ``calibration`` and scored against its truth."""
    inputs = plate_inputs(m["summaries"])
    if not inputs:
        return {"thickness_m": m["thickness_m"], "distance_m": m["distance_m"], "n_sizes": 0,
                "wall_s": m["wall_s"], "plate_material": material, "status_ok": False,
                "reason": "no reflection detected for any sphere size"}
    est = invert(table, inputs, calibration)
    t_est, l_est = est.thickness_m, est.distance_m
    true_t, true_l = m["thickness_m"], m["distance_m"]
    ambiguous = t_est.status == "ambiguous"
    # an ambiguous answer covers when one of its readings does, and is flagged otherwise
    reading_covered = ambiguous and any(
        covered(r.thickness_m.ci95, true_t) for r in est.readings)
    flagged = est.inconsistent or (ambiguous and not reading_covered)
    answered = t_est.status in ANSWERS and not flagged
    # What the data the inversion used can tell: a size it left out as disagreeing with the
    # others (see :func:`invert`) does not count towards the expected status either.
    excluded = est.extra.get("excluded_diameters_m", [])
    used = [i for i in inputs if i.diameter_m not in excluded and not i.hidden]
    (exp_ts, exp_ls, exp_tp, exp_lp), sep = _expected(table, used, m, calibration)
    exp_t, exp_l = exp_ts | exp_tp, exp_ls | exp_lp
    two = two_sided(t_est) if answered else None
    return {
        "thickness_m": true_t, "distance_m": true_l, "n_sizes": len(inputs),
        "wall_s": m["wall_s"], "plate_material": material,
        "thickness": t_est.to_dict(), "distance": l_est.to_dict(),
        "excluded_diameters_m": excluded, "fit": est.fit, "warnings": est.warnings,
        "hidden_diameters_m": [i.diameter_m for i in inputs if i.hidden],
        "flagged": flagged, "answered": answered, "ambiguous": ambiguous,
        "readings": [r.to_dict() for r in est.readings],
        "other_reading": est.extra.get("other_reading"),
        **sep,
        "expected_thickness_status": sorted(exp_t), "expected_distance_status": sorted(exp_l),
        "status_ok": t_est.status in exp_t and l_est.status in exp_l,
        "status_ok_slice": t_est.status in exp_ts and l_est.status in exp_ls,
        "status_ok_profile": t_est.status in exp_tp and l_est.status in exp_lp,
        "thickness_error": (abs(t_est.median - true_t) / true_t
                            if t_est.median is not None and not flagged else None),
        # every answer with its bounds: a one-sided one covers when its bound holds
        "thickness_covered": ((reading_covered if ambiguous else covered(t_est.ci95, true_t))
                              if answered else None),
        "thickness_covered_two_sided": two[0] <= true_t <= two[1] if two else None,
        "thickness_width": (two[1] - two[0]) / true_t if two else None,
        "distance_covered": covered(l_est.ci95, true_l) if not flagged else None,
    }


def _expected(table: ModelTable, used: Sequence[FeatureSummary], m: MeasuredPlate,
              calibration: Calibration
              ) -> tuple[tuple[set[str], set[str], set[str], set[str]], Separations]:
    """The statuses the noise-free model supports for thickness and distance, along the slice
    and along the profile, and the separations they come from."""
    if not used:  # no reflection at all: the bound is what the data can tell
        return ({"upper_bound_only"}, set(STATUSES), {"upper_bound_only"}, set(STATUSES)), {}
    phys = bool(table.axes["distance_m"][0] <= 0.0)
    sep = separations(table, used, m["thickness_m"], m["distance_m"], calibration)
    # a slice (the other parameter at its true value) misses joint (t, L) degeneracies, the
    # profile flags every one however little posterior mass it carries: both are answers the
    # noise-free model supports, and both are scored separately too
    return ((expected_statuses(sep["thickness_m_slice"], lower_physical=False),
             expected_statuses(sep["distance_m_slice"], lower_physical=phys),
             expected_statuses(sep["thickness_m"], lower_physical=False),
             expected_statuses(sep["distance_m"], lower_physical=phys)),
            {"separations": {k: v.tolist() for k, v in sep.items()}})


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


def missed_unflagged(row: PlateScore) -> bool:
    """Whether a plate's answer misses its truth with nothing said: not flagged, not ambiguous,
    a thickness with bounds (two-sided or one-sided) that do not hold it."""
    thickness = row.get("thickness")
    status = None if thickness is None else thickness["status"]
    return (not row.get("flagged") and status in ANSWERS and status != "ambiguous"
            and row.get("thickness_covered") is False)


def by_distance(rows: Sequence[PlateScore]) -> list[DistanceBinScore]:
    """The scores per bin of the true distance to the support (:data:`DISTANCE_BINS_M`):
    plates, answered, the 95 % coverage, the unflagged misses and the ambiguous answers; a bin
    without plates is left out."""
    out: list[DistanceBinScore] = []
    for lo, hi in pairwise(DISTANCE_BINS_M):
        assert lo is not None
        inside = [r for r in rows if r["distance_m"] >= lo and (hi is None or r["distance_m"] < hi)]
        if not inside:
            continue
        cov = [c for r in inside if (c := r.get("thickness_covered")) is not None]
        out.append({"distance_m": [lo, hi], "n": len(inside),
                    "answered": float(np.mean([bool(r.get("answered")) for r in inside])),
                    "coverage_95": float(np.mean(cov)) if cov else None,
                    "missed_unflagged": float(np.mean([missed_unflagged(r) for r in inside])),
                    "ambiguous_rate": float(np.mean([bool(r.get("ambiguous")) for r in inside]))})
    return out


def two_sided(p: ParameterEstimate) -> tuple[float, float] | None:
    """A constrained answer's 95 % interval, or None for any other."""
    ci = p.ci95
    if p.status != "constrained" or ci is None or ci[0] is None or ci[1] is None:
        return None
    return float(ci[0]), float(ci[1])


def covered(ci: Sequence[float | None] | None, truth: float) -> bool | None:
    """Whether the bounds ``ci`` (None where open) hold ``truth``; None without bounds."""
    if ci is None:
        return None
    lo, hi = ci
    return (lo is None or lo <= truth) and (hi is None or truth <= hi)


def counts(values: Iterable[object]) -> dict[str, int]:
    """How often each value occurs, by its text."""
    out: dict[str, int] = {}
    for v in values:
        out[str(v)] = out.get(str(v), 0) + 1
    return out
