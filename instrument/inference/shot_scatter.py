"""The rig's own per-shot scatter, measured on the calibration's reference shots, for the shots
that state none.

A single shot has no scatter of its own to state. Without a calibration the inversion assumes a
lab's shot-to-shot spread (:data:`~.inversion_inputs.DEFAULT_TOF_REL_STD`, 1 % of TOF, and
:data:`~.inversion_inputs.DEFAULT_ARR_STD`, 0.03 in ARR). A calibration fitted on references
shot several times has measured this rig's spread: the references' scatter pooled per sphere
size (TOF relative to its value, ARR absolute) with its degrees of freedom,
``sum(n_i - 1)``. A shot read with that calibration takes it instead of the assumed one.

The pooled value is itself an estimate from few shots, so it is widened to Student's t: the
standard deviation is multiplied by ``t_{0.975, dof} / 1.96``, which makes the Gaussian's 95 %
interval as wide as the t distribution's (1.18 for 8 degrees of freedom, 1.03 for 40): a rig
characterised by five shots does not give a single shot the confidence of one characterised by
fifty. Fewer than :data:`MIN_DOF` degrees of freedom give no value (the assumed spread stays).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import TypedDict

from solitonde.instrument.inference.inversion_inputs import (
    DEFAULT_ARR_STD,
    DEFAULT_TOF_REL_STD,
    FeatureSummary,
)

MIN_DOF = 2
"""Degrees of freedom below which a pooled scatter is not used (one reference of two shots)."""
Z_95 = 1.959963984540054
"""The standard normal's two-sided 95 % point."""


class ShotScatter(TypedDict):
    """A sphere size's pooled per-shot scatter on the references, as the calibration stores it."""

    shot_tof_rel_std: float
    shot_arr_std: float
    shot_scatter_dof: int


def pooled(references: Sequence[FeatureSummary]) -> ShotScatter | None:
    """The per-shot scatter pooled over one size's reference summaries that state theirs from
    two or more shots; None when they hold fewer than :data:`MIN_DOF` degrees of freedom."""
    dof = 0
    tof_ss = arr_ss = 0.0
    for s in references:
        if (s.n_shots < 2 or s.tof_std_s is None or s.arr_std is None or s.tof_s is None
                or s.tof_s <= 0):
            continue
        k = s.n_shots - 1
        dof += k
        tof_ss += k * (s.tof_std_s / s.tof_s) ** 2
        arr_ss += k * s.arr_std**2
    if dof < MIN_DOF:
        return None
    return {"shot_tof_rel_std": math.sqrt(tof_ss / dof), "shot_arr_std": math.sqrt(arr_ss / dof),
            "shot_scatter_dof": dof}


def none_stated(diameter_m: float) -> None:
    """The ``scatter_for`` of no calibration: no size has a measured scatter."""
    return None


def widening(dof: int) -> float:
    """The factor on a pooled standard deviation with ``dof`` degrees of freedom that gives a
    Gaussian the 95 % width of Student's t."""
    from scipy.stats import t as student_t  # scipy.stats takes a second to import

    return float(student_t.ppf(0.975, dof)) / Z_95


def fill(items: Sequence[FeatureSummary],
         scatter_for: Callable[[float], ShotScatter | None]
         ) -> tuple[list[FeatureSummary], list[str]]:
    """``items`` with the rig's scatter where a seen size states none (``scatter_for``: a
    sphere size's, as :meth:`~.calibration.Calibration.shot_scatter` gives it, None where there
    is none), and one note per size so read."""
    out: list[FeatureSummary] = []
    notes: list[str] = []
    for item in items:
        rig = scatter_for(item.diameter_m)
        if (rig is None or item.hidden or item.tof_s is None
                or (item.tof_std_s is not None and item.arr_std is not None)):
            out.append(item)
            continue
        k = widening(rig["shot_scatter_dof"])
        tof_rel, arr = k * rig["shot_tof_rel_std"], k * rig["shot_arr_std"]
        out.append(replace(item,
                           tof_std_s=item.tof_std_s if item.tof_std_s is not None
                           else tof_rel * item.tof_s,
                           arr_std=item.arr_std if item.arr_std is not None else arr))
        notes.append(
            f"D = {item.diameter_m * 1e3:.3g} mm: the per-shot scatter is the rig's, measured on "
            f"the calibration's reference shots (TOF {tof_rel * 100:.2g} %, ARR {arr:.2g}, from "
            f"{rig['shot_scatter_dof']} degrees of freedom, widened to Student's t), not the "
            f"{DEFAULT_TOF_REL_STD * 100:g} % of TOF and {DEFAULT_ARR_STD:g} in ARR assumed "
            "without it")
    return out, notes
