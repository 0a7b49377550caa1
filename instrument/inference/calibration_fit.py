"""Fitting a :class:`~.calibration.Calibration` on reference shots: plates of known thickness
and position, measured, compared with the model table there.

Apart from :mod:`.calibration` (the record the inversion applies) because it uses the inversion's
own interpolation of the table, and the inversion uses the record.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from solitonde.instrument.inference.calibration import (
    Calibration,
    CalibrationError,
    DiameterEntry,
    DistanceRow,
)
from solitonde.instrument.inference.fine_grid import predict
from solitonde.instrument.inference.inversion_inputs import FeatureSummary, InversionError
from solitonde.instrument.inference.shot_scatter import pooled
from solitonde.instrument.tables.dissipation import damped, slice_reads
from solitonde.instrument.tables.table import ModelTable


def _combine(values: Sequence[float], sigmas: Sequence[float]) -> tuple[float, float, float]:
    """Inverse-variance mean, its statistical error, and the excess scatter between the values
    (sample variance beyond the mean statistical variance; 0 for a single value)."""
    w = [1 / s**2 for s in sigmas]
    mean = sum(x * wi for x, wi in zip(values, w, strict=True)) / sum(w)
    stat = 1 / math.sqrt(sum(w))
    if len(values) < 2:
        return mean, stat, 0.0
    plain = sum(values) / len(values)
    var = sum((x - plain) ** 2 for x in values) / (len(values) - 1)
    excess = var - sum(s**2 for s in sigmas) / len(sigmas)
    return mean, stat, math.sqrt(max(0.0, excess))


TAU_GRID_POINTS = 1201
"""Time constants tried by the damping fit, 0 to 1.5 times the layer's largest."""


def _fit_damping(table: ModelTable, d: float, refs: Sequence[Reference]) -> tuple[float, float]:
    """(tau, sd) of the chain's Kuwabara-Kono damping from the references' ARR (see
    :func:`fit_calibration`): the chi^2 over a fine grid of tau, the model piecewise linear in
    tau between the table's slices as the inversion reads it; sd from chi^2 = min + 1, scaled by
    the Birge ratio when several references disagree beyond their errors."""
    layer = table.dissipation
    assert layer is not None
    reads = slice_reads(table)
    nodes = np.concatenate([[0.0], layer.damping_s])
    taus = np.linspace(0.0, 1.5 * nodes[-1], TAU_GRID_POINTS)
    chi2 = np.zeros_like(taus)
    for ref in refs:
        at = np.array([predict(r, d, ref.thickness_m, ref.distance_m)[1] for r in reads])
        arr0_sd = predict(table, d, ref.thickness_m, ref.distance_m, with_error=True)[3]
        model = np.interp(taus, nodes, at)
        beyond = taus > nodes[-1]  # the last segment, extended
        model[beyond] = at[-1] + (taus[beyond] - nodes[-1]) * (at[-1] - at[-2]) / (
            nodes[-1] - nodes[-2])
        chi2 += (ref.summary.arr - model) ** 2 / (ref.summary.sigmas()[1] ** 2 + arr0_sd**2)
    if np.ptp(chi2) <= 0:
        raise CalibrationError("references", f"the references of D = {d:g} m sit where the "
                               "table's damping changes nothing; the chain's damping cannot "
                               "be fitted there")
    best = int(np.argmin(chi2))
    inside = taus[chi2 <= chi2[best] + 1.0]
    sd = 0.5 * (inside.max() - inside.min()) if inside.min() > 0 else inside.max() - taus[best]
    sd = max(sd, taus[1] - taus[0])
    if len(refs) > 1:
        sd *= max(1.0, math.sqrt(chi2[best] / (len(refs) - 1)))
    if best == taus.size - 1:
        # more damping than the layer reaches (or references the damping cannot explain, e.g. a
        # large sphere's floor-level reflection): the damping is not known, only that it is large
        sd = max(sd, float(taus[-1]))
    return float(taus[best]), float(sd)


DISTINCT_DISTANCE_M = 1e-3
"""References of a size whose distances to the support differ by more than this stand at
different distances: with two or more such distances the factor and offset are fitted per
distance (``by_distance``)."""


