"""The table's near-support plate brought to its far-field plate's level where the two meet.

Along each thickness row a table built with the ``auto`` plate policy holds two plate models: the
meshed plate (Mindlin's 2-D plate, or the 3-D one) from the support out to where the support
stops mattering, and Zener's dashpot beyond. Both are flat in L where they meet (the support's
echo has died out), yet they differ there by a step: in the default table's 9.53 mm column, on
the rows whose reflection is clear (3.45-6 mm), the Mindlin plate's TOF runs 0.09-0.16 % longer
than the dashpot's and its ARR 0.7-1.4 % lower. The 3-D plate sides with the dashpot. On the 80
validation draws of 3.45 mm or more within 50 mm of a clamp (three seeds), simulated on both
plates with the same shot, the 3-D plate's TOF and ARR differ from the Mindlin plate's, from
three plate thicknesses out, by 0.85 and 1.07 of that row's step on average (0.6-1.4 and
0.6-2.4); between one and three thicknesses its ARR by half the step; within one thickness of
the clamp, where both plates hold the chain as a wall does, its ARR not at all (its TOF by a
third of the step the other way). So the step is the 2-D plate's own offset, which only the
clamp's near field undoes. On a fourth seed's 31 such draws the match below brings the read
within 0.05 % (TOF) and 0.41 % (ARR) rms of the 3-D plate, from 0.11 % and 1.17 %.

A calibration is fitted on reference plates far from the supports, at the dashpot's level, and
carries to every node only if the table has one level. Each row's meshed nodes are therefore
scaled, TOF by one factor and ARR by another, so that the last meshed node meets the first
dashpot node (the next one in L), the share of the step ramping in as measured (:func:`ramp`).
Unmatched, a near-support answer reads the 2-D plate's level through a calibration of the
dashpot's, and an answer far from the supports, whose posterior reaches along L into the meshed
nodes, takes both levels at once and comes out wider (the default validation's median width by
16-19 %).

Only a step the 2-D plate's own offset explains is matched: the dashpot's TOF shorter and its ARR
higher, as the 3-D plate's are, by at most twice the 2-D plate's error
(:data:`~.model_error.PLATE_THEORY_TOF_REL_STD`, ``..._ARR_REL_STD``), where the reflection is a
clear pulse at both nodes (ARR at least :data:`~.model_error.FLOOR_ARR_MAX`). A step the other way
is not the plate's offset: with 4.76 mm spheres on 4.55 and 4.99 mm plates it is measured from a
last Mindlin node (80 mm) that stands 1.5-2 % above the row's flat part (55-70 mm; against that part
the step has the usual sign), and the 3-D plate at 30 mm reads the dashpot's level (ARR 0.8372
against 0.8377), so matching to that node would move the read away from it. Between weaker
reflections the step wanders in sign from row to row (a weak pulse's shape, not the plate's offset:
the 3-D plate at 2.61 mm, 30 mm read ARR 2.4 % above the Mindlin node where that row's step says 1
% below), so such rows keep their levels. The 2-D plate's error term stays in full on every meshed
node: it covers what the match leaves (at the draws' extremes 0.4 of the step in TOF and 1.4 in
ARR) and the rows it does not match.
"""

from __future__ import annotations

from typing import TypedDict

import numpy as np

from solitonde.instrument.inference.model_error import (
    FLOOR_ARR_MAX,
    PLATE_THEORY_ARR_REL_STD,
    PLATE_THEORY_TOF_REL_STD,
)
from solitonde.instrument.tables.table import STATUS_OK, ModelTable

MESHED_MODELS = ("sem", "greens", "mindlin", "mindlin_greens")
"""The plate models next to a support: their nodes are scaled."""
FAR_MODELS = ("infinite",)
"""The far-field plate model (Zener's dashpot): the level the meshed nodes are brought to."""
MATCH_TOF_REL_MAX = 2.0 * PLATE_THEORY_TOF_REL_STD
MATCH_ARR_REL_MAX = 2.0 * PLATE_THEORY_ARR_REL_STD
"""The largest step (relative) matched: twice the 2-D plate's own error's standard deviation."""
RAMP_START = 1.0
RAMP_END = 3.0
"""The step is applied from L = RAMP_START t, in full from L = RAMP_END t (:func:`ramp`)."""


