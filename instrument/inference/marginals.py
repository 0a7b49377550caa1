"""A parameter's answer from its marginal posterior on a grid: MAP, median, intervals, status.

The rules :func:`solitonde.instrument.inference.inversion.invert` states for each parameter: a
two-sided answer's intervals are central quantiles of the marginal; a side where the data do not
bound the parameter (the density at the table's end near its peak, or the profile likelihood there
above the 95 % likelihood-ratio level) is open, and a one-sided answer reports the
likelihood-ratio bound, not a quantile.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TypedDict

import numpy as np

EDGE_FRACTION = 0.2
"""A marginal posterior with at least this fraction of its peak density at a table end is open
there (the data do not bound the parameter on that side)."""
LR_LEVELS = (math.exp(-0.5), math.exp(-0.5 * 3.841458820694124))
"""Ratios of the marginal posterior density to its peak that bound a one-sided 68 % and 95 %
answer, the levels of a likelihood-ratio interval for one parameter (chi^2_1 of 1 and 3.84): the
bound then follows the data, not how far the table extends."""


class ParameterDict(TypedDict):
    """A parameter's answer as JSON (:meth:`ParameterEstimate.to_dict`)."""

    map: float | None
    median: float | None
    ci68: list[float | None] | None
    ci95: list[float | None] | None
    status: str


@dataclass
class ParameterEstimate:
    """One parameter's answer. Numbers the data do not support are None."""

    map: float | None
    median: float | None
    ci68: tuple[float | None, float | None] | None
    ci95: tuple[float | None, float | None] | None
    status: str

    def to_dict(self) -> ParameterDict:
        return {"map": self.map, "median": self.median,
                "ci68": None if self.ci68 is None else list(self.ci68),
                "ci95": None if self.ci95 is None else list(self.ci95), "status": self.status}



def _quantiles(x: np.ndarray, mass: np.ndarray, qs: Sequence[float]) -> list[float]:
    """Quantiles of a distribution given as the mass of each point's cell (cells from midpoint
    to midpoint between the points, half cells at the ends; mass spread evenly in a cell)."""
    if x.size == 1:
        return [float(x[0])] * len(qs)
    edges = np.concatenate([x[:1], 0.5 * (x[1:] + x[:-1]), x[-1:]])
    cdf = np.concatenate([[0.0], np.cumsum(mass)])
    cdf /= cdf[-1]
    return [float(np.interp(q, cdf, edges)) for q in qs]


def _crossing(x: np.ndarray, density: np.ndarray, level: float, from_left: bool) -> float:
    """Where ``density`` first reaches ``level`` walking in from one end (linear between points)."""
    order = range(x.size) if from_left else range(x.size - 1, -1, -1)
    prev = None
    for i in order:
        if density[i] >= level:
            if prev is None:
                return float(x[i])
            f = (level - density[prev]) / (density[i] - density[prev])
            return float(x[prev] + f * (x[i] - x[prev]))
        prev = i
    return float(x[-1] if from_left else x[0])


def summarise_marginal(x: np.ndarray, mass: np.ndarray, widths: np.ndarray,
                       lower_physical: bool, transform: Callable[[float], float] | None = None,
                       profile: np.ndarray | None = None) -> ParameterEstimate:
    """MAP, median, intervals and status of a marginal posterior given as the mass of each point
    of ``x`` (cells of ``widths``); ``transform`` maps x back to the parameter (exp for log t)."""
    est = _summarise_x(x, mass, widths, lower_physical, profile)
    if transform is None:
        return est

    def f(v: float | None) -> float | None:
        return None if v is None else float(transform(v))

    Pair = tuple[float | None, float | None] | None

    def pair(c: Pair) -> Pair:
        return None if c is None else (f(c[0]), f(c[1]))

    return ParameterEstimate(f(est.map), f(est.median), pair(est.ci68), pair(est.ci95), est.status)


def _summarise_x(x: np.ndarray, mass: np.ndarray, widths: np.ndarray,
                 lower_physical: bool, profile: np.ndarray | None = None) -> ParameterEstimate:
    """The summary of :func:`summarise_marginal` on the grid's own axis.

    A side is open (the data do not bound the parameter there) when the density at the table's end
    is at least :data:`EDGE_FRACTION` of its peak, or when the profile likelihood there (the best
    fit over the other parameter, relative to the overall best) is above the 95 % likelihood-ratio
    level: a marginal can fall towards an end only because less of the other parameter's range
    fits there (near a support thickness and distance trade off, and thin plates fit a narrower
    band of L), which is prior volume, not evidence against that end. A physical limit (L = 0) is
    never open. A one-
    sided answer reports the likelihood-ratio bound (:data:`LR_LEVELS`), not a quantile: with the
    density flat out to the table's end, a quantile would follow the table's extent, not the data.
    At a physical limit an interval whose end falls in the limit's own cell starts there.
    """
    density = mass / widths
    peak = density.max()
    q = _quantiles(x, mass, (0.025, 0.16, 0.5, 0.84, 0.975))
    ends = np.zeros(2, dtype=bool) if profile is None else profile[[0, -1]] >= LR_LEVELS[1]
    lower_open = x.size > 1 and not lower_physical and (density[0] >= EDGE_FRACTION * peak
                                                         or bool(ends[0]))
    upper_open = x.size > 1 and (density[-1] >= EDGE_FRACTION * peak or bool(ends[1]))
    if lower_open and upper_open:
        return ParameterEstimate(None, None, None, None, "unconstrained")
    if upper_open:
        b68, b95 = (_crossing(x, density, lv * peak, from_left=True) for lv in LR_LEVELS)
        if lower_physical:
            b68, b95 = (float(x[0]) if b <= 0.5 * (x[0] + x[1]) else b for b in (b68, b95))
        return ParameterEstimate(None, None, (b68, None), (b95, None), "lower_bound_only")
    if lower_open:
        b68, b95 = (_crossing(x, density, lv * peak, from_left=False) for lv in LR_LEVELS)
        return ParameterEstimate(None, None, (None, b68), (None, b95), "upper_bound_only")
    if lower_physical and x.size > 1:
        first_cell = 0.5 * (x[0] + x[1])
        q = [float(x[0]) if (k < 2 and v <= first_cell) else v for k, v in enumerate(q)]
    return ParameterEstimate(float(x[int(np.argmax(density))]), q[2], (q[1], q[3]), (q[0], q[4]),
                             "constrained")