def _distance_groups(distances: Sequence[float]) -> list[list[int]]:
    """Indices of the references per distance, nearest first: sorted by distance, a new group
    wherever the next distance lies more than :data:`DISTINCT_DISTANCE_M` beyond the last."""
    order = sorted(range(len(distances)), key=lambda i: distances[i])
    groups: list[list[int]] = []
    for i in order:
        if groups and distances[i] - distances[groups[-1][-1]] <= DISTINCT_DISTANCE_M:
            groups[-1].append(i)
        else:
            groups.append([i])
    return groups


def _factor_offset(d: float, rows: Sequence[tuple[float, float, float, float]],
                   arrs: Sequence[float], damped_fit: bool) -> DiameterEntry:
    """The ARR factor and TOF offset of a size's references ``(f, sf, o, so)`` (measured ARR
    ``arrs``) with their stated uncertainties (:func:`_combine`: statistical and transfer
    parts). ``damped_fit``: the references' ARR fitted the damping, whose sd holds their
    statistical error, so the factor keeps only their disagreement beyond it."""
    f, sf, o, so = (list(c) for c in zip(*rows, strict=True))
    f_mean, f_stat, f_transfer = _combine(f, sf)
    o_mean, o_stat, o_transfer = _combine(o, so)
    if not (math.isfinite(f_mean) and f_mean > 0):
        # ARR 0 at the reference: a factor of 0 would erase every model reflection
        listed = ", ".join(f"{a:g}" for a in arrs)
        raise CalibrationError("arr", f"the measured ARR at the reference (D = {d:g} m: "
                               f"{listed}) gives an ARR factor of {f_mean:g}; it must be > 0 "
                               "(measure a reference where the reflection is seen)")
    if not all(math.isfinite(x) for x in (f_stat, f_transfer, o_mean, o_stat, o_transfer)):
        raise CalibrationError("tof", f"the reference shots at D = {d:g} m give a "
                               "non-finite TOF offset or uncertainty")
    if damped_fit:
        f_stat = 0.0
    return {
        "arr_factor": f_mean,
        "arr_factor_std": math.hypot(f_stat, f_transfer),
        "arr_factor_transfer_std": f_transfer,
        "tof_offset_s": o_mean,
        "tof_offset_std_s": math.hypot(o_stat, o_transfer),
        "tof_offset_transfer_std_s": o_transfer,
        "n_references": len(rows),
    }


def _distance_row(distance_m: float, fit: DiameterEntry) -> DistanceRow:
    """What a ``by_distance`` row keeps of the fit at one distance, beside the distance."""
    return {"distance_m": distance_m, "arr_factor": fit["arr_factor"],
            "tof_offset_s": fit["tof_offset_s"], "arr_factor_std": fit["arr_factor_std"],
            "tof_offset_std_s": fit["tof_offset_std_s"], "n_references": fit["n_references"]}


@dataclass(frozen=True)
class Reference:
    """Shots of one sphere size on a reference plate of known thickness and position."""

    thickness_m: float
    distance_m: float
    summary: FeatureSummary


