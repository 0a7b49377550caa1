"""What the joint posterior says of each position (its thickness and distance), of the fit at
the joint best answer, and of where the edge lies (its posterior median line)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from solitonde.instrument.inference.joint_likelihood import Interp
from solitonde.instrument.inference.joint_posterior import JointPosterior
from solitonde.instrument.inference.marginals import ParameterEstimate, summarise_marginal

PROFILE_SUPPORT = 1e-4
"""A position's thickness profile ranges over the distances whose joint posterior density is
at least this fraction of its peak."""


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

    it = Interp.on(grid, np.clip(dist, grid[0], grid[-1]))
    n = it.idx.size
    spread = csr_matrix((np.concatenate([1.0 - it.frac, it.frac]),
                         (np.concatenate([np.arange(n), np.arange(n)]),
                          np.concatenate([it.idx, it.idx + 1]))), shape=(n, grid.size))
    return np.asarray((spread.T @ weights.T).T)


@dataclass
class PositionAnswer:
    """A position's thickness and distance from the joint posterior, and what the next
    position's choice and the joint fit read of it."""

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


def best_fit(post: JointPosterior) -> tuple[list[float], int, float]:
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
        it = Interp.on(lk.distance_m, np.clip(post.model.distance(d), lk.distance_m[0],
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
        it = Interp.on(lk.distance_m, np.array([dist]))
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
