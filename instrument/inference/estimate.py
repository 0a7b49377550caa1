"""An inversion's answer (:class:`Estimate`): thickness and distance to the support, what the
inversion used, how well the table's family explains the data and what to read the answer with."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NotRequired, TypedDict

import numpy as np

from solitonde.instrument.inference import ridge
from solitonde.instrument.inference.calibration import Calibration, CalibrationDict
from solitonde.instrument.inference.inversion_inputs import FeatureSummary, FeatureSummaryDict
from solitonde.instrument.inference.marginals import ParameterDict, ParameterEstimate


class OtherReading(TypedDict):
    """An ambiguous answer's second reading: the thicknesses every reading spans, and the second
    most probable reading's thickness and distance (None where it has no number)."""

    thickness_m: list[float]
    thickness_at_m: float
    distance_m: float | None


class RidgeWidened(TypedDict):
    """The thickness's 95 % interval before and after the profile likelihood widened it."""

    marginal_ci95: list[float | None]
    ci95: list[float | None]


class EstimateExtra(TypedDict, total=False):
    """What the inversion leaves for the adequacy check and the answer's readers beside the
    numbers: the sizes left out, the ridge's widening, the second reading, the effective number of
    parameters the data fix (``p_d``), the material's posterior shift (in its spread's standard
    deviations), and per seen size the posterior's weight on floor cells and the probability that
    its features are explained without the floor's looseness."""

    excluded_diameters_m: list[float]
    ridge_widened: RidgeWidened
    other_reading: OtherReading
    p_d: float
    material_shift_sd: list[float]
    floor_mass: dict[float, float]
    strict_explained: dict[float, float]


class FitDict(TypedDict):
    """How well the table's family explains the data (None where nothing was fitted)."""

    chi2: float | None
    dof: float | None
    p_value: float | None


class EstimateDict(TypedDict):
    """An estimate as files and answers hold it (:meth:`Estimate.to_dict`); ``posterior`` only
    where it was asked for."""

    thickness_m: ParameterDict
    distance_m: ParameterDict
    chi2_min: float | None  # None once made JSON-ready where no cell was finite
    n_terms: int
    fit: FitDict
    warnings: list[str]
    reason: str | None
    inputs: list[FeatureSummaryDict]
    excluded_diameters_m: list[float]
    calibration: CalibrationDict | None
    material_spread: dict[str, float] | None
    other_reading: OtherReading | None
    readings: list[ridge.ReadingDict]
    material_shift_sd: list[float] | None
    posterior: NotRequired[dict[str, list[Any]]]  # per axis or grid name, its values as lists


@dataclass
class Estimate:
    """Thickness and distance to the support, with what the inversion used, how well the table's
    family explains the data (``fit``) and what the answer should be read with (``warnings``)."""

    thickness_m: ParameterEstimate
    distance_m: ParameterEstimate
    inputs: list[FeatureSummary]
    calibration: Calibration | None
    chi2_min: float
    n_terms: int
    reason: str | None = None
    posterior: dict[str, np.ndarray] | None = None
    extra: EstimateExtra = field(default_factory=EstimateExtra)
    fit: FitDict = field(default_factory=lambda: FitDict(chi2=None, dof=None, p_value=None))
    warnings: list[str] = field(default_factory=list)
    material_spread: dict[str, float] | None = None
    readings: list[ridge.Reading] = field(default_factory=list)
    """An ``ambiguous`` answer's readings along the thickness-distance ridge (:mod:`.ridge`),
    most probable first; empty otherwise."""

    @property
    def out_of_range(self) -> bool:
        return self.thickness_m.status == "out_of_range"

    @property
    def inconsistent(self) -> bool:
        """Whether the table's family does not explain the data (out of range included)."""
        return self.thickness_m.status in ("inconsistent", "out_of_range")

    def to_dict(self, posterior: bool = False) -> EstimateDict:
        out: EstimateDict = {
            "thickness_m": self.thickness_m.to_dict(),
            "distance_m": self.distance_m.to_dict(),
            "chi2_min": self.chi2_min,
            "n_terms": self.n_terms,
            "fit": FitDict(chi2=self.fit["chi2"], dof=self.fit["dof"],
                           p_value=self.fit["p_value"]),
            "warnings": list(self.warnings),
            "reason": self.reason,
            "inputs": [i.to_dict() for i in self.inputs],
            "excluded_diameters_m": list(self.extra.get("excluded_diameters_m", [])),
            "calibration": None if self.calibration is None else self.calibration.to_dict(),
            "material_spread": None if self.material_spread is None else dict(
                self.material_spread),
            "other_reading": self.extra.get("other_reading"),
            "readings": [r.to_dict() for r in self.readings],
            "material_shift_sd": self.extra.get("material_shift_sd"),
        }
        if posterior and self.posterior is not None:
            out["posterior"] = {k: v.tolist() for k, v in self.posterior.items()}
        return out


def second_reading(readings: list[ridge.Reading], thickness_m: np.ndarray) -> OtherReading:
    """An ambiguous answer's ``other_reading``: the thicknesses of every reading (an open side
    at the table's end) and the second most probable reading's thickness and distance."""
    lows = [r.thickness_m.ci95[0] if r.thickness_m.ci95 else None for r in readings]
    highs = [r.thickness_m.ci95[1] if r.thickness_m.ci95 else None for r in readings]
    lo = min(float(thickness_m[0]) if v is None else v for v in lows)
    hi = max(float(thickness_m[-1]) if v is None else v for v in highs)
    t2, d2 = readings[1].thickness_m, readings[1].distance_m
    t_at = t2.median if t2.median is not None else next(
        v for v in (t2.ci95 or (None, None)) if v is not None)
    d_at = d2.median if d2.median is not None else next(
        (v for v in (d2.ci95 or (None, None)) if v is not None), None)
    return {"thickness_m": [lo, hi], "thickness_at_m": float(t_at), "distance_m": d_at}


def out_of_range(inputs: list[FeatureSummary], cal: Calibration | None, chi2_min: float,
                 n_terms: int, reason: str) -> Estimate:
    """The answer where no table point explains the measurement: no numbers, only why."""
    nothing = ParameterEstimate(None, None, None, None, "out_of_range")
    return Estimate(nothing, ParameterEstimate(None, None, None, None, "out_of_range"), inputs,
                    cal, chi2_min, n_terms, reason)
