"""A plate's scan inverted as one unknown: its clamped edges and every position's thickness.

A map inverts each position alone and then fits an edge to the positions' distance answers
(:mod:`.support`). Near a clamped edge, thickness and distance trade off in a single position's
TOF and ARR, so its thickness comes back loose or as a bound; yet the positions together locate
the edge, and once the edge is known each position's distance is known too. Here the scan is one
unknown:

* **The supports as the family declares them.** The paper's plate has two opposite clamped
  edges a plate length ``a`` apart (the table family's ``plate_size_m[0]``, the length along
  which ``distance_to_support`` runs); in the scan's own frame they are the lines
  ``x cos(theta) + y sin(theta) = offset`` and ``... = offset + a``, angle and offset unknown (a
  prior uniform in both). The reported edge is the one nearer the scan's centroid, so each pair
  of lines is counted once. A position at signed distance ``d`` from it stands ``min(d, a - d)``
  from the nearer support, and on the plate only for ``0 <= d <= a``. A family whose plate size
  is not recorded has one edge (``line``): ``d >= 0``, distance ``d``.
* **Each position's own likelihood.** Every position's per-size TOF/ARR summaries are inverted
  as :func:`~.inversion.invert` does and its likelihood over the fine (t, L) grid is kept
  (:func:`~.inversion.cell_likelihood`: the same terms, not a second likelihood). Positions the
  table's family does not explain (``inconsistent``, ``out_of_range``) are left out, named.
* **One posterior.** ``p(edge, t_1..t_n | data) ~ p(edge) prod_i L_i(t_i, L_i(edge)) p(t_i)``.
  With thickness free per position (the default; ``p(t_i)`` uniform in log t as in a single
  inversion) each position enters the edge's posterior through its marginal over t. With
  ``common`` the positions share a mean ``mu`` (uniform in log) around which each ``log t_i``
  scatters with a stated relative spread (``N(log mu, s^2)``); ``mu`` is integrated on a grid.
  The edge's posterior lives on cells in (angle, the centroid's distance from the edge), refined
  where it carries weight until it is smooth across each cell; each position's distance follows
  from its coordinates on every cell, and its thickness is the mixture over the cells of its
  own conditional posterior at that distance, summarised by the rules of a single inversion
  (status, intervals, one-sided bounds).
* **Do the positions agree with one straight edge?** ``fit = {chi2, dof, p_value}``: the misfit
  of every position at the joint best answer, against ``n_terms - p_D`` degrees of freedom (p_D
  the joint posterior's effective number of parameters: the posterior mean of the misfit over
  its value at the answer, which is the parameter count for a linear-Gaussian model; unlike a
  single inversion's (:mod:`.adequacy`) it leaves out the deviance's log-determinant, which
  varies across the posterior with the model's stated error and summed over a scan's positions
  took p_D to 18.5 for 10 positions of a 1.93 mm plate (12 parameters): five of the map study's
  30 right-family scans were flagged so, none now; docs/joint-map.md). A single
  position near a support fits any edge and leaves no degree of freedom; together they test the
  edge. Below ``p = 0.001`` the joint answers are marked ``inconsistent`` and the warning names
  the positions that disagree most.

* **One calibration, one plate (optional).** A scan's positions share one calibration, and the
  part of its TOF offset that does not transfer from the reference plates (the dissipation's
  delay, which depends on the plate's thickness) is, to first order, one error for the whole
  plate. Counted per position, as a single inversion must count it, it lets each position's TOF
  wander by its own ~12 us (TOF changes by 0.5-4 us per mm near a clamp, thick plates least:
  3-25 mm of distance each), so the positions seem to disagree about the edge's direction more
  than they can. ``posterior(..., shared_calibration=True)`` draws it once
  (:func:`calibration_nodes`): each position's deviance is quadratic in the offset's error
  (exactly), and the joint posterior is integrated over nodes of it (a hyper value, as the
  common mean is). It is not the default: in the map study it narrowed the edge and the
  near-edge thickness intervals but left the free thickness answers covering 0.90, because the
  simulated delay is not one number for a plate (next to the clamp it differs from far away by
  a few us); counted per position, the offset's 12 us also covers that. The ARR factor's
  uncertainty stays per position (the study's calibration states 0.4 %, a fifth of the table's
  own ARR error next to a clamp), and so does the plate material's spread (E +- 0.8 %: it does
  not change a near-edge position's thickness interval at two decimals, docs/joint-map.md).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.special import logsumexp
from scipy.stats import chi2 as chi2_dist

from solitonde.instrument.errors import InstrumentError
from solitonde.instrument.inference.calibration import Calibration
from solitonde.instrument.inference.inversion import (
    Estimate,
    FeatureSummary,
    InversionError,
    ParameterEstimate,
    cell_likelihood,
    invert,
    summarise_marginal,
)
from solitonde.instrument.tables.table import ModelTable, TableError

EDGE_MODELS = ("opposite_edges", "line")
THICKNESS_PRIORS = ("free", "common")
DEFAULT_SPREAD = 0.05
"""Relative spread of a position's thickness around the plate's common mean (1 sd in log t)."""
SPREAD_RANGE = (1e-3, 1.0)
ANGLE_STEP_DEG = 1.0
"""First cells of the edge's posterior: 1 degree by :data:`OFFSET_STEP_M`, refined where it
matters."""
OFFSET_STEP_M = 2e-3
SIGNIFICANT = 25.0
"""Cells whose log posterior lies within this of the best are refined (e^-25: nothing lost)."""
FLAT = 0.5
"""A cell whose four children differ by less than this (in log posterior) is fine enough."""
MIN_ANGLE_STEP_DEG = 0.02
MIN_OFFSET_STEP_M = 1e-4
MAX_ROUNDS = 12
LOG_FLOOR = -1e4
"""log of a likelihood that is zero (no reflection in the model where one was measured)."""
HYPER_STRIDE = 8
"""The common mean's grid: every 8th fine thickness (4 per table interval, 2.3 % apart on the
bundled tables' 16 thickness nodes). A spread well below that is under-resolved: the mean's
interval snaps to the grid's nodes (docs/joint-map.md)."""
P_INCONSISTENT = 1e-3
DISAGREE_CHI2 = 9.0
"""A position whose misfit at the joint answer exceeds its own best by this disagrees."""
WIDE_ANGLE_DEG = 20.0
PROFILE_SUPPORT = 1e-4
"""A position's thickness profile ranges over the distances whose joint posterior density is
at least this fraction of its peak."""
POSITION_SD_M = 1.0e-3
"""How well a position's distance from the edge follows from its recorded coordinates (1 sd):
the coordinates' own error (the chain's contact point against the mark, read off a rule), so a
joint edge is not sharper than the positions can place it. (It was first sized for a distance
axis 10 mm apart next to the clamp too; the axis is 2.5 mm apart there now, and the value was
kept: in the map study dropping it did not narrow the edge's angle, docs/joint-map.md.) Each
position's likelihood is averaged over it along L."""