def row_factors(table: ModelTable, i_d: int) -> np.ndarray:
    """(n_t, 2): the factors on TOF and ARR of each thickness row's meshed nodes for sphere size
    ``i_d``; 1 where the row is not matched (no step between adjacent meshed and far nodes that
    both reflect clearly, or one the 2-D plate's offset does not explain: larger than twice its
    error, or the other way than TOF shorter and ARR higher)."""
    key = f"tier-factors:{i_d}"
    cached = table._cache.get(key)
    if cached is not None:
        return cached
    factors = np.ones((table.axes["thickness_m"].size, 2))
    ok = table.status[i_d] == STATUS_OK
    meshed = table.simulated_on(i_d, MESHED_MODELS) & ok
    far = table.simulated_on(i_d, FAR_MODELS) & ok
    tof, arr = table.features["tof_s"][i_d], table.features["arr"][i_d]
    for i in range(factors.shape[0]):
        near, beyond = np.flatnonzero(meshed[i]), np.flatnonzero(far[i])
        if not near.size or not beyond.size or beyond[0] != near[-1] + 1:
            continue
        a, b = near[-1], beyond[0]
        f_tof, f_arr = tof[i, b] / tof[i, a], arr[i, b] / arr[i, a]
        if (min(arr[i, a], arr[i, b]) >= FLOOR_ARR_MAX
                and 1.0 - MATCH_TOF_REL_MAX <= f_tof < 1.0 < f_arr <= 1.0 + MATCH_ARR_REL_MAX):
            factors[i] = f_tof, f_arr
    table._cache[key] = factors
    return factors


def ramp(distance_over_thickness: np.ndarray) -> np.ndarray:
    """The share of a row's step applied at L / t: none within :data:`RAMP_START` plate
    thicknesses of the support, all of it from :data:`RAMP_END` on, linear in between."""
    return np.clip((distance_over_thickness - RAMP_START) / (RAMP_END - RAMP_START), 0.0, 1.0)


def matched_features(table: ModelTable, i_d: int) -> tuple[np.ndarray, np.ndarray]:
    """TOF and ARR of sphere size ``i_d`` over (thickness, distance) with each row's meshed nodes
    at the far-field level (:func:`row_factors`); nodes without a reflection as the table has
    them. What the inversion reads; the table file itself is not changed."""
    key = f"tier-matched:{i_d}"
    cached = table._cache.get(key)
    if cached is not None:
        return cached
    factors = row_factors(table, i_d)
    meshed = table.simulated_on(i_d, MESHED_MODELS)
    share = np.where(meshed, ramp(table.axes["distance_m"][None, :]
                                  / table.axes["thickness_m"][:, None]), 0.0)
    tof = table.features["tof_s"][i_d] * (1.0 + share * (factors[:, :1] - 1.0))
    arr = table.features["arr"][i_d] * (1.0 + share * (factors[:, 1:] - 1.0))
    table._cache[key] = (tof, arr)
    return tof, arr


class TierMatchRow(TypedDict):
    """One sphere size's match as ``table info`` shows it: rows matched, and the range of the
    factors on their Mindlin nodes (None where no row is)."""

    diameter_m: float
    rows_matched: int
    rows: int
    tof_factor: list[float] | None
    arr_factor: list[float] | None


def _span(values: np.ndarray) -> list[float] | None:
    return [float(values.min()), float(values.max())] if values.size else None


def summary(table: ModelTable) -> list[TierMatchRow]:
    """Per sphere size, the rows whose meshed nodes are read at the far-field level."""
    out: list[TierMatchRow] = []
    for i_d, d in enumerate(table.axes["diameter_m"]):
        f = row_factors(table, i_d)
        f = f[(f != 1.0).any(axis=1)]
        out.append({"diameter_m": float(d), "rows_matched": int(f.shape[0]),
                    "rows": int(table.axes["thickness_m"].size),
                    "tof_factor": _span(f[:, 0]), "arr_factor": _span(f[:, 1])})
    return out
