"""Where to put the chain next: the positions whose measurement would shrink the edge's interval
(or the thickness map's) the most, from a scan's joint posterior (:mod:`.joint_map`).

Expected variance reduction, by simulating the measurement from the table under the posterior:

1. The edge's posterior is drawn as :data:`PARTICLES` equally weighted edges (its cells
   resampled by their probability, each jittered inside its cell); :data:`TRUTHS` of them serve
   as the truth a measurement would come from.
2. A measurement at distance ``L0`` from the nearer support is simulated from the table: the
   model's TOF and ARR at the scan's typical thickness (the median of the positions' joint
   medians, or the common mean) and ``L0``, through the positions' calibration, with the shot
   noise of the scan's own positions (their median per-shot scatter over their median shot
   count; :data:`NOISE_DRAWS` draws each) -- a sphere size that would show no reflection there
   enters with its ARR bound, as a measured one would. Each simulated measurement is inverted
   with the inversion's own likelihood (:func:`~.inversion.cell_likelihood`), its thickness
   free, giving how likely it makes every distance: ``m(L | y)``. These curves are computed once
   for every ``L0`` of the fine distance grid and shifted for the ``L0`` in between.
3. For a candidate point q, truth k puts q at ``L0 = L_q(edge_k)``; the measurement's curve
   weighs every particle m by ``m(L_q(edge_m) | y_k)``; the edge's variance under those weights
   is what would remain. The edge's spread is measured where it matters: the signed distance of
   the located edge's two ends (the region's extent along it) from each particle's edge; its 95 %
   interval is ``3.92 sqrt(mean variance of the two)``. For the thickness map, the positions'
   thickness variances (each position's thickness given its distance, mixed over the weighted
   particles).
4. ``expected_gain``: the 95 % interval now less its expectation over the truths after the
   measurement, in metres. N positions are chosen greedily: the k-th is the best given the
   earlier ones (each truth's weights multiply), and its gain is what it adds to them.

Candidates lie on lines parallel to the located edge (along its extent inside the region, at
distances from 10 mm to the middle of the plate from either support) and on a 24 x 24 grid over
the region (where the located edge may be the wrong one, points that tell the likely edges
apart), inside the region (the
plate's rectangle in the scan's frame where the family states its size), at least 10 mm from
the edges under at least half the likely edges (:data:`MIN_DISTANCE_M`: the table is least
trustworthy there) and 15 mm from the positions already measured. Where a likely edge puts a
candidate off the plate, the chain would stand on the clamp, which reads as the clamped edge
itself (L = 0).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NotRequired, TypedDict

import numpy as np

from solitonde.instrument.inference.calibration import calibrated_table, calibration_along
from solitonde.instrument.inference.fine_grid import predict
from solitonde.instrument.inference.inversion_inputs import FeatureSummary, InversionError
from solitonde.instrument.inference.joint_answers import PositionAnswer, position_answer
from solitonde.instrument.inference.joint_model import JointMapError
from solitonde.instrument.inference.joint_posterior import JointPosterior
from solitonde.instrument.inference.likelihood import cell_likelihood
from solitonde.instrument.tables.table import ModelTable

PARTICLES = 256
TRUTHS = 48
NOISE_DRAWS = 2
SEED = 20261
"""Fixed: the same scan gives the same suggestions."""
MAX_SUGGEST = 20
OBJECTIVES = ("edge", "thickness")
Z95 = 3.919927969080108
"""A 95 % interval's width over its standard deviation (2 x 1.96)."""
CANDIDATE_DISTANCES_M = (0.010, 0.012, 0.014, 0.016, 0.018, 0.020, 0.023, 0.026, 0.030, 0.035,
                         0.040, 0.050, 0.065, 0.080, 0.100, 0.130, 0.170, 0.220, 0.300, 0.400)