class JointMapError(InstrumentError, ValueError):
    """Bad joint-map input; ``field`` names it."""


@dataclass
class ScanPosition:
    """One position of a scan: where, and its per-size summaries with what they need."""

    name: str | None
    x_m: float
    y_m: float
    inputs: list[FeatureSummary]
    calibration: Calibration | None = None
    material_spread: dict[str, float] | None = None


@dataclass(frozen=True)
class EdgeModel:
    """The clamped supports as the family declares them, in the scan's frame."""

    kind: str
    width_m: float | None = None
    """The separation of the two opposite edges (``opposite_edges``)."""
    table_max_m: float = math.inf

    @property
    def width(self) -> float:
        """The separation of the opposite edges, for an ``opposite_edges`` model (ValueError
        for another)."""
        if self.width_m is None:
            raise ValueError(f"a {self.kind} model has no width")
        return self.width_m

    def distance(self, d: np.ndarray) -> np.ndarray:
        """Distance to the nearer support of positions at signed distance ``d`` from the edge."""
        if self.kind == "opposite_edges":
            return np.minimum(d, self.width - d)
        return d

    def on_plate(self, d: np.ndarray) -> np.ndarray:
        if self.kind == "opposite_edges":
            return (d >= 0.0) & (d <= self.width_m)
        return d >= 0.0

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "width_m": self.width_m}


def edge_model(table: ModelTable) -> EdgeModel:
    """The supports of the table's family (two opposite edges a plate length apart, or one
    line where the plate's size is not recorded).

    Raises JointMapError (``joint``) for a family without a clamped support or with all four
    edges clamped (not a line's angle and offset)."""
    family = table.family or {}
    supports = family.get("supports")
    size = family.get("plate_size_m")
    l_max = float(table.axes["distance_m"][-1])
    if supports in (None, "opposite_edges") and size:
        return EdgeModel("opposite_edges", float(size[0]), l_max)
    if supports == "none":
        raise JointMapError("joint", "the table's family has no clamped support: there is no "
                            "edge to locate (allowed: a family with opposite clamped edges)")
    if supports == "all_edges":
        raise JointMapError("joint", "the table's family clamps all four edges; a joint map "
                            "locates two opposite edges or one line (allowed: opposite_edges)")
    return EdgeModel("line", None, l_max)


# --- each position's own likelihood -----------------------------------------------------------


@dataclass
class PositionLikelihood:
    """One position's likelihood over the fine (t, L) grid at each node of the scan's shared
    calibration error (one node when there is none), with its own answer."""

    position: ScanPosition
    estimate: Estimate
    log_t: np.ndarray
    distance_m: np.ndarray
    weight_t: np.ndarray
    like: np.ndarray
    """(node, t, L): exp(-(deviance - its minimum) / 2), 1 at the position's best cell and
    node, 0 where impossible."""
    deviance: np.ndarray
    """(node, t, L)."""
    rest: np.ndarray
    """(t, L): the deviance's terms beside the misfit (log det of the covariance, penalties)."""
    n_terms: int

    def misfit(self, node: int | None = None) -> np.ndarray:
        """The chi^2 part of the deviance at a node of the shared calibration error (at every
        node, ``(node, t, L)``, when ``node`` is None); inf where the model is impossible."""
        deviance = self.deviance if node is None else self.deviance[node]
        with np.errstate(invalid="ignore"):
            return np.where(np.isfinite(deviance), np.maximum(deviance - self.rest, 0.0), np.inf)


@dataclass
class _RawLikelihood:
    """A position's deviance at the calibration's stated values, and how it moves with the
    calibration's errors (:func:`~.inversion.cell_likelihood` with ``shared_calibration``)."""

    position: ScanPosition
    estimate: Estimate
    keep: dict[str, Any]
    keys: list[tuple[Any, ...]]
    """One key per shared error: (diameter, quantity, stated value, sd)."""


def _raw_likelihood(table: ModelTable, position: ScanPosition, shared: bool
                    ) -> tuple[_RawLikelihood | None, str | None]:
    """The position's raw likelihood, or None and why it is left out of the joint posterior."""
    inputs = list(position.inputs)
    if not inputs:
        return None, "no sphere size with an inversion input"
    try:
        est = invert(table, inputs, position.calibration,
                     material_spread=position.material_spread)
    except (InversionError, TableError) as exc:  # e.g. a sphere size the table lacks
        return None, f"not inverted: {exc}"
    if est.inconsistent:
        return None, ("its own answer is " + est.thickness_m.status + " (the table's family "
                      "does not explain it): " + (est.warnings[0] if est.warnings else
                                                   str(est.reason)))
    excluded = set(est.extra.get("excluded_diameters_m", []))
    used = [i for i in inputs if i.diameter_m not in excluded]
    keep = cell_likelihood(table, used, position.calibration,
                           material_spread=est.material_spread, shared_calibration=shared)
    if not np.isfinite(keep["deviance"]).any():
        return None, "the model detects no reflection anywhere for its sphere sizes"
    cal = position.calibration
    keys = []
    for d, kind, sd in keep["shared"]:
        # the key names the calibration entry (the size's values over all its references); a
        # distance-dependent offset shares one error, scaled to its sd at each distance
        factor, offset = (1.0, 0.0) if cal is None else cal.for_diameter(d)
        keys.append((round(d * 1e6), kind, factor if kind == "arr_factor" else offset, sd))
    return _RawLikelihood(position, est, keep, keys), None


