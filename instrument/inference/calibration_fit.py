"""Fitting a :class:`~.calibration.Calibration` on reference shots: plates of known thickness
and position, measured, compared with the model table there.

Apart from :mod:`.calibration` (the record the inversion applies) because it uses the inversion's
own interpolation of the table, and the inversion uses the record.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from solitonde.instrument.inference.calibration import Calibration, CalibrationError
from solitonde.instrument.inference.inversion import FeatureSummary, InversionError, predict
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


@dataclass(frozen=True)
class Reference:
    """Shots of one sphere size on a reference plate of known thickness and position."""

    thickness_m: float
    distance_m: float
    summary: FeatureSummary


def fit_calibration(table: ModelTable, references: Sequence[Reference]) -> Calibration:
    """ARR factor and TOF offset per sphere size from reference shots; globals as their means.

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
    """
    if not references:
        raise CalibrationError("references", "need at least one reference measurement")
    by_d: dict[float, list[tuple[float, float, float, float]]] = {}
    measured: dict[float, list[float]] = {}
    for ref in references:
        s = ref.summary
        d = float(table.axes["diameter_m"][table.diameter_index(s.diameter_m)])
        tof_m, arr_m, tof_sd, arr_sd = predict(table, d, ref.thickness_m, ref.distance_m,
                                               with_error=True)
        if arr_m <= 0:
            raise InversionError("arr", f"the model ARR at the reference is {arr_m:g}: no factor "
                                 "can be fitted there; use a thicker or closer reference")
        s_tof, s_arr = s.sigmas()
        # the reference's own error: its shots, and the table's interpolation error there
        f = s.arr / arr_m
        sf = math.hypot(s_arr, f * arr_sd) / arr_m
        by_d.setdefault(d, []).append((f, sf, s.tof_s - tof_m, math.hypot(s_tof, tof_sd)))
        measured.setdefault(d, []).append(s.arr)
    per: dict[float, dict[str, float]] = {}
    for d, rows in by_d.items():
        f, sf, o, so = (list(c) for c in zip(*rows, strict=True))
        f_mean, f_stat, f_transfer = _combine(f, sf)
        o_mean, o_stat, o_transfer = _combine(o, so)
        if not (math.isfinite(f_mean) and f_mean > 0):
            # ARR 0 at the reference: a factor of 0 would erase every model reflection
            arrs = ", ".join(f"{a:g}" for a in measured[d])
            raise CalibrationError("arr", f"the measured ARR at the reference (D = {d:g} m: "
                                   f"{arrs}) gives an ARR factor of {f_mean:g}; it must be > 0 "
                                   "(measure a reference where the reflection is seen)")
        if not all(math.isfinite(x) for x in (f_stat, f_transfer, o_mean, o_stat, o_transfer)):
            raise CalibrationError("tof", f"the reference shots at D = {d:g} m give a "
                                   "non-finite TOF offset or uncertainty")
        per[d] = {
            "arr_factor": f_mean,
            "arr_factor_std": math.hypot(f_stat, f_transfer),
            "arr_factor_transfer_std": f_transfer,
            "tof_offset_s": o_mean,
            "tof_offset_std_s": math.hypot(o_stat, o_transfer),
            "tof_offset_transfer_std_s": o_transfer,
            "n_references": len(rows),
        }
    n = len(per)
    reference = {
        "references": [{"thickness_m": r.thickness_m, "distance_m": r.distance_m,
                        **vars(r.summary)} for r in references],
        "table": str(table.path) if table.path else None,
    }
    return Calibration(sum(e["arr_factor"] for e in per.values()) / n,
                       sum(e["tof_offset_s"] for e in per.values()) / n, per, reference)
