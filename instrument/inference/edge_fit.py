"""Locate a clamped edge from a scan: the straight line that the distance answers imply.

Each position ``(x, y)`` on the plate came with a distance-to-support answer: a median with 68 %
and 95 % intervals when constrained, a lower bound when the support is too far to be felt, an
upper bound when it is too close to tell how close. The edge is the line
``x cos(theta) + y sin(theta) = offset`` whose signed distance ``d_i = x_i cos(theta) + y_i
sin(theta) - offset`` best honours every answer: a constrained answer pulls ``d_i`` to its
median with the half-width of its 68 % interval on that side as the deviation (the interval, not
the point alone), a one-sided answer only penalises a ``d_i`` beyond its 68 % bound, with the
gap between its 68 % and 95 % bounds as the deviation. The fit minimises the sum of squared
normalised violations (a chi-square); the 95 % interval of the offset is where its profile,
minimised over the angle, rises by 3.84 above the minimum.

The positions cannot tell where the edge is when fewer than three answers say anything, fewer
than two are constrained (all far from any support), they lie on one line, or a line on their
other side (the edge's mirror image) fits within the 95 % chi-square level of the best, as it does
for positions standing along the edge at one distance; :func:`locate` then returns None and the
reason.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypedDict

import numpy as np
from scipy import optimize

SIGMA_FLOOR_M = 0.5e-3
"""Smallest deviation given to an answer: the table's own interpolation error is of this size."""
CHI2_95_1DOF = 3.841458820694124
COLLINEAR_M = 1e-4
"""Positions whose spread across their best line is under this (0.1 mm) lie on one line."""


@dataclass(frozen=True)
class Answer:
    """One position's distance answer, as the fit uses it."""

    x: float
    y: float
    kind: str  # "constrained", "lower_bound_only", "upper_bound_only"
    centre: float  # median (constrained) or the 68 % bound (one-sided)
    below: float  # deviation when the line puts the position nearer than centre
    above: float  # deviation when farther


class SupportFitDict(TypedDict):
    """A located edge as JSON (:meth:`SupportFit.to_dict`)."""

    normal_angle_deg: float
    offset_m: float
    ci95_offset_m: list[float]
    n_positions: int
    residual_m: float


@dataclass(frozen=True)
class SupportFit:
    """The located edge: ``x cos(theta) + y sin(theta) = offset`` with theta in degrees."""

    normal_angle_deg: float
    offset_m: float
    ci95_offset_m: tuple[float, float]
    n_positions: int
    residual_m: float
    chi2: float

    def distance(self, x: float, y: float) -> float:
        """Signed distance of ``(x, y)`` from the edge (positive on the plate's side)."""
        t = math.radians(self.normal_angle_deg)
        return x * math.cos(t) + y * math.sin(t) - self.offset_m

    def to_dict(self) -> SupportFitDict:
        return {"normal_angle_deg": self.normal_angle_deg, "offset_m": self.offset_m,
                "ci95_offset_m": list(self.ci95_offset_m), "n_positions": self.n_positions,
                "residual_m": self.residual_m}


def answers(positions: Sequence[Mapping[str, Any]]) -> list[Answer]:
    """The usable answers of ``positions`` (dicts with ``x_m``, ``y_m`` and ``distance_m`` as
    the inversion reports it: ``median``, ``ci68``, ``ci95``, ``status``)."""
    out = []
    for p in positions:
        d = p.get("distance_m") or {}
        x, y, status = p.get("x_m"), p.get("y_m"), d.get("status")
        if x is None or y is None or status not in ("constrained", "lower_bound_only",
                                                    "upper_bound_only"):
            continue
        lo68, hi68 = d["ci68"]
        lo95, hi95 = d["ci95"]
        if status == "constrained":
            m = d["median"]
            out.append(Answer(x, y, status, m, max(m - lo68, SIGMA_FLOOR_M),
                              max(hi68 - m, SIGMA_FLOOR_M)))
        elif status == "lower_bound_only":
            out.append(Answer(x, y, status, lo68, max(lo68 - lo95, SIGMA_FLOOR_M), math.inf))
        else:
            out.append(Answer(x, y, status, hi68, math.inf, max(hi95 - hi68, SIGMA_FLOOR_M)))
    return out