MIN_DISTANCE_M = 0.010
"""No suggestion closer to a likely edge than this: the table's first distance node beyond the
clamp. Closer in, its features are interpolated over the span where they change fastest, and a
few millimetres of the edge's uncertainty put the chain on the clamp; the simulated measurement
(the table itself) would promise more than a real one there gives."""
MIN_SPACING_M = 0.015
"""Nor within this of a position already measured: a repeat averages that position's shot
noise, not the table's error at its distance."""
ALONG_STEPS = 25
GRID_STEPS = 24
CHUNK = 32
UNIFORM_STEP_M = 5e-4
"""The curves' resampling step: half a millimetre."""


def check_request(n: Any, objective: Any) -> tuple[int, str]:
    """``(n, objective)`` validated; JointMapError naming ``suggest`` or ``suggest_for``."""
    if isinstance(n, bool) or not isinstance(n, int) or not 0 <= n <= MAX_SUGGEST:
        raise JointMapError("suggest", f"{n!r} (allowed: an integer 0..{MAX_SUGGEST})")
    if objective not in OBJECTIVES:
        raise JointMapError("suggest_for", f"{objective!r} (allowed: {', '.join(OBJECTIVES)})")
    return n, objective


@dataclass(frozen=True)
class _Measurement:
    """What a new position's shots would be like: per sphere size its diameter, per-shot
    scatter of TOF and ARR, and shot count (the scan's medians)."""

    sizes: tuple[tuple[float, float | None, float | None, int, float | None], ...]
    thickness_m: float


def _typical(post: JointPosterior, answers: Sequence[PositionAnswer]) -> _Measurement:
    by_size: dict[float, list[FeatureSummary]] = {}
    bounds: dict[float, list[float]] = {}
    for lk in post.likes:
        for s in lk.position.inputs:
            by_size.setdefault(s.diameter_m, []).append(s)
            if s.hidden and s.arr_upper_bound is not None:
                bounds.setdefault(s.diameter_m, []).append(float(s.arr_upper_bound))
    sizes = []
    for d, items in sorted(by_size.items()):
        seen = [i for i in items if not i.hidden]
        tof_std = [i.tof_std_s for i in seen if i.tof_std_s is not None]
        arr_std = [i.arr_std for i in seen if i.arr_std is not None]
        bound = float(np.median(bounds[d])) if d in bounds else None
        sizes.append((d, float(np.median(tof_std)) if tof_std else None,
                      float(np.median(arr_std)) if arr_std else None,
                      int(np.median([i.n_shots for i in items])), bound))
    if post.prior.kind == "common":
        _, w = post.hyper_weights()
        thickness = math.exp(float(np.sum(w * post.log_mu) / w.sum()))
    else:
        medians = [a.thickness.median for a in answers if a.thickness.median is not None]
        bounds_t = [b for a in answers if a.thickness.ci95 for b in a.thickness.ci95
                    if b is not None]
        thickness = float(np.median(medians or bounds_t or [math.exp(
            float(np.median(post.likes[0].log_t)))]))
    return _Measurement(tuple(sizes), float(thickness))


