"""The thickness-distance ridge: one answer, a widened one, or several readings.

Near a support a thinner plate nearer to it gives the features of a thicker one farther out, so
the likelihood on the (t, L) grid is a ridge. The marginal posterior of thickness weighs each part
of the ridge by how much of the table's distance range fits there (the prior's volume, uniform in
L), not by how well it fits: one shot 25 mm from a clamp fits a 3.0 mm plate at 25 mm as well as
a 3.25 mm plate anywhere beyond 30 mm, and the marginal, carried by the far part's 400 mm, gave
3.04-3.44 mm.

The profile likelihood of thickness (the best fit over every distance) has no such volume. Its
95 % set, the thicknesses whose profile is above the likelihood-ratio level of chi^2_1 = 3.84
(:data:`~solitonde.instrument.inference.marginals.LR_LEVELS`), is a union of runs on the grid. A
run counts where it reaches beyond the marginal's 95 % interval by more than :data:`REACH`; runs
the profile joins above the 99 % level are one (:data:`SEPARATE_LEVEL`). With the marginal's own
95 % interval the counted runs make groups (spans that touch or overlap merge):

* one group: the answer keeps its status, and its intervals reach over the group (the hull of the
  marginal's interval and the profile's runs at that level, 68 % and 95 % alike): each of the
  two has its stated coverage, so their hull has at least that;
* several groups, separated where the data fit worse than the 95 % level: the answer is
  ``ambiguous``. Each group is a *reading*: the posterior restricted to its thicknesses gives its
  median, its distance and its weight (the posterior's share), and its 95 % interval is the
  group's span, open where the group reaches an open end of the table. The answer's own 95 %
  interval is their hull.

Far from a support the profile and the marginal agree (TOF and ARR do not depend on L there):
nothing changes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TypedDict

import numpy as np

from solitonde.instrument.inference.marginals import (
    LR_LEVELS,
    ParameterDict,
    ParameterEstimate,
    _crossing,
    _quantiles,
    summarise_marginal,
)

Span = tuple[int, int]
"""An inclusive run of grid indices."""
REACH = 1.0
"""A run of the profile's 95 % set counts when it reaches beyond the marginal's 95 % interval by
more than this fraction of the interval's own reach on that side (from the median to the bound;
beyond a one-sided answer's bound, any run, unless none reaches past it by more than
:data:`ONE_SIDED_REACH`). Far from a support the profile runs a little wider than the marginal
everywhere, because some cell near the support fits each thickness a little off the answer;
counting those would widen every answer for thicknesses nothing in the data favours."""


ONE_SIDED_REACH = float(np.log(1.01))
"""A one-sided answer (no median to measure a reach from) counts the profile's runs beyond its
bound only when one of them reaches more than this past it (1 %, in log t). Counting any run
moved "at most 1.98 mm" to "at most 1.98 mm" and warned "another reading fits as well" of no
other reading: on the validation's draws a third to half of those warnings were such, and no
interval's coverage depended on them. When one reaches farther, all count, as before (a run
next to the bound can join a farther one to the answer)."""


SEPARATE_LEVEL = float(np.exp(-0.5 * 6.634896601021214))
"""The likelihood ratio (chi^2_1 of 6.63, the 99 % level) the profile must fall below between
two runs of its 95 % set for them to be separate readings."""


class ReadingDict(TypedDict):
    """A reading as JSON (:meth:`Reading.to_dict`)."""

    thickness_m: ParameterDict
    distance_m: ParameterDict
    weight: float


@dataclass
class Reading:
    """One of several readings of an ``ambiguous`` answer: where on the ridge, and how much of
    the posterior lies there."""

    thickness_m: ParameterEstimate
    distance_m: ParameterEstimate
    weight: float

    def to_dict(self) -> ReadingDict:
        return {"thickness_m": self.thickness_m.to_dict(), "distance_m": self.distance_m.to_dict(),
                "weight": self.weight}


def runs(mask: np.ndarray) -> list[Span]:
    """The maximal runs of True in a 1-D mask, as inclusive index spans."""
    if not mask.any():
        return []
    m = np.concatenate([[False], mask.astype(bool), [False]])
    edges = np.flatnonzero(m[1:] != m[:-1])
    return [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def _edges(x: np.ndarray, profile: np.ndarray, level: float, span: Span) -> tuple[float, float]:
    """Where the profile crosses ``level`` at a run's two ends, linear between grid points (the
    grid's own end where the run reaches it): a run's end is not a whole cell out."""
    a, b = span
    lo = _crossing(x[max(a - 1, 0):a + 1], profile[max(a - 1, 0):a + 1], level, from_left=True)
    hi = _crossing(x[b:b + 2], profile[b:b + 2], level, from_left=False)
    return lo, hi


def _bridged(spans: list[Span], profile: np.ndarray) -> list[Span]:
    """Runs whose gap the profile crosses above the 99 % likelihood-ratio level
    (:data:`SEPARATE_LEVEL`) merged: a dip that shallow between two runs is the table's
    interpolation wiggling about the 95 % level, not two readings."""
    out: list[Span] = []
    for a, b in spans:
        if out and profile[out[-1][1]:a + 1].min() >= SEPARATE_LEVEL:
            out[-1] = (out[-1][0], b)
        else:
            out.append((a, b))
    return out


def _merge(spans: list[Span]) -> list[Span]:
    """Spans that overlap or touch, merged; sorted."""
    out: list[Span] = []
    for a, b in sorted(spans):
        if out and a <= out[-1][1] + 1:
            out[-1] = (out[-1][0], max(out[-1][1], b))
        else:
            out.append((a, b))
    return out


def _index_span(x: np.ndarray, ci: tuple[float | None, float | None]) -> Span | None:
    """The grid indices inside an interval on x (an open side runs to the grid's end)."""
    lo = 0 if ci[0] is None else int(np.searchsorted(x, ci[0] - 1e-12 * abs(ci[0])))
    hi = x.size - 1 if ci[1] is None else int(np.searchsorted(x, ci[1] * (1 + 1e-12),
                                                              side="right")) - 1
    lo, hi = max(lo, 0), min(hi, x.size - 1)
    return (lo, hi) if lo <= hi else None


def _widen(ci: tuple[float | None, float | None], lo: float, hi: float
           ) -> tuple[float | None, float | None]:
    """An interval reached out to [lo, hi] (an open side stays open)."""
    return (None if ci[0] is None else min(ci[0], lo), None if ci[1] is None else max(ci[1], hi))


def resolve(thickness: ParameterEstimate, distance: ParameterEstimate, t_m: np.ndarray,
            distance_m: np.ndarray, density: Callable[[], np.ndarray], weight_t: np.ndarray,
            weight_l: np.ndarray, profile_t: np.ndarray, lower_physical: bool
            ) -> tuple[ParameterEstimate, ParameterEstimate, list[Reading]]:
    """The answer for thickness and distance with the ridge taken into account (module doc).

    ``density()`` gives the normalised posterior on the (t, L) grid (prior masses ``weight_t``
    and ``weight_l``; asked for only where the data fit separate readings), ``profile_t`` the
    likelihood ratio to the best cell, maximised over L, per thickness.
    Returns the thickness and distance answers and the readings (empty unless ``ambiguous``).
    """
    if thickness.status not in ("constrained", "lower_bound_only", "upper_bound_only"):
        return thickness, distance, []
    assert thickness.ci95 is not None
    log_t = np.log(t_m)
    ci95_log = tuple(None if v is None else float(np.log(v)) for v in thickness.ci95)
    own = _index_span(log_t, ci95_log)  # type: ignore[arg-type]
    lo_m = -np.inf if ci95_log[0] is None else ci95_log[0]
    hi_m = np.inf if ci95_log[1] is None else ci95_log[1]
    centre = None if thickness.median is None else float(np.log(thickness.median))
    reach_lo = 0.0 if centre is None else REACH * (centre - lo_m)
    reach_hi = 0.0 if centre is None else REACH * (hi_m - centre)
    profile_runs, beyond = [], 0.0
    for span in runs(profile_t >= LR_LEVELS[1]):
        a, b = _edges(log_t, profile_t, LR_LEVELS[1], span)
        if a < lo_m - reach_lo or b > hi_m + reach_hi:
            profile_runs.append(span)
            beyond = max(beyond, lo_m - a, b - hi_m)
    if centre is None and beyond <= ONE_SIDED_REACH:
        profile_runs = []  # a one-sided bound moved by no more than that: no other reading
    groups = _merge(_bridged(profile_runs, profile_t) + ([own] if own is not None else []))
    if len(groups) <= 1:
        return _widened(thickness, t_m, profile_t, profile_runs), distance, []
    post = density()
    like = post / (weight_t[:, None] * weight_l[None, :])
    like /= like.max()
    readings = [_reading(span, _bounds(span, profile_runs, own, thickness, log_t, profile_t),
                         thickness, t_m, distance_m, post, like, weight_t, weight_l,
                         lower_physical) for span in groups]
    total = sum(r.weight for r in readings) or 1.0
    for r in readings:
        r.weight /= total
    readings.sort(key=lambda r: -r.weight)
    lows = [r.thickness_m.ci95[0] for r in readings if r.thickness_m.ci95 is not None]
    highs = [r.thickness_m.ci95[1] for r in readings if r.thickness_m.ci95 is not None]
    hull_t = (None if None in lows else min(v for v in lows if v is not None),
              None if None in highs else max(v for v in highs if v is not None))
    answer_t = ParameterEstimate(None, None, None, hull_t, "ambiguous")
    return answer_t, _distance_answer(distance, readings), readings


def _widened(thickness: ParameterEstimate, t_m: np.ndarray, profile_t: np.ndarray,
             counted: list[Span]) -> ParameterEstimate:
    """A single group's answer: the marginal's intervals reached over the profile's runs that
    count (:data:`REACH`), 68 % and 95 % each at their own likelihood-ratio level."""
    if not counted:
        return thickness
    log_t = np.log(t_m)
    ci95 = thickness.ci95
    for span in counted:
        lo, hi = _edges(log_t, profile_t, LR_LEVELS[1], span)
        ci95 = _widen(ci95, float(np.exp(lo)), float(np.exp(hi)))  # type: ignore[arg-type]
    ci68 = thickness.ci68
    if ci68 is not None:
        own68 = _index_span(log_t, tuple(None if v is None else float(np.log(v))
                                         for v in ci68))  # type: ignore[arg-type]
        for span in runs(profile_t >= LR_LEVELS[0]):
            inside = any(c[0] <= span[0] and span[1] <= c[1] for c in counted)
            if inside and own68 is not None and span[0] <= own68[1] + 1 and span[1] >= own68[0] - 1:
                lo, hi = _edges(log_t, profile_t, LR_LEVELS[0], span)
                ci68 = _widen(ci68, float(np.exp(lo)), float(np.exp(hi)))
    return ParameterEstimate(thickness.map, thickness.median, ci68, ci95, thickness.status)


def _bounds(group: Span, profile_runs: list[Span], own: Span | None,
            answer: ParameterEstimate, log_t: np.ndarray, profile_t: np.ndarray
            ) -> tuple[float, float]:
    """A group's thickness span: the profile's crossings at its runs' ends and the marginal's
    own 95 % bounds where its interval is part of the group."""
    lo, hi = np.inf, -np.inf
    for span in profile_runs:
        if group[0] <= span[0] and span[1] <= group[1]:
            a, b = _edges(log_t, profile_t, LR_LEVELS[1], span)
            lo, hi = min(lo, a), max(hi, b)
    if own is not None and group[0] <= own[0] and own[1] <= group[1]:
        assert answer.ci95 is not None
        c_lo, c_hi = answer.ci95
        lo = min(lo, float(log_t[0]) if c_lo is None else float(np.log(c_lo)))
        hi = max(hi, float(log_t[-1]) if c_hi is None else float(np.log(c_hi)))
    return float(np.exp(lo)), float(np.exp(hi))


def _reading(span: Span, bounds: tuple[float, float], answer: ParameterEstimate,
             t_m: np.ndarray, distance_m: np.ndarray,
             post: np.ndarray, like: np.ndarray, weight_t: np.ndarray, weight_l: np.ndarray,
             lower_physical: bool) -> Reading:
    """One group of thicknesses as a reading: its share of the posterior, its thickness (the
    restricted marginal's median and 68 % interval, the group's span as its 95 % interval, open
    where the group reaches a side the whole answer leaves open) and its distance (the restricted
    posterior's marginal, by the usual rules)."""
    a, b = span
    sub = post[a:b + 1]
    mass_t = sub.sum(axis=1)
    weight = float(mass_t.sum())
    log_t = np.log(t_m[a:b + 1])
    low_open = a == 0 and answer.status == "upper_bound_only"
    high_open = b == t_m.size - 1 and answer.status == "lower_bound_only"
    lo95 = None if low_open else bounds[0]
    hi95 = None if high_open else bounds[1]
    if weight > 0 and b > a:
        q16, q50, q84 = (float(np.exp(v)) for v in _quantiles(log_t, mass_t, (0.16, 0.5, 0.84)))
        peak = float(t_m[a + int(np.argmax(mass_t / weight_t[a:b + 1]))])
    else:
        q16 = q50 = q84 = peak = float(t_m[a])
    if low_open or high_open:
        status = "upper_bound_only" if low_open else "lower_bound_only"
        t_est = ParameterEstimate(None, None, (None if low_open else q16,
                                               None if high_open else q84), (lo95, hi95), status)
    else:
        t_est = ParameterEstimate(peak, q50, (q16, q84), (lo95, hi95), "constrained")
    mass_l = sub.sum(axis=0)
    profile_l = like[a:b + 1].max(axis=0)
    d_est = (summarise_marginal(distance_m, mass_l, weight_l, lower_physical, profile=profile_l)
             if mass_l.sum() > 0 else ParameterEstimate(None, None, None, None, "unconstrained"))
    return Reading(t_est, d_est, weight)


def _distance_answer(distance: ParameterEstimate, readings: list[Reading]) -> ParameterEstimate:
    """The distance of an ambiguous answer: ``ambiguous`` with the readings' hull where two
    readings put the support at distances their 95 % intervals do not share, else the
    marginal's own answer."""
    spans = [r.distance_m.ci95 for r in readings]
    if any(s is None for s in spans):
        return distance
    los = [-np.inf if s[0] is None else s[0] for s in spans]  # type: ignore[index]
    his = [np.inf if s[1] is None else s[1] for s in spans]  # type: ignore[index]
    if max(los) <= min(his):
        return distance
    lo, hi = min(los), max(his)
    return ParameterEstimate(None, None, None, (None if not np.isfinite(lo) else float(lo),
                                                None if not np.isfinite(hi) else float(hi)),
                             "ambiguous")