def fit_calibration(table: ModelTable, references: Sequence[Reference]) -> Calibration:
    """The chain's damping (where the table has a dissipation layer), ARR factor and TOF offset
    per sphere size from reference shots; globals as their means.

    With a dissipation layer (instrument.tables.dissipation), each size's Kuwabara-Kono time
    constant comes first: the least-squares fit of the references' ARR to the table read at tau
    (piecewise linear between the layer's slices, at each reference's known (t, L); tau >= 0: a
    chain that loses nothing is elastic). Its standard error is the fit's, scaled up by the
    residuals' scatter when several references disagree beyond their errors (Birge ratio). The
    ARR factor and TOF offset are then fitted against the table read at that damping, so they
    hold what damping does not explain (about 1 and 0 for a chain whose losses are contact
    damping); the factor's stated uncertainty is then the references' disagreement alone (their
    statistical error is the damping's).

    Each reference gives ``factor = ARR / ARR_model`` and ``offset = TOF - TOF_model`` with the
    model interpolated from ``table`` at the known (t, L); several references of one size are
    combined with inverse-variance weights (shot scatter over sqrt(n), or the inversion's stated
    defaults, and the table's interpolation error at the reference). The global values weigh
    every size equally.

    The stated uncertainty (``arr_factor_std``, ``tof_offset_std_s``, which the inversion adds to
    its error budget) is the statistical one plus, with two or more references of a size
    (different plates), the scatter between them beyond their statistical errors (a
    random-effects estimate, ``*_transfer_*``): how far a factor and offset fitted on one plate
    carry over to another. One reference cannot show that and states the statistical part only.

    The references' own scatter, pooled per size over those shot two or more times, is the
    rig's per-shot repeatability (``shot_tof_rel_std``, ``shot_arr_std``,
    ``shot_scatter_dof``): a single shot read with this calibration takes it instead of the
    inversion's assumed spread (:mod:`.shot_scatter`).

    References of a size at two or more distances to the support (more than
    :data:`DISTINCT_DISTANCE_M` apart) also give the factor and offset per distance, combined
    the same way over the references at each (``by_distance``, nearest first): next to a clamp
    the model's mismatch differs from the one far away, and the inversion reads these rows at
    each candidate distance (:meth:`~.calibration.Calibration.along`). The damping stays the one
    fitted on all of them, and the entry's own factor and offset the combination over all (for
    readers that know no distance, and as the transfer uncertainty shows, wider). References at
    one distance give no rows: the result is as without them.
    """
    if not references:
        raise CalibrationError("references", "need at least one reference measurement")
    groups: dict[float, list[Reference]] = {}
    for ref in references:
        d = float(table.axes["diameter_m"][table.diameter_index(ref.summary.diameter_m)])
        groups.setdefault(d, []).append(ref)
    dampings = ({d: _fit_damping(table, d, refs) for d, refs in groups.items()}
                if table.dissipation is not None else {})
    by_d: dict[float, list[tuple[float, float, float, float]]] = {}
    measured: dict[float, list[float]] = {}
    for d, refs in groups.items():
        # the factor and offset against the table at the fitted damping; the reference's error
        # is its shots' and the table's interpolation's (the damped read's own error is the
        # inversion's to add)
        tau = dampings[d][0] if d in dampings else 0.0
        model = table if d not in dampings else damped(table, [tau] * table.shape[0],
                                                       [0.0] * table.shape[0])
        for ref in refs:
            s = ref.summary
            tof_m, arr_m = predict(model, d, ref.thickness_m, ref.distance_m)
            _, _, tof_sd, arr_sd = predict(table, d, ref.thickness_m, ref.distance_m,
                                           with_error=True)
            if arr_m <= 0:
                raise InversionError("arr", f"the model ARR at the reference is {arr_m:g}: no "
                                     "factor can be fitted there; use a thicker or closer "
                                     "reference")
            s_tof, s_arr = s.sigmas()
            assert s.tof_s is not None and s.arr is not None  # sigmas() refuses a hidden one
            # the reference's own error: its shots, and the table's interpolation error there
            f = s.arr / arr_m
            sf = math.hypot(s_arr, f * arr_sd) / arr_m
            by_d.setdefault(d, []).append((f, sf, s.tof_s - tof_m, math.hypot(s_tof, tof_sd)))
            measured.setdefault(d, []).append(s.arr)
    per: dict[float, DiameterEntry] = {}
    for d, rows in by_d.items():
        per[d] = _factor_offset(d, rows, measured[d], d in dampings)
        if d in dampings:
            per[d]["damping_s"], per[d]["damping_std_s"] = dampings[d]
        rig = pooled([ref.summary for ref in groups[d]])
        if rig is not None:
            per[d].update(rig)
        # references at two or more distances: the factor and offset per distance too (the
        # damping stays the one fitted on all of them)
        distances = [ref.distance_m for ref in groups[d]]
        near_far = _distance_groups(distances)
        if len(near_far) >= 2:
            per[d]["by_distance"] = [
                _distance_row(sum(distances[i] for i in idx) / len(idx),
                              _factor_offset(d, [rows[i] for i in idx],
                                             [measured[d][i] for i in idx], d in dampings))
                for idx in near_far]
    n = len(per)
    reference = {
        "references": [{"thickness_m": r.thickness_m, "distance_m": r.distance_m,
                        **vars(r.summary)} for r in references],
        "table": str(table.path) if table.path else None,
    }
    return Calibration(sum(e["arr_factor"] for e in per.values()) / n,
                       sum(e["tof_offset_s"] for e in per.values()) / n, per, reference)