def _at_nodes(raw: _RawLikelihood, keys: Sequence[tuple[Any, ...]], eta: np.ndarray
              ) -> PositionLikelihood:
    """The position's likelihood at every node ``eta`` (node, shared error) of the scan's
    shared calibration errors ``keys``, averaged along L over its coordinates' error."""
    keep = raw.keep
    dev0 = keep["deviance"]
    finite = np.isfinite(dev0)
    cols = [keys.index(k) for k in raw.keys]
    b, q = keep["shared_b"], keep["shared_q"]
    n_nodes = eta.shape[0]
    dev = np.empty((n_nodes, *dev0.shape))
    for k in range(n_nodes):
        e = eta[k, cols] if cols else np.zeros(0)
        dk = dev0.copy()
        for a, ea in enumerate(e):
            dk -= 2.0 * ea * b[a]
            for c, ec in enumerate(e):
                dk += ea * ec * q[a, c]
        dev[k] = np.where(finite, dk, np.inf)
    g = keep["grid"]
    rest = np.where(finite, dev0 - keep["misfit"], np.nan)
    best = float(dev[np.isfinite(dev)].min())
    like = np.where(np.isfinite(dev), np.exp(-0.5 * (np.where(np.isfinite(dev), dev, best)
                                                     - best)), 0.0)
    if POSITION_SD_M > 0:  # where the chain stood is known to its recorded coordinates' error
        blur = _blur(g.distance_m, POSITION_SD_M)
        blurred = like @ blur.T
        with np.errstate(divide="ignore"):
            dev = np.where(blurred > 0, best - 2.0 * np.log(blurred), np.inf)
        # the terms beside the misfit (log det of the covariance) vary slowly: kept per row
        row_mean = np.nanmean(np.where(finite.any(axis=1, keepdims=True), rest, 0.0), axis=1)
        rest = np.where(finite, rest, row_mean[:, None])
        best = float(dev[np.isfinite(dev)].min())
        like = np.where(np.isfinite(dev), np.exp(-0.5 * (np.where(np.isfinite(dev), dev, best)
                                                         - best)), 0.0)
    return PositionLikelihood(raw.position, raw.estimate, np.log(g.thickness_m), g.distance_m,
                              g.weight_t, like, dev, rest, int(keep["n_terms"]))


def position_likelihood(table: ModelTable, position: ScanPosition
                        ) -> tuple[PositionLikelihood | None, str | None]:
    """The position's likelihood alone (its calibration's uncertainty marginalised for it
    alone, as a single inversion does), or None and why it is left out."""
    raw, why = _raw_likelihood(table, position, False)
    if raw is None:
        return None, why
    return _at_nodes(raw, [], np.zeros((1, 0))), None


# --- the calibration's errors, one draw for the scan --------------------------------------

NODES_PER_ERROR = {1: 9, 2: 5}
"""Nodes per shared calibration error, by how many there are (3 each beyond two)."""
NODE_SPAN_SD = 4.0
"""The nodes span this many sds either side of the error's posterior mean."""


def _proxy(raws: Sequence[_RawLikelihood], key: tuple[Any, ...], x: np.ndarray) -> np.ndarray:
    """log p(data | error = x) of the positions that carry this error, each position's (t, L)
    marginalised over a single inversion's prior (the edge ignored), the other errors at 0."""
    total = np.zeros(x.size)
    for raw in raws:
        if key not in raw.keys:
            continue
        a = raw.keys.index(key)
        keep = raw.keep
        g = keep["grid"]
        dev0 = keep["deviance"]
        ok = np.isfinite(dev0)
        logw = np.log(g.weight_t)[:, None] + np.log(g.weight_l)[None, :]
        d = (dev0[ok][None, :] - 2.0 * x[:, None] * keep["shared_b"][a][ok][None, :]
             + x[:, None] ** 2 * keep["shared_q"][a, a][ok][None, :])
        total += logsumexp(logw[ok][None, :] - 0.5 * (d - d.min()), axis=1) - 0.5 * d.min()
    return total


def calibration_nodes(raws: Sequence[_RawLikelihood]
                      ) -> tuple[list[tuple[Any, ...]], np.ndarray, np.ndarray]:
    """The scan's shared calibration errors and the nodes over which they are integrated:
    ``(keys, eta (node, error), z2 (node,))`` with ``z2`` each node's ``sum (eta / sd)^2``.

    One error per calibration entry with a stated sd (a sphere size's TOF offset or ARR
    factor), shared by every position measured with it: one calibration, one plate. Each
    error's nodes are equally spaced (the trapezoid rule, which integrates a smooth peak to
    within e^-2pi^2 when the spacing is its sd) across +-:data:`NODE_SPAN_SD` sds of where the
    positions together put it, found by zooming in from the prior's +-6 sd; several errors get
    the product of their nodes."""
    keys = sorted({k for raw in raws for k in raw.keys})
    if not keys:
        return [], np.zeros((1, 0)), np.zeros(1)
    n = NODES_PER_ERROR.get(len(keys), 3)
    axes = []
    for key in keys:
        sd = float(key[3])
        lo, hi = -6.0 * sd, 6.0 * sd
        mean, s = 0.0, sd
        for _ in range(10):
            x = np.linspace(lo, hi, 25)
            lp = -0.5 * (x / sd) ** 2 + _proxy(raws, key, x)
            w = np.exp(lp - lp.max())
            w /= w.sum()
            mean = float(w @ x)
            s = float(np.sqrt(w @ (x - mean) ** 2))
            h = x[1] - x[0]
            if s >= 1.5 * h:
                break
            half = max(6.0 * s, 2.0 * h)
            lo, hi = mean - half, mean + half
        axes.append(mean + s * np.linspace(-NODE_SPAN_SD, NODE_SPAN_SD, n))
    mesh = np.meshgrid(*axes, indexing="ij")
    eta = np.stack([m.ravel() for m in mesh], axis=1)
    sds = np.array([float(k[3]) for k in keys])
    return keys, eta, ((eta / sds[None, :]) ** 2).sum(axis=1)


@functools.lru_cache(maxsize=8)
def _blur_cached(grid: tuple[float, ...], sd: float) -> np.ndarray:
    x = np.asarray(grid)
    step = sd / 8.0
    fine = np.arange(x[0], x[-1] + 0.5 * step, step)
    interp = _Interp.on(x, fine)  # linear interpolation of the grid onto the fine points
    to_fine = np.zeros((fine.size, x.size))
    rows = np.arange(fine.size)
    to_fine[rows, interp.idx] += 1.0 - interp.frac
    to_fine[rows, interp.idx + 1] += interp.frac
    kernel = np.exp(-0.5 * ((x[:, None] - fine[None, :]) / sd) ** 2)
    kernel /= kernel.sum(axis=1, keepdims=True)  # truncated at the grid's ends (L >= 0)
    return kernel @ to_fine


def _blur(grid: np.ndarray, sd: float) -> np.ndarray:
    """The matrix that averages a function given by its values on ``grid`` (linear between
    them) over a Gaussian of ``sd`` around each grid point."""
    return _blur_cached(tuple(float(v) for v in grid), float(sd))


# --- the thickness prior -------------------------------------------------------------------