def _curves(post: JointPosterior, meas: _Measurement) -> np.ndarray:
    """``log m(L | y)`` (normalised to a maximum of 0) for a measurement simulated at every
    ``L0`` of the fine grid, :data:`NOISE_DRAWS` noise draws each: (L0, draw, L)."""
    table = post.table
    lk0 = post.likes[0]
    cal = lk0.position.calibration
    spread = lk0.estimate.material_spread
    grid = post.distance_grid
    t = float(np.clip(meas.thickness_m, table.axes["thickness_m"][0],
                      table.axes["thickness_m"][-1]))
    key = ("suggest-curves", meas, None if cal is None else repr(cal.to_dict()),
           None if spread is None else tuple(sorted(spread.items())))
    cached = table._cache.get(key)
    if cached is not None:
        return cached
    rng = np.random.default_rng(SEED)
    model = calibrated_table(table, cal)  # the features a calibrated chain would measure
    out = np.empty((grid.size, NOISE_DRAWS, grid.size))
    w_t = lk0.weight_t
    for j, l0 in enumerate(grid):
        for r in range(NOISE_DRAWS):
            inputs = []
            for d, s_tof, s_arr, n, bound in meas.sizes:
                try:
                    tof, arr = predict(model, d, t, float(l0))
                except InversionError:  # no reflection there: the size's bound, as measured
                    b = bound if bound is not None else _table_bound(table, d)
                    inputs.append(FeatureSummary(d, None, None, n_shots=n, arr_upper_bound=b))
                    continue
                probe = FeatureSummary(d, tof, arr, s_tof, s_arr, n)
                e_tof, e_arr = probe.sigmas()
                factor, offset = (float(v) for v in calibration_along(cal, d, float(l0))[:2])
                inputs.append(FeatureSummary(
                    d, tof + offset + e_tof * rng.standard_normal(),
                    max(factor * arr + e_arr * rng.standard_normal(), 0.0), s_tof, s_arr, n))
            keep = cell_likelihood(table, inputs, cal, material_spread=spread)
            dev = keep["deviance"]
            finite = np.isfinite(dev)
            best = float(dev[finite].min()) if finite.any() else 0.0
            like = np.where(finite, np.exp(-0.5 * (np.where(finite, dev, best) - best)), 0.0)
            m = w_t @ like
            out[j, r] = np.log(m, out=np.full_like(m, -1e4), where=m > 0)
            out[j, r] -= out[j, r].max()
    # on a uniform grid, so that a distance's cell is arithmetic, not a search
    step = UNIFORM_STEP_M
    uniform = np.arange(grid[0], grid[-1] + 0.5 * step, step)
    flat = out.reshape(-1, grid.size)
    resampled = np.empty((flat.shape[0], uniform.size))
    for k in range(flat.shape[0]):
        resampled[k] = np.interp(uniform, grid, flat[k])
    out = resampled.reshape(grid.size, NOISE_DRAWS, uniform.size)
    table._cache[key] = out
    return out


def _table_bound(table: ModelTable, diameter_m: float) -> float:
    i = table.diameter_index(diameter_m)
    bounds = np.asarray(table.features["arr_upper_bound"][i], dtype=float)
    return float(np.nanmedian(bounds)) if np.isfinite(bounds).any() else 0.02


def region_of(post: JointPosterior, plate_size_m: Sequence[float] | None
              ) -> tuple[float, float, float, float]:
    """Where a position may go: the plate's rectangle ``[0, size_x] x [0, size_y]`` in the
    scan's frame when the family states its size and every position lies inside it, else the
    positions' bounding box widened by a tenth of its diagonal (at least 50 mm)."""
    xy = np.array([[lk.position.x_m, lk.position.y_m] for lk in post.likes])
    if plate_size_m and len(plate_size_m) >= 2:
        sx, sy = float(plate_size_m[0]), float(plate_size_m[1])
        if (xy[:, 0] >= 0).all() and (xy[:, 0] <= sx).all() and (xy[:, 1] >= 0).all() \
                and (xy[:, 1] <= sy).all():
            return 0.0, sx, 0.0, sy
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    pad = max(0.05, 0.1 * float(np.hypot(*(hi - lo))))
    return float(lo[0] - pad), float(hi[0] + pad), float(lo[1] - pad), float(hi[1] + pad)


@dataclass
class _Particles:
    theta: np.ndarray
    c: np.ndarray


def _particles(post: JointPosterior, rng: np.random.Generator) -> _Particles:
    cells = post.cells
    u = (rng.random() + np.arange(PARTICLES)) / PARTICLES
    idx = np.minimum(np.searchsorted(np.cumsum(post.mass), u), post.mass.size - 1)
    rng.shuffle(idx)
    theta = cells.theta[idx] + (rng.random(PARTICLES) - 0.5) * cells.h_theta[idx]
    c = cells.c[idx] + (rng.random(PARTICLES) - 0.5) * cells.h_c[idx]
    return _Particles(theta, c)