def _chi2(theta: float, offset: float, data: Sequence[Answer]) -> float:
    total = 0.0
    c, s = math.cos(theta), math.sin(theta)
    for a in data:
        d = a.x * c + a.y * s - offset
        dev = d - a.centre
        sigma = a.below if dev < 0 else a.above
        if math.isfinite(sigma):
            total += (dev / sigma) ** 2
        if d < 0:  # the chain stands on the plate: the edge is never between it and the plate
            total += (d / SIGMA_FLOOR_M) ** 2
    return total


def _best_offset(theta: float, data: Sequence[Answer], span: float) -> tuple[float, float]:
    res = optimize.minimize_scalar(lambda o: _chi2(theta, o, data), bounds=(-span, span),
                                   method="bounded", options={"xatol": 1e-6})
    return float(res.x), float(res.fun)


def locate(positions: Sequence[Mapping[str, Any]]) -> tuple[SupportFit | None, str | None]:
    """The edge the positions' distance answers imply, or None and the reason it cannot be told."""
    data = answers(positions)
    n_constrained = sum(a.kind == "constrained" for a in data)
    if len(data) < 3:
        return None, (f"{len(data)} position(s) with coordinates and a distance answer; at "
                      "least three are needed")
    if n_constrained < 2:
        return None, ("the positions are far from any support: fewer than two distance answers "
                      "are constrained (the others only bound it)")
    xy = np.array([[a.x, a.y] for a in data])
    centred = xy - xy.mean(axis=0)
    spread = np.linalg.svd(centred, compute_uv=False)
    if spread[1] <= COLLINEAR_M:
        return None, ("the positions lie on one line: the edge and its mirror image across it "
                      "fit equally well; add a position off that line")
    span = float(np.abs(xy).max() + max(a.centre for a in data) + 1.0)
    grid = np.radians(np.arange(0.0, 360.0, 2.0))
    scores = [(_best_offset(t, data, span), t) for t in grid]
    (offset, best), theta = min(scores, key=lambda item: item[0][1])
    mirror = min(score for (_o, score), t in scores
                 if abs((t - theta + math.pi) % (2 * math.pi) - math.pi) > math.pi / 2)
    if mirror - best < CHI2_95_1DOF:
        return None, ("the positions cannot tell on which side of them the edge lies: they "
                      "stand along it at one distance, and its mirror image fits as well; add "
                      "positions at other distances from it")
    res = optimize.minimize(lambda p: _chi2(p[0], p[1], data), [theta, offset],
                            method="Nelder-Mead", options={"xatol": 1e-7, "fatol": 1e-9})
    theta, offset = float(res.x[0]), float(res.x[1])
    chi2 = float(res.fun)

    def profile(o: float) -> float:
        r = optimize.minimize_scalar(lambda t: _chi2(t, o, data),
                                     bounds=(theta - 0.5, theta + 0.5), method="bounded")
        return float(r.fun) - chi2 - CHI2_95_1DOF

    bounds = []
    for sign in (-1.0, 1.0):
        step, edge = 1e-3, None
        while step < span:
            if profile(offset + sign * step) > 0:
                inner = offset + sign * (step / 2 if step > 1e-3 else 0.0)
                edge = optimize.brentq(profile, inner, offset + sign * step)
                break
            step *= 2
        bounds.append(edge if edge is not None else sign * math.inf)
    fit = SupportFit(math.degrees(theta) % 360.0, offset, (bounds[0], bounds[1]), len(data), 0.0,
                     chi2)
    resid = [fit.distance(a.x, a.y) - a.centre for a in data if a.kind == "constrained"]
    fit = SupportFit(fit.normal_angle_deg, offset, fit.ci95_offset_m, len(data),
                     float(np.sqrt(np.mean(np.square(resid)))), chi2)
    return fit, None
