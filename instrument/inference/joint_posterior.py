"""The edge's posterior on cells of (angle, offset), refined where it carries weight, and the
:class:`JointPosterior` that the joint answer and the next position's choice read."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.special import logsumexp

from solitonde.instrument.inference.joint_likelihood import Interp, PositionLikelihood
from solitonde.instrument.inference.joint_model import (
    EdgeModel,
    JointMapError,
    ScanPosition,
    ThicknessPrior,
)
from solitonde.instrument.tables.table import ModelTable

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
        total += Interp.on(grid, dist)(lm)
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