def _signed(post: JointPosterior, parts: _Particles, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Signed distance of points (x, y) from each particle's edge: (points, particles)."""
    dx, dy = np.atleast_1d(x) - post.anchor[0], np.atleast_1d(y) - post.anchor[1]
    return (np.outer(dx, np.cos(parts.theta)) + np.outer(dy, np.sin(parts.theta))
            + parts.c[None, :])


class Suggestion(TypedDict):
    """A next position, what it is expected to gain and its distance from the located edge."""

    x_m: float
    y_m: float
    expected_gain: float
    distance_m: float


class Suggestions(TypedDict):
    """What :func:`suggest` answers: the positions, and the 95 % interval before and after
    (or why there is none)."""

    objective: str
    suggestions: list[Suggestion]
    reason: NotRequired[str]
    interval_95_m: NotRequired[float]
    expected_interval_95_m: NotRequired[float]
    thickness_m: NotRequired[float]


@dataclass
class _Frame:
    """The located edge (the joint posterior's best cell) and the region's extent along it."""

    normal: np.ndarray
    along: np.ndarray
    offset_m: float
    s_lo: float
    s_hi: float

    @classmethod
    def of(cls, post: JointPosterior, region: Sequence[float]) -> _Frame:
        x0, x1, y0, y1 = region
        theta_b = float(post.cells.theta[post.best])
        normal = np.array([math.cos(theta_b), math.sin(theta_b)])
        along = np.array([-normal[1], normal[0]])
        corners = np.array([[x0, y0], [x0, y1], [x1, y0], [x1, y1]])
        return cls(normal, along, float(post.offsets()[post.best]),
                   float((corners @ along).min()), float((corners @ along).max()))

    @property
    def ends(self) -> np.ndarray:
        """The located edge's two ends in the region."""
        return np.array([self.offset_m * self.normal + s * self.along
                         for s in (self.s_lo, self.s_hi)])


def _candidates(post: JointPosterior, parts: _Particles, frame: _Frame,
                region: Sequence[float]) -> np.ndarray:
    """The candidate points (see the module doc): on lines parallel to the located edge and
    on a grid over the region, kept where most likely edges leave them on the plate, clear of
    the clamp and of the positions already measured."""
    x0, x1, y0, y1 = region
    s_vals = np.linspace(frame.s_lo, frame.s_hi, ALONG_STEPS + 2)[1:-1]
    u_vals = list(CANDIDATE_DISTANCES_M)
    if post.model.kind == "opposite_edges":
        u_vals += [post.model.width - u for u in CANDIDATE_DISTANCES_M
                   if u < 0.5 * post.model.width]
    u_vals = [u for u in u_vals if u <= (post.model.width_m or math.inf)]
    ss, uu = np.meshgrid(s_vals, np.array(u_vals), indexing="ij")
    pts = ((frame.offset_m * frame.normal)[None, :] + ss.ravel()[:, None] * frame.along
           + uu.ravel()[:, None] * frame.normal)
    # and a grid over the whole region: where the located edge may be the wrong one (few
    # positions, a mirror image), points that tell the likely edges apart
    gx, gy = np.meshgrid(np.linspace(x0, x1, GRID_STEPS + 2)[1:-1],
                         np.linspace(y0, y1, GRID_STEPS + 2)[1:-1], indexing="ij")
    pts = np.concatenate([pts, np.column_stack([gx.ravel(), gy.ravel()])])
    inside = (pts[:, 0] >= x0) & (pts[:, 0] <= x1) & (pts[:, 1] >= y0) & (pts[:, 1] <= y1)
    pts = pts[inside]
    if pts.size:  # where the plate most likely is, not next to a likely clamp
        d_p = _signed(post, parts, pts[:, 0], pts[:, 1])
        clear = post.model.on_plate(d_p - MIN_DISTANCE_M)
        if post.model.kind == "opposite_edges":
            clear &= post.model.on_plate(d_p + MIN_DISTANCE_M)
        pts = pts[clear.mean(axis=1) >= 0.5]
    if pts.size:
        xy = np.array([[lk.position.x_m, lk.position.y_m] for lk in post.likes])
        gap = np.hypot(pts[:, None, 0] - xy[None, :, 0], pts[:, None, 1] - xy[None, :, 1])
        pts = pts[gap.min(axis=1) >= MIN_SPACING_M]
    return pts


@dataclass
class _Objective:
    """What a measurement is to shrink: the spread of the located edge's two ends over the
    particles (``edge``), or the positions' thickness intervals (``thickness``: each
    position's conditional moments of log t at its distance under every particle)."""

    kind: str
    z_ends: np.ndarray
    """(2, particles): the ends' signed distance from each particle's edge."""
    mean_l: np.ndarray | None = None
    var_l: np.ndarray | None = None
    scale: np.ndarray | None = None

    @classmethod
    def of(cls, kind: str, post: JointPosterior, parts: _Particles, frame: _Frame,
           answers: Sequence[PositionAnswer]) -> _Objective:
        ends = frame.ends
        z_ends = _signed(post, parts, ends[:, 0], ends[:, 1])  # (2, particles)
        if kind != "thickness":
            return cls(kind, z_ends)
        grid = post.distance_grid
        xy = np.array([[lk.position.x_m, lk.position.y_m] for lk in post.likes])
        dist = np.clip(post.model.distance(_signed(post, parts, xy[:, 0], xy[:, 1])),
                       grid[0], grid[-1])
        mean_l = np.array([np.interp(dist[i], grid, a.conditional[0])
                           for i, a in enumerate(answers)])
        var_l = np.array([np.interp(dist[i], grid, a.conditional[1])
                          for i, a in enumerate(answers)])
        scale = np.array([math.exp(float(np.mean(m))) for m in mean_l])  # t, to turn log into m
        return cls(kind, z_ends, mean_l, var_l, scale)

    def width(self, logw: np.ndarray) -> np.ndarray:
        """Expected 95 % interval over the truths, for weights (..., truths, particles)."""
        w = np.exp(logw - logw.max(axis=-1, keepdims=True))
        w /= w.sum(axis=-1, keepdims=True)
        if self.mean_l is None or self.var_l is None or self.scale is None:
            m1 = w @ self.z_ends.T  # (..., truths, 2)
            m2 = w @ (self.z_ends**2).T
            var = np.maximum(m2 - m1**2, 0.0).mean(axis=-1)
            return Z95 * np.sqrt(var).mean(axis=-1)
        total = np.zeros(w.shape[:-1])
        for i in range(len(self.mean_l)):
            e1 = w @ self.mean_l[i]
            e2 = w @ (self.var_l[i] + self.mean_l[i] ** 2)
            total += Z95 * self.scale[i] * np.sqrt(np.maximum(e2 - e1**2, 0.0))
        return (total / len(self.mean_l)).mean(axis=-1)


def _log_weights(curves: np.ndarray, grid: np.ndarray, l_c: np.ndarray, truths: np.ndarray,
                 draws: np.ndarray) -> np.ndarray:
    """Log weights (candidates, truths, particles) of a measurement at every candidate: each
    truth puts the candidate at its distance ``L0``, and the measurement simulated there
    weighs each particle by how likely it makes the particle's distance of the candidate."""
    last = curves.shape[-1] - 1

    def logw_of(rows: np.ndarray) -> np.ndarray:
        l0 = l_c[rows][:, truths]  # (B, truths): where each truth puts the candidate
        e = np.clip(np.searchsorted(grid, l0) - 1, 0, grid.size - 2)
        e = np.where(np.abs(grid[e + 1] - l0) < np.abs(grid[e] - l0), e + 1, e)
        shift = l0 - grid[e]
        x = (l_c[rows][:, None, :] - shift[:, :, None] - grid[0]) / UNIFORM_STEP_M
        x = np.clip(x, 0.0, last)
        j = np.minimum(x.astype(np.intp), last - 1)
        f = x - j
        rows_c = curves[e, draws[None, :]]  # (B, truths, L)
        lo = np.take_along_axis(rows_c, j, axis=-1)
        hi = np.take_along_axis(rows_c, j + 1, axis=-1)
        return lo + (hi - lo) * f

    # every candidate's log weights once (float32: they are compared, not accumulated far)
    n = l_c.shape[0]
    return np.concatenate([logw_of(np.arange(k, min(k + CHUNK, n))).astype(np.float32)
                           for k in range(0, n, CHUNK)])


def _greedy(post: JointPosterior, n: int, pts: np.ndarray, lw_all: np.ndarray,
            objective: _Objective, frame: _Frame, out: Suggestions) -> None:
    """Choose ``n`` positions one at a time, each the best given the earlier ones, into
    ``out`` with the interval before and after."""
    acc = np.zeros(lw_all.shape[1:], dtype=np.float32)
    now = float(objective.width(acc[None])[0])
    out["interval_95_m"] = now
    chosen: list[int] = []
    for _ in range(n):
        vals = np.concatenate([objective.width(lw_all[k:k + CHUNK] + acc[None])
                               for k in range(0, len(pts), CHUNK)])
        vals[chosen] = math.inf
        best_row = int(np.argmin(vals))
        if not math.isfinite(vals[best_row]):
            break
        best_val = float(vals[best_row])
        chosen.append(best_row)
        acc = acc + lw_all[best_row]
        d_map = float(post.model.distance(
            np.array([float(pts[best_row] @ frame.normal) - frame.offset_m]))[0])
        out["suggestions"].append({"x_m": float(pts[best_row, 0]),
                                   "y_m": float(pts[best_row, 1]),
                                   "expected_gain": max(now - best_val, 0.0),
                                   "distance_m": d_map})
        now = best_val
    out["expected_interval_95_m"] = now


def suggest(post: JointPosterior, n: int, *, objective: str = "edge",
            region: Sequence[float] | None = None,
            plate_size_m: Sequence[float] | None = None) -> Suggestions:
    """N next positions ``{x_m, y_m, expected_gain, distance_m}`` and what the gain measures
    (see the module doc). ``region`` is ``(x_min, x_max, y_min, y_max)``; by default
    :func:`region_of`."""
    n, objective = check_request(n, objective)
    out: Suggestions = {"objective": objective, "suggestions": []}
    if n == 0:
        return out
    rng = np.random.default_rng(SEED)
    answers = [position_answer(post, i) for i in range(len(post.likes))]
    meas = _typical(post, answers)
    curves = _curves(post, meas)
    grid = post.distance_grid
    bounds = tuple(region) if region is not None else region_of(post, plate_size_m)
    parts = _particles(post, rng)
    frame = _Frame.of(post, bounds)
    aim = _Objective.of(objective, post, parts, frame, answers)
    pts = _candidates(post, parts, frame, bounds)
    if not pts.size:
        out["reason"] = "no point of the region lies on the plate under most likely edges"
        return out
    d_c = _signed(post, parts, pts[:, 0], pts[:, 1])
    # where a likely edge puts a candidate off the plate, the chain would stand on the clamp:
    # as at the clamped edge itself (L = 0)
    l_c = np.clip(post.model.distance(d_c), grid[0], grid[-1])  # (candidates, particles)
    truths = np.arange(min(TRUTHS, PARTICLES))
    draws = rng.integers(0, NOISE_DRAWS, truths.size)
    lw_all = _log_weights(curves, grid, l_c, truths, draws)
    _greedy(post, n, pts, lw_all, aim, frame, out)
    out["thickness_m"] = meas.thickness_m
    return out


def describe(objective: str) -> str:
    """What ``expected_gain`` measures, in words."""
    if objective == "edge":
        return ("expected reduction, in metres, of the 95 % interval of the located edge's "
                "position at its two ends in the plate's region, by measuring there (after the "
                "suggestions before it)")
    return ("expected reduction, in metres, of the positions' mean 95 % thickness interval, by "
            "measuring there (after the suggestions before it)")


__all__ = ["MAX_SUGGEST", "OBJECTIVES", "check_request", "describe", "region_of", "suggest"]