@dataclass(frozen=True)
class ThicknessPrior:
    """Free per position (uniform in log t, as a single inversion), or tied to a common mean
    ``mu`` with a relative spread (``log t_i ~ N(log mu, spread^2)``, mu uniform in log)."""

    kind: str = "free"
    spread_rel: float = DEFAULT_SPREAD

    def __post_init__(self) -> None:
        if self.kind not in THICKNESS_PRIORS:
            raise JointMapError("thickness_prior", f"{self.kind!r} (allowed: "
                                f"{', '.join(THICKNESS_PRIORS)})")
        s = self.spread_rel
        if (isinstance(s, bool) or not isinstance(s, int | float) or not math.isfinite(s)
                or not SPREAD_RANGE[0] <= s <= SPREAD_RANGE[1]):
            raise JointMapError("thickness_spread", f"{s!r} (allowed: {SPREAD_RANGE[0]:g} to "
                                f"{SPREAD_RANGE[1]:g}, a relative standard deviation)")

    def matrix(self, log_t: np.ndarray, weight_t: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(P, log_mu, prior_mu)``: ``P[h, k]`` the prior mass of thickness cell k given the
        hyper value h (each row sums to 1); one row for ``free``."""
        if self.kind == "free":
            p = weight_t / weight_t.sum()
            return p[None, :], np.array([np.nan]), np.ones(1)
        log_mu = log_t[::HYPER_STRIDE]
        if log_mu[-1] != log_t[-1]:
            log_mu = np.append(log_mu, log_t[-1])
        dens = np.exp(-0.5 * ((log_t[None, :] - log_mu[:, None]) / self.spread_rel) ** 2)
        p = dens * weight_t[None, :]
        p /= p.sum(axis=1, keepdims=True)
        widths = np.diff(np.concatenate([log_mu[:1], 0.5 * (log_mu[1:] + log_mu[:-1]),
                                         log_mu[-1:]]))
        return p, log_mu, widths / widths.sum()

    def to_dict(self) -> dict[str, Any]:
        if self.kind == "free":
            return {"kind": "free", "description": "each position's thickness free (uniform in "
                    "log t), as in a single inversion"}
        return {"kind": "common", "spread_rel": self.spread_rel,
                "description": f"each position's thickness scatters around the plate's common "
                f"mean (uniform in log) with a relative spread of {100 * self.spread_rel:.3g} % "
                "(1 sd, log-normal)"}


# --- the edge's posterior on refined cells --------------------------------------------------


@dataclass
class EdgeCells:
    """Cells of the edge's posterior: angle theta (rad) of the normal, and c, the scan
    centroid's distance from the edge; each with its size and log posterior (per hyper value
    and summed)."""

    theta: np.ndarray
    c: np.ndarray
    h_theta: np.ndarray
    h_c: np.ndarray
    lp_hyper: np.ndarray
    lp: np.ndarray

    def take(self, keep: np.ndarray) -> EdgeCells:
        return EdgeCells(self.theta[keep], self.c[keep], self.h_theta[keep], self.h_c[keep],
                         self.lp_hyper[:, keep], self.lp[keep])


@dataclass
class _Interp:
    """Linear interpolation weights of values on the fine distance grid."""

    idx: np.ndarray
    frac: np.ndarray

    @classmethod
    def on(cls, grid: np.ndarray, x: np.ndarray) -> _Interp:
        j = np.clip(np.searchsorted(grid, x, side="right") - 1, 0, grid.size - 2)
        frac = np.clip((x - grid[j]) / (grid[j + 1] - grid[j]), 0.0, 1.0)
        return cls(j, frac)

    def __call__(self, values: np.ndarray) -> np.ndarray:
        """``values[..., L]`` at the points (last axis interpolated)."""
        return values[..., self.idx] * (1.0 - self.frac) + values[..., self.idx + 1] * self.frac


@dataclass
class JointPosterior:
    """Everything the joint answer and the next position's choice read."""

    table: ModelTable
    model: EdgeModel
    prior: ThicknessPrior
    likes: list[PositionLikelihood]
    anchor: np.ndarray
    cells: EdgeCells
    mass: np.ndarray
    """Each cell's posterior probability (sums to 1)."""
    mass_hyper: np.ndarray
    """(hyper value, cell) probabilities."""
    p_matrix: np.ndarray
    log_mu: np.ndarray
    log_marginal: list[np.ndarray]
    """Per position, log of its likelihood marginalised over t given (hyper value, L)."""
    distance_grid: np.ndarray
    excluded: list[tuple[ScanPosition, str]] = field(default_factory=list)
    keys: list[tuple[Any, ...]] = field(default_factory=list)
    """The scan's shared calibration errors (:func:`calibration_nodes`)."""
    eta: np.ndarray = field(default_factory=lambda: np.zeros((1, 0)))
    """(node, error): the nodes the shared errors are integrated over."""
    node_z2: np.ndarray = field(default_factory=lambda: np.zeros(1))
    """Each node's ``sum (eta / sd)^2`` (its prior is ``exp(-z2 / 2)``)."""

    @property
    def n_nodes(self) -> int:
        return int(self.eta.shape[0])

    def hyper_weights(self) -> tuple[np.ndarray, np.ndarray]:
        """Posterior probability of each calibration node and of each common-mean value."""
        w = self.mass_hyper.sum(axis=1).reshape(self.n_nodes, -1)
        return w.sum(axis=1), w.sum(axis=0)

    def hyper_like(self, lk: PositionLikelihood, values: np.ndarray | None = None
                   ) -> np.ndarray:
        """``sum_t P[h, t] values[k, t, L]`` (default: the position's likelihood) per hyper
        value (node k, mean h), flattened as :attr:`mass_hyper`'s rows: (hyper, L)."""
        v = lk.like if values is None else values
        return np.einsum("ht,ktl->khl", self.p_matrix, v).reshape(-1, v.shape[-1])

    def signed_distances(self, x: np.ndarray, y: np.ndarray,
                         cells: EdgeCells | None = None) -> np.ndarray:
        """Signed distance from the edge of points (x, y) on every cell: (points, cells)."""
        cells = self.cells if cells is None else cells
        dx = np.atleast_1d(x) - self.anchor[0]
        dy = np.atleast_1d(y) - self.anchor[1]
        return (np.outer(dx, np.cos(cells.theta)) + np.outer(dy, np.sin(cells.theta))
                + cells.c[None, :])

    def offsets(self, cells: EdgeCells | None = None) -> np.ndarray:
        """Each cell's line offset ``x cos(theta) + y sin(theta) = offset`` in the scan's
        frame."""
        cells = self.cells if cells is None else cells
        return (self.anchor[0] * np.cos(cells.theta) + self.anchor[1] * np.sin(cells.theta)
                - cells.c)

    @property
    def best(self) -> int:
        return int(np.argmax(self.cells.lp))


