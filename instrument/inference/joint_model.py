"""What a joint map assumes: a scan's positions, the clamped supports the table's family
declares, and the prior on the positions' thicknesses (:mod:`.joint_map` describes the model)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NotRequired, TypedDict

import numpy as np

from solitonde.instrument.errors import InstrumentError
from solitonde.instrument.inference.calibration import Calibration
from solitonde.instrument.inference.inversion_inputs import FeatureSummary
from solitonde.instrument.tables.table import ModelTable

EDGE_MODELS = ("opposite_edges", "line")
THICKNESS_PRIORS = ("free", "common")
DEFAULT_SPREAD = 0.05
"""Relative spread of a position's thickness around the plate's common mean (1 sd in log t)."""
SPREAD_RANGE = (1e-3, 1.0)
HYPER_STRIDE = 8
"""The common mean's grid: every 8th fine thickness (4 per table interval, 2.3 % apart on the
bundled tables' 16 thickness nodes). A spread well below that is under-resolved: the mean's
interval snaps to the grid's nodes (docs/explanation/joint-map.md)."""


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


class EdgeModelRow(TypedDict):
    """An edge model as the joint answer reports it (``edges``)."""

    kind: str
    width_m: float | None


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
        """Whether positions at signed distance ``d`` from the edge stand on the plate."""
        if self.kind == "opposite_edges":
            return (d >= 0.0) & (d <= self.width_m)
        return d >= 0.0

    def to_dict(self) -> EdgeModelRow:
        return {"kind": self.kind, "width_m": self.width_m}


def edge_model(table: ModelTable) -> EdgeModel:
    """The supports of the table's family (two opposite edges a plate length apart, or one
    line where the plate's size is not recorded).

    Raises JointMapError (``joint``) for a family without a clamped support or with all four
    edges clamped (not a line's angle and offset)."""
    family = table.family
    supports = family["supports"] if family else None
    size = family["plate_size_m"] if family else None
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


class PlateMean(TypedDict):
    """The common mean's posterior median and 95 % interval, in metres."""

    median: float
    ci95: list[float]


class ThicknessPriorRow(TypedDict):
    """A thickness prior as the joint answer reports it (``thickness_prior``)."""

    kind: str
    spread_rel: NotRequired[float]
    description: str
    mean_m: NotRequired[PlateMean]


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

    def to_dict(self) -> ThicknessPriorRow:
        if self.kind == "free":
            return {"kind": "free", "description": "each position's thickness free (uniform in "
                    "log t), as in a single inversion"}
        return {"kind": "common", "spread_rel": self.spread_rel,
                "description": f"each position's thickness scatters around the plate's common "
                f"mean (uniform in log) with a relative spread of {100 * self.spread_rel:.3g} % "
                "(1 sd, log-normal)"}
