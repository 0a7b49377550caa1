"""Each position's likelihood over the fine (thickness, distance) grid, at the nodes of the
scan's shared calibration errors and averaged over its coordinates' error (:mod:`.joint_map`
inverts each position and keeps it)."""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from solitonde.instrument.inference.estimate import Estimate
from solitonde.instrument.inference.joint_model import ScanPosition
from solitonde.instrument.inference.likelihood import CellLikelihood

POSITION_SD_M = 1.0e-3
"""How well a position's distance from the edge follows from its recorded coordinates (1 sd):
the coordinates' own error (the chain's contact point against the mark, read off a rule), so a
joint edge is not sharper than the positions can place it. (It was first sized for a distance
axis 10 mm apart next to the clamp too; the axis is 2.5 mm apart there now, and the value was
kept: in the map study dropping it did not narrow the edge's angle, docs/explanation/joint-map.md.)
Each position's likelihood is averaged over it along L."""


@dataclass
class Interp:
    """Linear interpolation weights of values on the fine distance grid."""

    idx: np.ndarray
    frac: np.ndarray

    @classmethod
    def on(cls, grid: np.ndarray, x: np.ndarray) -> Interp:
        j = np.clip(np.searchsorted(grid, x, side="right") - 1, 0, grid.size - 2)
        frac = np.clip((x - grid[j]) / (grid[j + 1] - grid[j]), 0.0, 1.0)
        return cls(j, frac)

    def __call__(self, values: np.ndarray) -> np.ndarray:
        """``values[..., L]`` at the points (last axis interpolated)."""
        return values[..., self.idx] * (1.0 - self.frac) + values[..., self.idx + 1] * self.frac


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
class RawLikelihood:
    """A position's deviance at the calibration's stated values, and how it moves with the
    calibration's errors (:func:`~.inversion.cell_likelihood` with ``shared_calibration``)."""

    position: ScanPosition
    estimate: Estimate
    keep: CellLikelihood
    keys: list[tuple[Any, ...]]
    """One key per shared error: (diameter, quantity, stated value, sd)."""


def at_nodes(raw: RawLikelihood, keys: Sequence[tuple[Any, ...]], eta: np.ndarray
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
        blur = blur_matrix(g.distance_m, POSITION_SD_M)
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


@functools.lru_cache(maxsize=8)
def _blur_cached(grid: tuple[float, ...], sd: float) -> np.ndarray:
    x = np.asarray(grid)
    step = sd / 8.0
    fine = np.arange(x[0], x[-1] + 0.5 * step, step)
    interp = Interp.on(x, fine)  # linear interpolation of the grid onto the fine points
    to_fine = np.zeros((fine.size, x.size))
    rows = np.arange(fine.size)
    to_fine[rows, interp.idx] += 1.0 - interp.frac
    to_fine[rows, interp.idx + 1] += interp.frac
    kernel = np.exp(-0.5 * ((x[:, None] - fine[None, :]) / sd) ** 2)
    kernel /= kernel.sum(axis=1, keepdims=True)  # truncated at the grid's ends (L >= 0)
    return kernel @ to_fine


def blur_matrix(grid: np.ndarray, sd: float) -> np.ndarray:
    """The matrix that averages a function given by its values on ``grid`` (linear between
    them) over a Gaussian of ``sd`` around each grid point."""
    return _blur_cached(tuple(float(v) for v in grid), float(sd))