def _log_marginals(likes: Sequence[PositionLikelihood], p: np.ndarray) -> list[np.ndarray]:
    out = []
    for lk in likes:
        # (node x hyper, L): the likelihood marginalised over t
        m = np.einsum("ht,ktl->khl", p, lk.like).reshape(-1, lk.like.shape[-1])
        out.append(np.log(m, out=np.full_like(m, LOG_FLOOR), where=m > 0).clip(min=LOG_FLOOR))
    return out


def _evaluate(theta: np.ndarray, c: np.ndarray, xy: np.ndarray, anchor: np.ndarray,
              model: EdgeModel, grid: np.ndarray, log_m: Sequence[np.ndarray],
              log_prior_hyper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Log posterior (per hyper value, and summed over them) of edge cells."""
    cos, sin = np.cos(theta), np.sin(theta)
    total = np.tile(log_prior_hyper[:, None], (1, theta.size))
    feasible = np.ones(theta.size, dtype=bool)
    for (x, y), lm in zip(xy, log_m, strict=True):
        d = (x - anchor[0]) * cos + (y - anchor[1]) * sin + c
        feasible &= model.on_plate(d)
        dist = np.clip(model.distance(d), grid[0], grid[-1])
        total += _Interp.on(grid, dist)(lm)
    total[:, ~feasible] = -np.inf
    return total, logsumexp(total, axis=0) if total.shape[0] > 1 else total[0]


def _c_range(model: EdgeModel, xy: np.ndarray, anchor: np.ndarray) -> tuple[float, float]:
    if model.kind == "opposite_edges":
        return 0.0, 0.5 * model.width
    spread = float(np.max(np.hypot(*(xy - anchor).T))) if len(xy) else 0.0
    return 0.0, float(min(model.table_max_m, 10.0)) + spread


def edge_posterior(likes: Sequence[PositionLikelihood], model: EdgeModel,
                   prior: ThicknessPrior, node_z2: np.ndarray | None = None
                   ) -> tuple[EdgeCells, np.ndarray, np.ndarray, np.ndarray, list[np.ndarray],
                              np.ndarray]:
    """The edge's posterior on cells refined where it carries weight: ``(cells, anchor,
    P, log_mu, log_marginals, hyper prior)``; the hyper values are the shared calibration's
    nodes (prior ``exp(-z2 / 2)`` each, ``node_z2``) times the common mean's values."""
    lk0 = likes[0]
    grid = lk0.distance_m
    p, log_mu, prior_mu = prior.matrix(lk0.log_t, lk0.weight_t)
    log_m = _log_marginals(likes, p)
    z2 = np.zeros(1) if node_z2 is None else node_z2
    log_prior_hyper = (-0.5 * z2[:, None] + np.log(prior_mu)[None, :]).ravel()
    xy = np.array([[lk.position.x_m, lk.position.y_m] for lk in likes], dtype=float)
    anchor = xy.mean(axis=0)
    lo, hi = _c_range(model, xy, anchor)
    n_t = round(360.0 / ANGLE_STEP_DEG)
    n_c = max(1, math.ceil((hi - lo) / OFFSET_STEP_M))
    h_t, h_c = 2 * math.pi / n_t, (hi - lo) / n_c
    tt, cc = np.meshgrid((np.arange(n_t) + 0.5) * h_t, lo + (np.arange(n_c) + 0.5) * h_c,
                         indexing="ij")
    theta, c = tt.ravel(), cc.ravel()

    def evaluate(th: np.ndarray, cv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return _evaluate(th, cv, xy, anchor, model, grid, log_m, log_prior_hyper)

    lph, lp = evaluate(theta, c)
    # a first cell is fine enough where it differs little from its neighbours (angle wraps)
    grid_lp = lp.reshape(n_t, n_c)
    diff = np.zeros_like(grid_lp)
    for shifted in (np.roll(grid_lp, 1, 0), np.roll(grid_lp, -1, 0)):
        diff = np.maximum(diff, _absdiff(grid_lp, shifted))
    if n_c > 1:
        diff[:, 1:] = np.maximum(diff[:, 1:], _absdiff(grid_lp[:, 1:], grid_lp[:, :-1]))
        diff[:, :-1] = np.maximum(diff[:, :-1], _absdiff(grid_lp[:, :-1], grid_lp[:, 1:]))
    cells = EdgeCells(theta, c, np.full(theta.size, h_t), np.full(theta.size, h_c), lph, lp)
    final = (diff < FLAT).ravel()
    min_t, min_c = math.radians(MIN_ANGLE_STEP_DEG), MIN_OFFSET_STEP_M
    for _ in range(MAX_ROUNDS):
        top = cells.lp.max()
        if not np.isfinite(top):
            raise JointMapError("positions", "no edge of the family's plate puts every position "
                                "on the plate where its measurement can be explained")
        split = ((cells.lp > top - SIGNIFICANT) & ~final
                 & ((cells.h_theta > min_t) | (cells.h_c > min_c)))
        # cells far below the best carry nothing: drop them
        keep = cells.lp > top - 2.0 * SIGNIFICANT
        if not split.any():
            cells, final = cells.take(keep), final[keep]
            break
        parent = cells.take(split)
        qt = np.array([-0.25, -0.25, 0.25, 0.25])
        qc = np.array([-0.25, 0.25, -0.25, 0.25])
        th = (parent.theta[:, None] + qt[None, :] * parent.h_theta[:, None]).ravel()
        cv = (parent.c[:, None] + qc[None, :] * parent.h_c[:, None]).ravel()
        child_lph, child_lp = evaluate(th, cv)
        span = child_lp.reshape(-1, 4)
        with np.errstate(invalid="ignore"):
            rng = np.where(np.isfinite(span).all(axis=1), span.max(axis=1) - span.min(axis=1),
                           np.where(np.isfinite(span).any(axis=1), np.inf, 0.0))
        child_final = np.repeat(rng < FLAT, 4)
        children = EdgeCells(th, cv, np.repeat(parent.h_theta / 2, 4),
                             np.repeat(parent.h_c / 2, 4), child_lph, child_lp)
        rest = keep & ~split
        cells = EdgeCells(*(np.concatenate([getattr(cells.take(rest), k), getattr(children, k)],
                                           axis=-1)
                            for k in ("theta", "c", "h_theta", "h_c", "lp_hyper", "lp")))
        final = np.concatenate([final[rest], child_final])
    return cells, anchor, p, log_mu, log_m, log_prior_hyper


def _absdiff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        d = np.abs(a - b)
    both_inf = ~np.isfinite(a) & ~np.isfinite(b)
    return np.where(both_inf, 0.0, np.where(np.isfinite(d), d, np.inf))


def posterior(table: ModelTable, positions: Sequence[ScanPosition],
              prior: ThicknessPrior | None = None, *,
              shared_calibration: bool = False) -> JointPosterior:
    """The joint posterior of a scan (see the module doc).

    ``shared_calibration``: the calibration's TOF offset error is drawn once for the scan and
    integrated over once (one calibration, one plate); by default it is taken per position, as
    each position's own inversion takes it, which the map study found keeps the thickness
    answers' coverage (sharing it narrows them too far: the offset's error is not one number
    for a plate, docs/joint-map.md).

    Raises JointMapError (``positions``) when no position can enter it, or (``joint``) for a
    family whose supports are not a line's angle and offset."""
    prior = prior or ThicknessPrior()
    model = edge_model(table)
    raws, excluded = [], []
    for pos in positions:
        for name, v in (("x_m", pos.x_m), ("y_m", pos.y_m)):
            if v is None or not math.isfinite(float(v)):
                raise JointMapError(name, f"position {pos.name!r}: {v!r} (allowed: a finite "
                                    "coordinate in metres)")
        raw, why = _raw_likelihood(table, pos, shared_calibration)
        if raw is None:
            excluded.append((pos, why or "left out"))
        else:
            raws.append(raw)
    keys, eta, node_z2 = calibration_nodes(raws)
    likes = [_at_nodes(raw, keys, eta) for raw in raws]
    if not likes:
        raise JointMapError("positions", "no position with coordinates whose measurement the "
                            "table's family explains: " + "; ".join(
                                f"{p.name}: {w}" for p, w in excluded) if excluded
                            else "no position with coordinates")
    cells, anchor, p, log_mu, log_m, _ = edge_posterior(likes, model, prior, node_z2)
    top = cells.lp.max()
    area = cells.h_theta * cells.h_c
    mass = np.exp(cells.lp - top) * area
    total = mass.sum()
    mass_hyper = np.exp(cells.lp_hyper - top) * area[None, :] / total
    return JointPosterior(table, model, prior, likes, anchor, cells, mass / total, mass_hyper, p,
                          log_mu, log_m, likes[0].distance_m, excluded, keys, eta, node_z2)


# --- what the posterior says ------------------------------------------------------------------


def weighted_quantiles(x: np.ndarray, w: np.ndarray, qs: Sequence[float]) -> list[float]:
    """Quantiles of points ``x`` with weights ``w`` (linear between the points' mid-masses)."""
    order = np.argsort(x)
    xs, ws = x[order], w[order]
    cdf = np.cumsum(ws) - 0.5 * ws
    cdf /= ws.sum()
    return [float(np.interp(q, cdf, xs)) for q in qs]


def _bins(grid: np.ndarray, dist: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weights (hyper, cells) of points at ``dist`` spread linearly onto the grid:
    (hyper, L)."""
    from scipy.sparse import csr_matrix

    it = _Interp.on(grid, np.clip(dist, grid[0], grid[-1]))
    n = it.idx.size
    spread = csr_matrix((np.concatenate([1.0 - it.frac, it.frac]),
                         (np.concatenate([np.arange(n), np.arange(n)]),
                          np.concatenate([it.idx, it.idx + 1]))), shape=(n, grid.size))
    return np.asarray((spread.T @ weights.T).T)


@dataclass
class PositionAnswer:
    thickness: ParameterEstimate
    distance: ParameterEstimate
    distance_map_m: float
    conditional: tuple[np.ndarray, np.ndarray]
    """E[log t | L] and Var[log t | L] on the distance grid (hyper values mixed by the
    posterior): what the next position's choice reads for the thickness map."""
    expected_misfit: float
    """The posterior mean of the position's misfit (the chi^2 part of its deviance; with the
    tie's term for ``common``)."""


def position_answer(post: JointPosterior, i: int) -> PositionAnswer:
    """Position i's thickness and distance from the joint posterior."""
    lk = post.likes[i]
    d = post.signed_distances(np.array([lk.position.x_m]), np.array([lk.position.y_m]))[0]
    dist = post.model.distance(d)
    w_bins = _bins(post.distance_grid, dist, post.mass_hyper)  # (hyper, L)
    m = post.hyper_like(lk)  # (hyper, L)
    n_mu = post.p_matrix.shape[0]
    q = np.divide(w_bins, m, out=np.zeros_like(w_bins), where=m > 0)
    r = np.einsum("ktl,khl->th", lk.like, q.reshape(post.n_nodes, n_mu, -1))  # (t, mean)
    mass_t = (post.p_matrix.T * r).sum(axis=1)
    # as in a single inversion, a side is open where the profile likelihood (the best over
    # distance) is within the 95 % level of the best; the distances are those the joint
    # posterior leaves possible (density at least 1e-4 of its peak), not any; the shared
    # calibration's nodes are mixed by their posterior weight
    possible = w_bins.sum(axis=0) > PROFILE_SUPPORT * w_bins.sum(axis=0).max()
    node_w, _ = post.hyper_weights()
    like_post = np.einsum("k,ktl->tl", node_w / node_w.sum(), lk.like)
    profile = like_post[:, possible].max(axis=1)
    profile = profile / profile.max() if profile.max() > 0 else profile
    thickness = summarise_marginal(lk.log_t, mass_t / mass_t.sum(), lk.weight_t,
                                   lower_physical=False, transform=np.exp, profile=profile)
    q2, q16, q50, q84, q98 = weighted_quantiles(dist, post.mass, (0.025, 0.16, 0.5, 0.84, 0.975))
    d_map = float(dist[post.best])
    distance = ParameterEstimate(d_map, q50, (q16, q84), (q2, q98), "constrained")
    # conditional moments of log t given L (hyper values mixed by their weight at each L)
    w_sum = w_bins.sum(axis=0, keepdims=True)
    mix = np.where(w_sum > 0, w_bins / np.maximum(w_sum, 1e-300), 1.0 / w_bins.shape[0])
    ratio = mix / np.maximum(m, 1e-300)
    cond = np.einsum("ktl,ht,khl->tl", lk.like, post.p_matrix,
                     ratio.reshape(post.n_nodes, n_mu, -1))  # p(t | L), hyper values mixed
    cond /= np.maximum(cond.sum(axis=0, keepdims=True), 1e-300)
    mean = (lk.log_t[:, None] * cond).sum(axis=0)
    var = ((lk.log_t[:, None] - mean[None, :]) ** 2 * cond).sum(axis=0)
    s = post.hyper_like(lk, lk.like * np.where(lk.like > 0, lk.misfit(), 0.0))
    if post.prior.kind == "common":  # the tie's own term, (log t - log mu)^2 / s^2
        s = s + np.einsum("ht,ktl->khl", post.p_matrix * _tie_z2(post, lk.log_t),
                          lk.like).reshape(s.shape)
    expected = float(np.sum(np.divide(w_bins * s, m, out=np.zeros_like(s), where=m > 0)))
    return PositionAnswer(thickness, distance, d_map, (mean, var), expected)


def _tie_z2(post: JointPosterior, log_t: np.ndarray) -> np.ndarray:
    """``((log t - log mu_h) / spread)^2`` per (hyper value, thickness cell)."""
    return ((log_t[None, :] - post.log_mu[:, None]) / post.prior.spread_rel) ** 2


def _best_fit(post: JointPosterior) -> tuple[list[float], int, float]:
    """At the joint best fit (the edge's cell, the shared calibration's node, and there each
    position's thickness, with the common mean's best value for ``common``, that together have
    the least deviance): each position's misfit (with the tie's term for ``common``), the number
    of terms (the tie's and the shared calibration's included) and the shared calibration's own
    term (``sum (eta / sd)^2`` at the best node)."""
    common = post.prior.kind == "common"
    z2 = _tie_z2(post, post.likes[0].log_t) if common else np.zeros((1, post.likes[0].log_t.size))
    support = np.flatnonzero(post.mass > 1e-9 * post.mass.max())
    cand = post.cells.take(support)
    total = np.zeros((post.n_nodes, z2.shape[0], support.size))
    for lk in post.likes:
        d = post.signed_distances(np.array([lk.position.x_m]), np.array([lk.position.y_m]),
                                  cand)[0]
        it = _Interp.on(lk.distance_m, np.clip(post.model.distance(d), lk.distance_m[0],
                                               lk.distance_m[-1]))
        dev = np.where(np.isfinite(lk.deviance), lk.deviance, 1e300)
        for node in range(post.n_nodes):
            best_l = (dev[node][None, :, :] + z2[:, :, None]).min(axis=1)  # (hyper, L)
            total[node] += it(best_l)
    total += post.node_z2[:, None, None]
    at = np.unravel_index(int(np.argmin(total)), total.shape)
    best_node, k = int(at[0]), int(at[2])
    z_node = float(post.node_z2[best_node])
    cells = cand.take(np.array([k]))
    columns = []
    for lk in post.likes:
        d = post.signed_distances(np.array([lk.position.x_m]), np.array([lk.position.y_m]),
                                  cells)
        dist = float(np.clip(post.model.distance(d)[0, 0], lk.distance_m[0], lk.distance_m[-1]))
        it = _Interp.on(lk.distance_m, np.array([dist]))
        j, f = int(it.idx[0]), float(it.frac[0])
        mis_all = lk.misfit(best_node)
        with np.errstate(invalid="ignore"):
            dev = ((1 - f) * lk.deviance[best_node][:, j]
                   + f * lk.deviance[best_node][:, j + 1])
            mis = (1 - f) * mis_all[:, j] + f * mis_all[:, j + 1]
        columns.append((np.where(np.isfinite(dev), dev, np.inf), mis))
    n_terms = sum(lk.n_terms for lk in post.likes) + len(post.keys)
    if post.prior.kind == "free":
        picks = [int(np.argmin(dev)) for dev, _ in columns]
        return ([float(mis[k]) for (_, mis), k in zip(columns, picks, strict=True)], n_terms,
                z_node)
    best: tuple[float, list[int], int] | None = None
    for h in range(z2.shape[0]):
        picks = [int(np.argmin(dev + z2[h])) for dev, _ in columns]
        total_h = float(sum(dev[k] + z2[h, k] for (dev, _), k in zip(columns, picks,
                                                                      strict=True)))
        if best is None or total_h < best[0]:
            best = (total_h, picks, h)
    assert best is not None
    _, picks, h = best
    # the common mean is continuous: a few rounds of (mean of the picks, picks given the mean)
    log_t, spread = post.likes[0].log_t, post.prior.spread_rel
    log_mu = float(post.log_mu[h])
    for _ in range(5):
        log_mu = float(np.mean(log_t[picks]))
        z = ((log_t - log_mu) / spread) ** 2
        picks = [int(np.argmin(dev + z)) for dev, _ in columns]
    z = ((log_t - log_mu) / spread) ** 2
    misfits = [float(mis[k] + z[k]) for (_, mis), k in zip(columns, picks, strict=True)]
    return misfits, n_terms + len(post.likes), z_node


def median_edge(post: JointPosterior) -> tuple[float, float]:
    """The posterior median edge: the line through the median positions of the edge at the two
    ends of the scan's extent along it (at least 0.2 m either side of its centre), as ``(theta,
    offset)``. The best cell of (angle, offset) is a density's mode that depends on how the edge
    is parametrised, and a mean is pulled by a second mode (the edge's mirror image, an edge
    labelled from the opposite side); the median of where the edge lies is neither."""
    b = post.best
    theta_b = float(post.cells.theta[b])
    n = np.array([math.cos(theta_b), math.sin(theta_b)])
    along = np.array([-n[1], n[0]])
    offset_b = float(post.offsets()[b])
    xy = np.array([[lk.position.x_m, lk.position.y_m] for lk in post.likes])
    s = xy @ along
    centre = 0.5 * (s.min() + s.max())
    half = max(0.5 * (s.max() - s.min()), 0.2)
    q = np.array([offset_b * n + (centre + k * half) * along for k in (-1.0, 1.0)])
    # the signed distance of q from each cell's edge (q lies on the best edge: its mean is
    # where the edge lies on average, along the best normal)
    z = (q[:, :1] * np.cos(post.cells.theta)[None, :]
         + q[:, 1:] * np.sin(post.cells.theta)[None, :] - post.offsets()[None, :])
    middle = np.array([weighted_quantiles(zz, post.mass, (0.5,))[0] for zz in z])
    p = q - middle[:, None] * n[None, :]
    d = p[1] - p[0]
    normal = np.array([d[1], -d[0]]) / float(np.hypot(*d))
    if normal @ n < 0:
        normal = -normal
    theta = math.atan2(normal[1], normal[0]) % (2 * math.pi)
    return theta, float(p[0] @ normal)


def shared_calibration(post: JointPosterior) -> list[dict[str, Any]]:
    """The calibration errors the scan shares (one draw for every position measured with the
    calibration): per error its sphere size, quantity, stated value and sd, and where the
    positions together put it (posterior mean and sd of the error)."""
    node_w, _ = post.hyper_weights()
    node_w = node_w / node_w.sum()
    out = []
    for a, (d_um, kind, value, sd) in enumerate(post.keys):
        e = post.eta[:, a]
        mean = float(node_w @ e)
        out.append({"diameter_m": d_um * 1e-6, "quantity": kind, "stated": value,
                    "stated_sd": sd, "error_mean": mean,
                    "error_sd": float(np.sqrt(node_w @ (e - mean) ** 2))})
    return out


def summary(post: JointPosterior) -> dict[str, Any]:
    """The joint answer: ``support``, per-position answers, ``fit``, ``warnings``,
    ``thickness_prior``."""
    cells, mass = post.cells, post.mass
    b = post.best
    offsets = post.offsets()
    theta_map = float(cells.theta[b])
    rel = (cells.theta - theta_map + math.pi) % (2 * math.pi) - math.pi
    a_lo, a_hi = weighted_quantiles(np.degrees(rel), mass, (0.025, 0.975))
    o_lo, o_hi = weighted_quantiles(offsets, mass, (0.025, 0.975))
    answers = [position_answer(post, i) for i in range(len(post.likes))]
    misfits, n_terms, z_node = _best_fit(post)
    chi2 = float(sum(misfits)) + z_node
    node_w, mu_w = post.hyper_weights()
    # the misfit's own drop from the posterior's mean to the answer: the deviance's other
    # terms (the log-determinant of a covariance that grows next to the clamp) vary across the
    # posterior without being a parameter the data fix
    p_d = max(sum(a.expected_misfit for a in answers) + float(node_w @ post.node_z2) - chi2,
              0.0)
    dof = max(n_terms - min(p_d, n_terms), 1.0)
    p_value = float(chi2_dist.sf(chi2, dof))
    warnings: list[str] = []
    excess = [(lk.position.name, f - float(lk.estimate.chi2_min))
              for lk, f in zip(post.likes, misfits, strict=True)]
    inconsistent = p_value < P_INCONSISTENT
    if inconsistent:
        worst = sorted((e for e in excess if e[1] > DISAGREE_CHI2), key=lambda e: -e[1])
        named = ", ".join(f"{n} (chi^2 {e:+.3g} over its own best)" for n, e in worst[:5])
        warnings.append(
            "inconsistent: the positions do not agree with one straight clamped edge"
            + (f" and the plate's length {post.model.width * 1e3:.0f} mm"
               if post.model.kind == "opposite_edges" else "")
            + f" (chi^2 {chi2:.3g} for {dof:.3g} degrees of freedom, p = {p_value:.2g} < "
            f"{P_INCONSISTENT:g})" + (f"; disagreeing most: {named}" if named else "")
            + "; check their coordinates, the frame, or whether the support is straight")
    angle_width = a_hi - a_lo
    if angle_width > WIDE_ANGLE_DEG:
        warnings.append(f"the positions do not fix the edge's direction (95 % of its angle "
                        f"spans {angle_width:.0f} deg): add positions near the edge, spread "
                        "along it")
    for pos, why in post.excluded:
        warnings.append(f"position {pos.name} left out of the joint answer: {why}")
    if any(lk.position.calibration is None for lk in post.likes):
        from solitonde.instrument.inference.adequacy import NO_CALIBRATION

        warnings.append(NO_CALIBRATION)
    theta_line, offset_line = median_edge(post)
    normal = math.degrees(theta_line) % 360.0
    line_n = np.array([math.cos(theta_line), math.sin(theta_line)])
    to_line = [float(post.model.distance(np.array([lk.position.x_m, lk.position.y_m]) @ line_n
                                         - offset_line)) for lk in post.likes]
    residuals = [d - median for lk, d in zip(post.likes, to_line, strict=True)
                 if lk.estimate.distance_m.status == "constrained"
                 and (median := lk.estimate.distance_m.median) is not None]
    support = {
        "normal_angle_deg": normal,
        "offset_m": offset_line,
        "ci95_offset_m": [o_lo, o_hi],
        "n_positions": len(post.likes),
        "residual_m": float(np.sqrt(np.mean(np.square(residuals)))) if residuals else None,
        "ci95_normal_angle_deg": [(normal + a_lo) % 360.0, (normal + a_hi) % 360.0],
        "model": post.model.kind,
        "second_offset_m": (offset_line + post.model.width
                            if post.model.kind == "opposite_edges" else None),
        "status": "inconsistent" if inconsistent else "located",
    }
    positions = []
    for lk, ans, line_d in zip(post.likes, answers, to_line, strict=True):
        t, d = ans.thickness, ans.distance
        if inconsistent:
            t = ParameterEstimate(t.map, t.median, t.ci68, t.ci95, "inconsistent")
            d = ParameterEstimate(d.map, d.median, d.ci68, d.ci95, "inconsistent")
        positions.append({"position": lk.position.name, "x_m": lk.position.x_m,
                          "y_m": lk.position.y_m, "thickness_m": t.to_dict(),
                          "distance_m": d.to_dict(),
                          "distance_to_located_support_m": line_d})
    prior = post.prior.to_dict()
    if post.prior.kind == "common":
        q2, q50, q98 = weighted_quantiles(post.log_mu, mu_w, (0.025, 0.5, 0.975))
        prior["mean_m"] = {"median": math.exp(q50), "ci95": [math.exp(q2), math.exp(q98)]}
    return {"support": support, "positions": positions,
            "fit": {"chi2": chi2, "dof": dof, "p_value": p_value}, "warnings": warnings,
            "thickness_prior": prior, "edges": post.model.to_dict(),
            "shared_calibration": shared_calibration(post),
            "excluded": [{"position": p.name, "reason": w} for p, w in post.excluded]}


__all__ = ["EDGE_MODELS", "THICKNESS_PRIORS", "EdgeModel", "JointMapError", "JointPosterior",
           "ScanPosition", "ThicknessPrior", "calibration_nodes", "edge_model", "median_edge",
           "position_likelihood", "posterior", "shared_calibration",
           "summary", "weighted_quantiles"]
