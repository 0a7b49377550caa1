"""Invert measured TOF and ARR against a model table: thickness and distance to the support.

Bayesian grid inversion. The table's features are interpolated (linear in log t and in L, the
axes along which TOF and ARR vary smoothly) onto a fine (log t, L) grid once per table and
sphere size; a prior uniform in log t (thickness is a scale) and in L over the table's range;
independent Gaussian errors on the mean TOF and mean ARR of each sphere size:

    sigma_tof^2 = s_tof^2 / n + sigma_model_tof(t, L)^2,   likewise for ARR

with s the shot scatter (or the stated defaults :data:`DEFAULT_TOF_REL_STD`,
:data:`DEFAULT_ARR_STD` when not given; floored at :data:`MIN_TOF_STD_S`, :data:`MIN_ARR_STD`) and
sigma_model the table's own interpolation error where the cell lies (leave-one-out at each node
along both axes, scaled to the grid spacing, interpolated like the features): large where TOF and
ARR oscillate with L near a support, small where they are smooth; plus, at nodes simulated on the
2-D plate (next to a support), that plate's own error against the 3-D plate
(:data:`PLATE_THEORY_TOF_REL_STD`, :data:`PLATE_THEORY_ARR_REL_STD`). A calibration fitted
against a table with a dissipation layer first reads the table at the chain's fitted contact
damping (instrument.tables.dissipation; its uncertainty adds to the model error); it multiplies the
model ARR by ``arr_factor`` (experiments lose energy the model does not) and adds ``tof_offset_s``
to the model TOF; its stated uncertainties (``arr_factor_std``, ``tof_offset_std_s``) enter the
variances. Beyond D/t = 5, where the paper finds ARR near 0 and the model's "reflection" is a
train at the detection floor whose features wander between table positions (table nodes with ARR
below :data:`FLOOR_ARR_MAX`; near a support the reflection is whole), the model error also holds
10 % of TOF and the whole ARR (:data:`FLOOR_TOF_REL_STD`, :data:`FLOOR_ARR_REL_STD`),
so such a size weighs little there. Where the model detects no reflection in that regime, the
reflection is below the detector's floor (the table's ``arr_upper_bound``, ~0.02), and a noisy
shot can still pick a floor-level "reflection" out of the noise: such a node is a floor node too,
its ARR that bound and its TOF that of the nearest reflection in its thickness row (far from a
support TOF hardly depends on L), so cells next to it explain a weak measured reflection instead
of being ruled out (which pinned thin plates far from a support to the few cells near it that
had one). Elsewhere, grid points where the model detects no reflection cannot explain a measured
one and get zero posterior. Sphere sizes multiply their likelihoods.

Per parameter the marginal posterior gives MAP, median, 68 % and 95 % central intervals, and a
status (:mod:`.marginals`): when the posterior still carries at least a fifth of its peak density
at an end of the table that is not a physical limit, the data do not bound the parameter on that
side (``lower_bound_only``: e.g. L beyond the critical distance, where TOF and ARR no longer depend
on L; ``upper_bound_only``; ``unconstrained`` on both sides). A one-sided result reports only the
bound (``ci95 = [lower, null]``), no MAP or median: the table's end is not an estimate; the bound
is where the density falls to the level of a likelihood-ratio interval (``marginals.LR_LEVELS``),
since a quantile of a density flat out to the table's end would follow the table's extent. A
measurement no table point explains (chi^2 beyond the 1e-6 tail) is ``out_of_range`` with no
numbers at all. With several sphere sizes, when all together are out of range but the others are
not once one size is left out, that answer is given, with the size left out named
(``excluded_diameters_m``, ``reason``): one disagreeing channel does not void the others. Unless
the size left out is a large sphere beyond D/t = 5 at the answer (its floor-level train), the
answer is then marked ``inconsistent`` (:mod:`.adequacy`): its numbers are the other sizes', but
the family does not explain the sizes together.

Near a support the likelihood is a ridge in (t, L), and the marginal weighs its parts by the
prior's volume in L, not by how well they fit. The thickness answer is therefore checked against
the profile likelihood (:mod:`.ridge`): its intervals reach over the thicknesses the profile
holds at their level, and where those fall into separate groups the answer is ``ambiguous``,
with one reading per group (``Estimate.readings``: thickness, distance, weight).

The plate material's spread (the library's for the table's plate material, or the one a
property mapping states) adds a rank-2 covariance shared by every term, from Zener's exchange
rates between material, thickness and distance (:mod:`.material_spread`), applied exactly per
cell with Woodbury's identity. A sphere size whose shots show no reflection enters with its ARR
upper bound: a cell weighs ``Phi((bound - ARR_model) / sigma)`` where the model has a reflection
and 1 where it has none, so such shots alone answer ``upper_bound_only``. Every estimate carries
``fit`` and ``warnings`` and may be marked ``inconsistent`` (:mod:`.adequacy`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from itertools import pairwise
from typing import Any

import numpy as np
from scipy.stats import chi2 as chi2_dist

from solitonde.instrument.errors import InstrumentError
from solitonde.instrument.inference import ridge
from solitonde.instrument.inference.calibration import (
    Calibration,
    calibrated_table,
    calibration_along,
)
from solitonde.instrument.inference.marginals import (
    ParameterEstimate,
    _summarise,
)
from solitonde.instrument.inference.sizes import SPHERE_DIAMETER_MAX, size_problem
from solitonde.instrument.tables.table import (
    STATUS_NO_REFLECTION,
    STATUS_OK,
    ModelTable,
    TableError,
)

DEFAULT_TOF_REL_STD = 0.01
"""Per-shot TOF scatter assumed when none is given: 1 % of the TOF."""
DEFAULT_ARR_STD = 0.03
"""Per-shot ARR scatter assumed when none is given (absolute)."""
MIN_TOF_STD_S = 0.2e-6
"""Floor of the per-shot TOF scatter (a tenth of a 2 MHz sample): a scatter of 0 from few
identical shots must not make the likelihood infinitely sharp."""
MIN_ARR_STD = 0.003
"""Floor of the per-shot ARR scatter."""
OUT_OF_RANGE_TAIL = 1e-6
"""Tail probability of the best chi^2 beyond which no table point explains the data."""
REFLECTION_D_OVER_T = 5.0
"""Above this D/t the paper finds ARR near 0: the model's "reflection" is a train at the
detection floor whose features wander from one table position to the next (TOF by ~10 %)."""
FLOOR_TOF_REL_STD = 0.1
FLOOR_ARR_REL_STD = 1.0
"""Model uncertainty at table nodes beyond :data:`REFLECTION_D_OVER_T` whose reflection is weak
(ARR below :data:`FLOOR_ARR_MAX`): TOF known to 10 %, ARR only as "small" (its own size), so
such a size barely weighs there instead of pinning (t, L) to a wandering value."""
FLOOR_ARR_MAX = 0.3
"""A reflection with ARR above this is a clear pulse even beyond D/t = 5 (near a support the
clamp returns the wave whole, ARR up to 0.99): its features are as exact as anywhere, and the
floor uncertainty would wrongly make such cells unlikely through the likelihood's log-variance."""
PLATE_THEORY_TOF_REL_STD = 0.0025
PLATE_THEORY_ARR_REL_STD = 0.0135
"""The 2-D (Mindlin-Reissner) plate's own error against the 3-D plate, at table nodes simulated on
it (next to a support; relative standard deviations): half the largest seen over the 25
near-support scenes of the tiers' comparison (0.49 % in TOF, 2.7 % in ARR; README, "Where a 2-D
plate suffices"). With the distance axis 2.5 mm apart next to the clamp the interpolation error
there fell to 0.2-1 % of ARR, under this: the bundled scan, simulated on the 3-D plate, read
ARR 0.9-2.4 % above the table and TOF 1.0-2.2 us earlier at 8-25 mm from the clamp, two to six
times the interpolation error alone. Far from the supports the table's dashpot is calibrated on
reference plates of its own tier, which takes up its error there."""
MINDLIN_PLATE_MODELS = ("mindlin", "mindlin_greens")
"""The tiers :data:`PLATE_THEORY_TOF_REL_STD` applies to."""
FINE_THICKNESS_STEPS = 32
"""Fine cells per table interval in thickness (log-uniform within each interval)."""
FINE_DISTANCE_STEP_M = 0.0025
"""Largest fine cell in distance (each table interval is split evenly)."""
FINE_DISTANCE_MIN_STEPS = 5
"""Fewest fine cells per table interval in distance. Next to a support TOF and ARR change fast
with L (a 1.5 mm plate: 27 us and 0.15 in ARR between the nodes 5 and 7.5 mm from the clamp), and
a grid of the nodes alone there placed a plate 6.2 mm from it at 5 or 7.5 mm, where neither fits:
its interval missed it."""
MIN_FLOOR_MASS = 0.1
"""Posterior mean weight on floor nodes above which the adequacy check asks whether a size's
features are explained without the floor's looseness (instrument.inference.adequacy)."""
PARAMETERS = ("thickness_m", "distance_m")
LOG_BATCH = 8
"""Variances multiplied before one log. A variance lies between about 1e-19 s^2 (the TOF floor
over 1e5 shots) and 1e2 (an ARR scatter of 10, the most an input may state): a product of 8
stays between 1e-152 and 1e16, far from underflow and overflow."""


class InversionError(InstrumentError, ValueError):
    """Bad inversion input; ``field`` names it."""



@dataclass(frozen=True)
class FeatureSummary:
    """The shots of one sphere size: mean TOF and ARR, their scatter and the shot count.

    A size whose shots show no reflection gives no TOF and no ARR but ``arr_upper_bound``, the
    largest ARR that could have hidden under the noise: it still bounds the plate (a reflection
    that small means a thin plate), and enters the likelihood as such.
    """

    diameter_m: float
    tof_s: float | None
    arr: float | None
    tof_std_s: float | None = None
    arr_std: float | None = None
    n_shots: int = 1
    arr_upper_bound: float | None = None
    tof_window_s: float | None = None
    """A hidden size's: the longest TOF its records would have shown whole (the bound says
    nothing of a reflection arriving later); None: no limit known."""

    def __post_init__(self) -> None:
        def check(name: str, value: Any, ok: bool, allowed: str) -> None:
            if not ok:
                raise InversionError(name, f"got {value!r} (allowed: {allowed})")

        def number(v: Any) -> bool:
            return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)

        hidden = self.tof_s is None and self.arr is None
        names = ("diameter_m", "arr_upper_bound") if hidden else ("diameter_m", "tof_s", "arr")
        for name in names:
            v = getattr(self, name)
            check(name, v, number(v), "a finite number" + (
                " (a size without TOF and ARR needs the bound of its hidden reflection)"
                if name == "arr_upper_bound" else ""))
        check("diameter_m", self.diameter_m, size_problem(self.diameter_m) is None,
              f"0 < D <= {SPHERE_DIAMETER_MAX:g} m; " + (size_problem(self.diameter_m) or ""))
        if hidden:
            bound = self.arr_upper_bound
            check("arr_upper_bound", bound, bound is not None and 0 < bound <= 1.5,
                  "0 < bound <= 1.5")
        else:
            check("tof_s", self.tof_s, self.tof_s is not None and self.tof_s > 0, "> 0 s")
            check("arr", self.arr, self.arr is not None and self.arr >= 0, ">= 0")
            check("arr_upper_bound", self.arr_upper_bound, self.arr_upper_bound is None,
                  "null when TOF and ARR are given")
        for name in ("tof_std_s", "arr_std"):
            v = getattr(self, name)
            check(name, v, v is None or (isinstance(v, int | float) and math.isfinite(v)
                                         and v >= 0), ">= 0, or null for the default")
        check("n_shots", self.n_shots, isinstance(self.n_shots, int) and self.n_shots >= 1,
              "an integer >= 1")
        check("tof_window_s", self.tof_window_s, self.tof_window_s is None or (
            hidden and number(self.tof_window_s)), "a finite number of seconds, for a size "
              "without TOF and ARR only, or null")

    @property
    def hidden(self) -> bool:
        """Whether this size shows no reflection (only its ARR bound)."""
        return self.tof_s is None

    @classmethod
    def from_any(cls, item: FeatureSummary | Mapping[str, Any]) -> FeatureSummary:
        if isinstance(item, FeatureSummary):
            return item
        if not isinstance(item, Mapping):
            raise InversionError("inputs", f"expected a mapping, got {type(item).__name__}")
        known = {"diameter_m", "tof_s", "arr", "tof_std_s", "arr_std", "n_shots",
                 "arr_upper_bound", "tof_window_s"}
        extra = set(item) - known
        if extra:
            raise InversionError(sorted(extra)[0], f"unknown key (allowed: {sorted(known)})")
        hidden = (item.get("tof_s") is None and item.get("arr") is None
                  and item.get("arr_upper_bound") is not None)
        for key in ("diameter_m",) if hidden else ("diameter_m", "tof_s", "arr"):
            if item.get(key) is None:
                raise InversionError(key, "missing")
        n = item.get("n_shots", 1)
        if isinstance(n, float) and n.is_integer():
            n = int(n)

        def opt(key: str) -> float | None:
            return None if item.get(key) is None else float(item[key])

        return cls(float(item["diameter_m"]), opt("tof_s"), opt("arr"), opt("tof_std_s"),
                   opt("arr_std"), 1 if n is None else n, opt("arr_upper_bound"),
                   opt("tof_window_s"))

    def sigmas(self) -> tuple[float, float]:
        """Standard errors of the mean TOF (s) and mean ARR, before the model error."""
        if self.hidden:
            raise InversionError("tof_s", "a size without a reflection has no TOF")
        assert self.tof_s is not None  # not hidden
        s_tof = self.tof_std_s if self.tof_std_s is not None else DEFAULT_TOF_REL_STD * self.tof_s
        s_arr = self.arr_std if self.arr_std is not None else DEFAULT_ARR_STD
        root = math.sqrt(self.n_shots)
        return max(s_tof, MIN_TOF_STD_S) / root, max(s_arr, MIN_ARR_STD) / root

    def bound_sigma(self) -> float:
        """Standard error of a hidden reflection's ARR against its bound: the per-shot default
        ARR scatter over the shots."""
        return max(DEFAULT_ARR_STD, MIN_ARR_STD) / math.sqrt(self.n_shots)


# The fine grid ----------------------------------------------------------------------------


def _refine(nodes: np.ndarray, steps: Any) -> np.ndarray:
    """The nodes with ``steps(width)`` even sub-intervals inserted between each neighbour pair."""
    if nodes.size == 1:
        return nodes.astype(float).copy()
    parts = [np.linspace(a, b, steps(b - a) + 1)[:-1] for a, b in pairwise(nodes)]
    return np.concatenate([*parts, nodes[-1:]])


def _cell_widths(x: np.ndarray) -> np.ndarray:
    """Width of each point's cell (midpoint to midpoint, half cells at the ends): the prior mass
    of a point under a prior uniform in x."""
    if x.size == 1:
        return np.ones(1)
    mid = 0.5 * (x[1:] + x[:-1])
    edges = np.concatenate([x[:1], mid, x[-1:]])
    return np.diff(edges)


def _interp_matrix(nodes: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Linear-interpolation weights W (len(x), len(nodes)): f(x) = W @ f(nodes)."""
    w = np.zeros((x.size, nodes.size))
    if nodes.size == 1:
        w[:, 0] = 1.0
        return w
    j = np.clip(np.searchsorted(nodes, x, side="right") - 1, 0, nodes.size - 2)
    frac = np.clip((x - nodes[j]) / (nodes[j + 1] - nodes[j]), 0.0, 1.0)
    rows = np.arange(x.size)
    w[rows, j] = 1.0 - frac
    w[rows, j + 1] += frac
    return w


def _node_variance(values: np.ndarray, valid: np.ndarray, coord_t: np.ndarray,
                   coord_l: np.ndarray) -> np.ndarray:
    """Variance of the table's interpolation error at each node, from leave-one-out.

    Along each axis, an interior node is predicted linearly from its two neighbours; linear
    interpolation over twice the spacing errs about four times as much as over the spacing
    itself (error ~ h^2 f''), so (LOO error / 4)^2 is the variance there. End nodes take their
    neighbour's value, nodes without valid neighbours the mean over the table; the two axes add.
    Rough regions (near a support, where guided waves make TOF and ARR oscillate with L) so get
    large errors and smooth ones small errors.
    """
    total = np.zeros(values.shape)
    for axis, c in ((0, coord_t), (1, coord_l)):
        v = np.moveaxis(values, axis, 0)
        ok = np.moveaxis(valid, axis, 0)
        e2 = np.full(v.shape, np.nan)
        if v.shape[0] >= 3:
            cc = c.reshape((-1,) + (1,) * (v.ndim - 1))
            a = (cc[1:-1] - cc[:-2]) / (cc[2:] - cc[:-2])
            pred = v[:-2] * (1 - a) + v[2:] * a
            good = ok[:-2] & ok[1:-1] & ok[2:]
            e2[1:-1] = np.where(good, ((v[1:-1] - pred) / 4.0) ** 2, np.nan)
            e2[0], e2[-1] = e2[1], e2[-2]
        fill = float(np.nanmean(e2)) if np.isfinite(e2).any() else 0.0
        total += np.moveaxis(np.where(np.isfinite(e2), e2, fill), 0, axis)
    return np.where(valid, total, 0.0)


@dataclass
class FineGrid:
    """One sphere size's table features on the fine (t, L) grid, ready for likelihoods."""

    diameter_m: float
    thickness_m: np.ndarray
    distance_m: np.ndarray
    tof_s: np.ndarray
    arr: np.ndarray
    valid: np.ndarray
    penalty: np.ndarray
    model_tof_var: np.ndarray
    model_arr_var: np.ndarray
    weight_t: np.ndarray
    weight_l: np.ndarray
    floor_weight: np.ndarray
    """Each cell's interpolation weight on floor nodes (a reflection at the detection floor)."""
    reflect_weight: np.ndarray
    """Each cell's interpolation weight on nodes where the model detects a reflection."""
    arr_reflecting: np.ndarray
    """ARR interpolated over those nodes alone (what a hidden reflection is compared with)."""
    model_tof_var_strict: np.ndarray
    model_arr_var_strict: np.ndarray
    """The interpolation error alone, without the floor nodes' looseness (the adequacy check
    asks whether a clear reflection is explained without it)."""

    @property
    def model_tof_std_s(self) -> float:
        """RMS interpolation error of TOF over the valid cells, s."""
        return float(np.sqrt(self.model_tof_var[self.valid].mean())) if self.valid.any() else 0.0

    @property
    def model_arr_std(self) -> float:
        """RMS interpolation error of ARR over the valid cells."""
        return float(np.sqrt(self.model_arr_var[self.valid].mean())) if self.valid.any() else 0.0


def _row_nearest(values: np.ndarray, ok: np.ndarray, l_nodes: np.ndarray) -> np.ndarray:
    """Each node's value replaced by that of the nearest node in L (same thickness) with
    ``ok``; rows without one keep theirs. Far from a support TOF hardly depends on L, so a
    floor node's unseen reflection is given its nearest neighbour's time."""
    out = values.copy()
    for i in range(values.shape[0]):
        good = np.flatnonzero(ok[i])
        if good.size:
            nearest = good[np.abs(l_nodes[good][None, :] - l_nodes[:, None]).argmin(axis=1)]
            out[i] = values[i, nearest]
    return out


def fine_grid(table: ModelTable, i_d: int) -> FineGrid:
    """The fine grid of sphere size ``i_d`` (computed once per table and kept on it)."""
    key = f"fine:{i_d}"
    cached = table._cache.get(key)
    if cached is not None:
        return cached
    t_nodes, l_nodes = table.axes["thickness_m"], table.axes["distance_m"]
    # Every table node is a fine point (a measurement at a node is judged on the node's own
    # features); log-uniform in t inside each interval, as the prior is uniform in log t.
    log_t = _refine(np.log(t_nodes), lambda width: FINE_THICKNESS_STEPS)
    t_f = np.exp(log_t)
    l_f = _refine(l_nodes, lambda width: max(FINE_DISTANCE_MIN_STEPS,
                                             math.ceil(width / FINE_DISTANCE_STEP_M - 1e-9)))
    wt = _interp_matrix(np.log(t_nodes), log_t)
    wl = _interp_matrix(l_nodes, l_f)
    ok = table.status[i_d] == STATUS_OK
    tof = np.where(ok, table.features["tof_s"][i_d], 0.0)
    arr = np.where(ok, table.features["arr"][i_d], 0.0)
    diameter = float(table.axes["diameter_m"][i_d])
    beyond = (diameter / t_nodes > REFLECTION_D_OVER_T)[:, None]
    # no-reflection nodes there take floor-level features, given a reflection in their row to
    # borrow a TOF from
    quiet = (beyond & (table.status[i_d] == STATUS_NO_REFLECTION)
             & ok.any(axis=1, keepdims=True))
    has = ok | quiet  # nodes with features (measured, or filled in at the floor)
    bound = np.nan_to_num(table.features["arr_upper_bound"][i_d])
    arr = np.where(quiet, bound, arr)
    tof = np.where(quiet, _row_nearest(tof, ok, l_nodes), tof)
    floor = (beyond & (arr < FLOOR_ARR_MAX) & has).astype(float)
    two_d = np.isin(table.plate_model[i_d], [table.plate_model_names.index(name)
                                             for name in MINDLIN_PLATE_MODELS
                                             if name in table.plate_model_names])
    tof_var = (_node_variance(tof, ok, np.log(t_nodes), l_nodes)
               + np.where(two_d, (PLATE_THEORY_TOF_REL_STD * tof) ** 2, 0.0))
    arr_var = (_node_variance(arr, ok, np.log(t_nodes), l_nodes)
               + np.where(two_d, (PLATE_THEORY_ARR_REL_STD * arr) ** 2, 0.0))
    if table.model_variance is not None:  # e.g. a fitted damping's uncertainty
        tof_var = tof_var + np.where(has, table.model_variance["tof_s"][i_d], 0.0)
        arr_var = arr_var + np.where(has, table.model_variance["arr"][i_d], 0.0)
    # A cell whose interpolation touches a node without features has none itself.
    touched = (wt > 1e-12).astype(float) @ (~has).astype(float) @ (wl > 1e-12).astype(float).T
    valid = touched == 0
    grid = FineGrid(
        diameter_m=diameter,
        thickness_m=t_f,
        distance_m=l_f,
        tof_s=wt @ tof @ wl.T,
        arr=wt @ arr @ wl.T,
        valid=valid,
        penalty=np.where(valid, 0.0, np.inf),
        model_tof_var=wt @ (tof_var + floor * (FLOOR_TOF_REL_STD * tof) ** 2) @ wl.T,
        model_arr_var=wt @ (arr_var + floor * (FLOOR_ARR_REL_STD * arr) ** 2) @ wl.T,
        model_tof_var_strict=wt @ tof_var @ wl.T,
        model_arr_var_strict=wt @ arr_var @ wl.T,
        weight_t=_cell_widths(log_t),
        weight_l=_cell_widths(l_f),
        floor_weight=wt @ floor @ wl.T,
        reflect_weight=(h := wt @ ok.astype(float) @ wl.T),
        arr_reflecting=np.divide(wt @ np.where(ok, table.features["arr"][i_d], 0.0) @ wl.T, h,
                                 out=np.zeros_like(h), where=h > 1e-12),
    )
    table._cache[key] = grid
    return grid


def predict(table: ModelTable, diameter_m: float, thickness_m: float,
            distance_m: float, *, with_error: bool = False) -> tuple[float, ...]:
    """Model (TOF s, ARR) at one (D, t, L) inside the table, interpolated as the inversion does;
    with ``with_error`` also the interpolation error's standard deviations (TOF s, ARR).

    Raises
    ------
    InversionError
        Outside the table's range, or where the model detects no reflection.
    """
    i_d = table.diameter_index(diameter_m)
    t_nodes, l_nodes = table.axes["thickness_m"], table.axes["distance_m"]
    for name, x, nodes in (("thickness_m", thickness_m, t_nodes), ("distance_m", distance_m,
                                                                    l_nodes)):
        if not nodes[0] <= x <= nodes[-1]:
            raise InversionError(name, f"{x!r} m is outside the table "
                                 f"({nodes[0]:g}..{nodes[-1]:g} m)")
    wt = _interp_matrix(np.log(t_nodes), np.array([math.log(thickness_m)]))
    wl = _interp_matrix(l_nodes, np.array([distance_m]))
    ok = table.status[i_d] == STATUS_OK
    if ((wt > 1e-12).astype(float) @ (~ok).astype(float) @ (wl > 1e-12).astype(float).T)[0, 0]:
        raise InversionError("thickness_m", "the model detects no reflection next to this point")
    tof_n = np.where(ok, table.features["tof_s"][i_d], 0.0)
    arr_n = np.where(ok, table.features["arr"][i_d], 0.0)
    tof = float((wt @ tof_n @ wl.T)[0, 0])
    arr = float((wt @ arr_n @ wl.T)[0, 0])
    if not with_error:
        return tof, arr
    ct, cl = np.log(t_nodes), l_nodes
    tof_var, arr_var = _node_variance(tof_n, ok, ct, cl), _node_variance(arr_n, ok, ct, cl)
    if table.model_variance is not None:
        tof_var = tof_var + np.where(ok, table.model_variance["tof_s"][i_d], 0.0)
        arr_var = arr_var + np.where(ok, table.model_variance["arr"][i_d], 0.0)
    tof_sd = math.sqrt(float((wt @ tof_var @ wl.T)[0, 0]))
    arr_sd = math.sqrt(float((wt @ arr_var @ wl.T)[0, 0]))
    return tof, arr, tof_sd, arr_sd


# The estimate -----------------------------------------------------------------------------


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
    extra: dict[str, Any] = field(default_factory=dict)
    fit: dict[str, float | None] = field(default_factory=dict)
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

    def to_dict(self, posterior: bool = False) -> dict[str, Any]:
        out: dict[str, Any] = {
            "thickness_m": self.thickness_m.to_dict(),
            "distance_m": self.distance_m.to_dict(),
            "chi2_min": self.chi2_min,
            "n_terms": self.n_terms,
            "fit": dict(self.fit) or {"chi2": None, "dof": None, "p_value": None},
            "warnings": list(self.warnings),
            "reason": self.reason,
            "inputs": [vars(i).copy() for i in self.inputs],
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


def _second_reading(readings: list[ridge.Reading], thickness_m: np.ndarray) -> dict[str, Any]:
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


@functools.lru_cache(maxsize=8)
def _chi2_limit_at(n_terms: int, tail: float) -> float:
    return float(chi2_dist.isf(tail, n_terms))


@functools.lru_cache(maxsize=64)
def _chi2_limit(n_terms: int) -> float:
    """The chi^2 beyond which no table point explains ``n_terms`` terms (scipy's isf costs a
    quarter of a millisecond, an eighth of an inversion)."""
    return float(chi2_dist.isf(OUT_OF_RANGE_TAIL, n_terms))


def _out_of_range(inputs: list[FeatureSummary], cal: Calibration | None, chi2_min: float,
                  n_terms: int, reason: str) -> Estimate:
    nothing = ParameterEstimate(None, None, None, None, "out_of_range")
    return Estimate(nothing, ParameterEstimate(None, None, None, None, "out_of_range"), inputs,
                    cal, chi2_min, n_terms, reason)


def invert(
    table: ModelTable,
    inputs: Sequence[FeatureSummary | Mapping[str, Any]],
    calibration: Calibration | Mapping[str, Any] | None = None,
    *,
    return_posterior: bool = False,
    material_spread: Mapping[str, float] | None = None,
) -> Estimate:
    """Posterior estimate of plate thickness and distance to the support.

    Parameters
    ----------
    table: the model table.
    inputs: one summary per sphere size (:class:`FeatureSummary` or a mapping with its fields).
    calibration: ARR factor and TOF offset (:class:`Calibration` or its dict).
    return_posterior: keep the 2-D posterior (``Estimate.posterior``: axes and density).
    material_spread: the plate material's spread (``youngs_modulus_rel_sd``,
        ``poisson_ratio_sd``, ``density_rel_sd``); None takes the library's for the table's
        plate material (instrument.inference.material_spread), zeros turn it off.

    Raises
    ------
    InversionError, TableError
        Bad input, or a sphere size the table does not hold.
    """
    from solitonde.instrument.inference import adequacy
    from solitonde.instrument.inference.material_spread import spread_of

    if isinstance(inputs, Mapping | FeatureSummary) or not inputs:
        raise InversionError("inputs", "give a non-empty list of per-sphere-size summaries")
    items = [FeatureSummary.from_any(i) for i in inputs]
    cal = Calibration.from_any(calibration)
    spread = dict(spread_of(table) if material_spread is None else material_spread)
    est = _invert_items(table, items, cal, return_posterior, spread)
    if est.out_of_range and len(items) >= 2:
        # One sphere size may disagree with the others and the table (e.g. a large sphere on a
        # thin plate whose "reflection" is a train at the detection floor): leave each out in
        # turn and keep the best in-range answer of the others, saying which size was left out
        # and why.
        kept: list[tuple[float, int, Estimate]] = []
        for skip in range(len(items)):
            rest = items[:skip] + items[skip + 1:]
            if all(i.hidden for i in rest):
                continue
            trial = _invert_items(table, rest, cal, return_posterior, spread)
            if not trial.out_of_range:
                tail = float(chi2_dist.sf(trial.chi2_min, max(trial.n_terms, 1)))
                kept.append((tail, skip, trial))
        if kept:
            _, skip, best = max(kept, key=lambda k: k[0])
            left_out = items[skip]
            best.reason = (f"sphere size D = {left_out.diameter_m * 1e3:.2f} mm left out: with "
                           f"it no table point explains the measurement ({est.reason}); the "
                           "other sizes agree with the table")
            best.extra["excluded_diameters_m"] = [left_out.diameter_m]
            best.inputs = items
            est = best
    est.material_spread = spread
    adequacy.judge(est, FLOOR_ARR_MAX, REFLECTION_D_OVER_T,
                   float(np.min(table.axes["thickness_m"])))
    stale = adequacy.reading_mismatch(table.reading_version)
    if stale is not None:
        est.warnings.append(stale)
    return est


def _invert_items(table: ModelTable, items: list[FeatureSummary], cal: Calibration | None,
                  return_posterior: bool, spread: Mapping[str, float] | None = None,
                  keep: dict[str, Any] | None = None, shared_calibration: bool = False
                  ) -> Estimate:
    """The grid posterior of :func:`invert` for exactly these sphere sizes.

    Per cell, -2 log likelihood = chi^2 + log det C (+ the hidden sizes' bound terms), with C the
    terms' covariance: diagonal (shot scatter, the table's interpolation error, the calibration)
    plus, when the plate material has a spread, the rank-2 covariance ``U U^T`` it induces
    across every term (instrument.inference.material_spread), applied with Woodbury's identity.

    ``shared_calibration`` (with ``keep``): the calibration's stated TOF offset uncertainty is
    left out of C and kept instead as the exact dependence of the deviance on the offsets'
    errors ``eta`` (an error adds to the model TOF: the residual moves linearly),
    ``chi^2(eta) = chi^2(0) - 2 b.eta + eta^T Q eta`` per cell, so that a plate's joint map can
    draw one offset error for all its positions (instrument.inference.joint_map). The ARR
    factor's uncertainty stays in C, per position.
    """
    from solitonde.instrument.inference.material_spread import sensitivity

    table = calibrated_table(table, cal)  # at the chain's fitted damping, if it has one
    seen = [i for i in items if not i.hidden]
    hidden = [i for i in items if i.hidden]
    grids = [fine_grid(table, table.diameter_index(i.diameter_m)) for i in items]
    g0 = grids[0]
    shape = g0.tof_s.shape
    misfit = np.zeros(shape)
    bound_terms = np.zeros(shape)
    bound_list: list[np.ndarray] = []
    var = np.empty(shape)
    r = np.empty(shape)
    # the log-variances as one log of a running product, taken every LOG_BATCH terms (a log
    # over the grid costs as much as the rest of a term)
    logdet = np.zeros(shape)
    det = np.ones(shape)
    terms = 0
    penalty = np.zeros(shape)
    ur_sum: np.ndarray | None = None
    m_sum: np.ndarray | None = None
    # shared calibration errors: per error, (diameter, kind, sd, b, q, U^T D^-1 e)
    shared: list[list[Any]] = []
    for item, g in zip(items, grids, strict=True):
        # numbers, or rows over the grid's distance axis where the calibration follows distance
        factor, offset, f_std, o_std = calibration_along(cal, g.diameter_m, g.distance_m[None, :])
        if item.hidden:
            # no reflection seen: the model's ARR (where it has a reflection) must lie under the
            # bound; cells where the model itself detects none agree with it
            sd = np.sqrt(item.bound_sigma() ** 2 + factor**2 * g.model_arr_var
                         + (f_std * g.arr_reflecting) ** 2)
            z = (item.arr_upper_bound - factor * g.arr_reflecting) / sd
            under = _normal_cdf(z)
            if item.tof_window_s is not None:
                # a reflection later than the records' window would not have been seen: the
                # bound holds only with the probability that the model's arrives within it
                tof_sd = np.sqrt(g.model_tof_var + o_std**2 + MIN_TOF_STD_S**2)
                p_in = _normal_cdf((item.tof_window_s - offset - np.nan_to_num(g.tof_s)) / tof_sd)
                under = p_in * under + (1.0 - p_in)
            like = (1.0 - g.reflect_weight) + g.reflect_weight * under
            term = -2.0 * np.log(np.maximum(like, 1e-300))
            bound_terms += term
            bound_list.append(term)
            continue
        s_tof, s_arr = item.sigmas()
        u_pair = (sensitivity(table, g, spread, (REFLECTION_D_OVER_T, FLOOR_ARR_MAX)) if spread
                  else None)
        share = shared_calibration and keep is not None
        for k, (model, obs, scale, s2, model_var, rel2) in enumerate((
            (g.tof_s, item.tof_s - offset, 1.0, s_tof**2 + (0.0 if share else o_std**2),
             g.model_tof_var, 0.0),
            (g.arr, item.arr, factor, s_arr**2, g.model_arr_var, f_std**2),
        )):
            # the calibration's own uncertainty: offset adds, factor scales the model ARR
            unscaled = np.ndim(scale) == 0 and scale == 1.0
            if unscaled:
                np.add(model_var, s2, out=var)
                np.subtract(obs, model, out=r)
            else:
                np.multiply(model_var, scale * scale, out=var)
                var += s2
                np.multiply(model, -scale, out=r)
                r += obs
            if np.any(rel2):
                rel = np.multiply(model, model)
                rel *= rel2
                var += rel
            u_over = None
            if u_pair is not None:
                u = u_pair[k] if unscaled else u_pair[k] * scale
                u_over = u / var
                ur = u_over * r
                ur_sum = ur if ur_sum is None else ur_sum + ur
                # the three distinct entries of U^T D^-1 U (symmetric 2 x 2)
                if m_sum is None:
                    m_sum = np.zeros((3, *shape))
                for n_e, (a, b) in enumerate(_UPPER):
                    m_sum[n_e] += u_over[a] * u[b]
            if share and k == 0 and np.any(o_std > 0):
                # the TOF residual moves by -1 per unit error of the offset (where the offset's
                # sd follows distance: one error, scaled to each distance's sd)
                sd = float(np.max(o_std))
                e = np.ones(shape) if np.ndim(o_std) == 0 else np.broadcast_to(o_std / sd, shape)
                shared.append([g.diameter_m, "tof_offset_s", sd,
                               e * r / var, e * e / var,
                               None if u_over is None else u_over * e])
            r *= r
            r /= var
            misfit += r
            det *= var
            terms += 1
            if terms % LOG_BATCH == 0:
                logdet += np.log(det)
                det.fill(1.0)
        penalty += g.penalty
    if terms % LOG_BATCH:
        logdet += np.log(det)
    b_sh = np.array([e[3] for e in shared]).reshape(len(shared), *shape)
    q_sh = np.zeros((len(shared), len(shared), *shape))
    for n_e, err in enumerate(shared):
        q_sh[n_e, n_e] = err[4]
    if m_sum is not None and ur_sum is not None:
        # Woodbury: C = D + U U^T  ->  chi^2 -= b^T M^-1 b, log det C += log det M, with
        # M = I + U^T D^-1 U and b = U^T D^-1 r (2 x 2 per cell, solved in closed form)
        quad, logdet_m = _solve2(m_sum, ur_sum)
        ok = np.isfinite(penalty)
        misfit[ok] -= quad[ok]
        logdet[ok] += logdet_m[ok]
        # the shared errors' coefficients through the same C^-1 (D^-1 - D^-1 U M^-1 U^T D^-1)
        for n_e, err in enumerate(shared):
            b_sh[n_e] -= _bilinear2(m_sum, err[5], ur_sum)
            for n_f, f in enumerate(shared):
                q_sh[n_e, n_f] -= _bilinear2(m_sum, err[5], f[5])
    n_terms = 2 * len(seen) + len(hidden)
    chi2 = misfit + logdet + penalty + bound_terms
    if keep is not None:  # the cells' likelihood itself, for a plate's joint map
        keep.update(deviance=chi2.copy(), n_terms=n_terms, grid=g0, misfit=misfit + sum(
            (np.maximum(b - 2.0 * math.log(2.0), 0.0) for b in bound_list), np.zeros(shape)),
            shared=[(float(e[0]), str(e[1]), float(e[2])) for e in shared],
            shared_b=b_sh, shared_q=q_sh)
    best = float(chi2.min())
    i_best = np.unravel_index(int(np.argmin(chi2)), chi2.shape)
    if not math.isfinite(best):
        return _out_of_range(items, cal, best, n_terms,
                             "the model detects no reflection anywhere in the table for these "
                             "sphere sizes, but one was measured")
    # a hidden size's misfit: -2 log of its likelihood against an ARR at the bound itself
    # (1/2), about z^2 once the model's reflection clearly exceeds the bound, 0 below it
    fit = float(misfit[i_best]) + sum(max(0.0, float(b[i_best]) - 2.0 * math.log(2.0))
                                      for b in bound_list)
    if n_terms:
        limit = _chi2_limit(n_terms)
        if fit > limit:
            return _out_of_range(items, cal, fit, n_terms,
                                 f"no table point explains the measurement (best chi^2 "
                                 f"{fit:.3g} > {limit:.3g} for {n_terms} terms): outside the "
                                 "table's range or not this kind of plate; no extrapolated "
                                 "number is given")
    chi2 -= best
    finite = np.isfinite(chi2)
    chi2 *= -0.5
    post = np.exp(chi2, out=chi2)
    # the profile likelihood of each parameter (the best over the other), before the prior
    profile_t, profile_l = post.max(axis=1), post.max(axis=0)
    post *= g0.weight_t[:, None]  # prior mass of each cell: uniform in log t and in L
    post *= g0.weight_l[None, :]
    post /= post.sum()
    thickness = _summarise(np.log(g0.thickness_m), post.sum(axis=1), g0.weight_t,
                           lower_physical=False, transform=np.exp, profile=profile_t)
    distance = _summarise(g0.distance_m, post.sum(axis=0), g0.weight_l,
                          lower_physical=bool(g0.distance_m[0] <= 0.0), profile=profile_l)
    marginal = thickness
    thickness, distance, readings = ridge.resolve(
        thickness, distance, g0.thickness_m, g0.distance_m, post, g0.weight_t, g0.weight_l,
        profile_t, lower_physical=bool(g0.distance_m[0] <= 0.0))
    est = Estimate(thickness, distance, items, cal, fit, n_terms, readings=readings)
    if thickness.status == marginal.status and thickness.ci95 != marginal.ci95:
        est.extra["ridge_widened"] = {"marginal_ci95": list(marginal.ci95 or ()),
                                      "ci95": list(thickness.ci95 or ())}
    if len(readings) > 1:
        est.extra["other_reading"] = _second_reading(readings, g0.thickness_m)
    # what the adequacy check reads: the effective number of parameters the data fix (the
    # posterior mean of the deviance over its minimum, Spiegelhalter et al.'s p_D) and, per
    # seen size, the posterior's weight on floor cells
    deviance = misfit + logdet + bound_terms
    d_best = float(deviance[i_best])
    p_d = float(np.sum(post[finite] * (deviance[finite] - d_best)))
    est.extra["p_d"] = p_d
    if m_sum is not None and ur_sum is not None:
        est.extra["material_shift_sd"] = _material_shift(m_sum, ur_sum, post)
    est.extra["floor_mass"] = {
        i.diameter_m: float(np.sum(post * g.floor_weight))
        for i, g in zip(items, grids, strict=True) if not i.hidden}
    # per seen size resting on floor cells: the posterior probability that its TOF and ARR are
    # explained without the floor nodes' looseness (their chi^2 within the 1e-3 tail)
    est.extra["strict_explained"] = {}
    for item, g in zip(items, grids, strict=True):
        if item.hidden or est.extra["floor_mass"][item.diameter_m] < MIN_FLOOR_MASS:
            continue
        factor, offset, f_std, o_std = calibration_along(cal, g.diameter_m, g.distance_m[None, :])
        s_tof, s_arr = item.sigmas()
        strict = ((item.tof_s - offset - g.tof_s) ** 2
                  / (s_tof**2 + o_std**2 + g.model_tof_var_strict)
                  + (item.arr - factor * g.arr) ** 2
                  / (s_arr**2 + factor**2 * g.model_arr_var_strict + (f_std * g.arr) ** 2))
        est.extra["strict_explained"][item.diameter_m] = float(
            np.sum(post[strict <= _chi2_limit_at(2, 1e-3)]))
    if return_posterior:
        est.posterior = {"thickness_m": g0.thickness_m, "distance_m": g0.distance_m,
                         "density": post}
    return est


_UPPER = ((0, 0), (0, 1), (1, 1))


def _solve2(m3: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``b^T (I + M)^-1 b`` and ``log det (I + M)`` per cell, for M symmetric positive
    semi-definite given by its three upper entries (:data:`_UPPER`, first axis; ``b`` likewise
    component first), in closed form."""
    a00, a01, a11 = m3
    a00 = a00 + 1.0
    a11 = a11 + 1.0
    det = a00 * a11 - a01 * a01
    b0, b1 = b
    quad = (a11 * b0 * b0 - 2.0 * a01 * b0 * b1 + a00 * b1 * b1) / det
    return quad, np.log(det)


def _material_shift(m3: np.ndarray, b: np.ndarray, post: np.ndarray) -> list[float]:
    """The posterior mean of the plate material's departure from the table's, in its spread's
    standard deviations along ``(d ln E', d ln rho)``: per cell ``(I + M)^-1 b`` (the Gaussian
    material term's own posterior mean, M and b as in :func:`_solve2`), averaged over the
    posterior. Two or more in E' means the data fit a plate at the edge of the grade's range."""
    # the cells that carry the posterior (a billionth of its peak and up) decide the mean
    cells = np.flatnonzero(post.ravel() > 1e-9 * float(post.max()))
    a00, a01, a11 = (m.ravel()[cells] for m in m3)
    a00 = a00 + 1.0
    a11 = a11 + 1.0
    det = a00 * a11 - a01 * a01
    b0, b1 = (v.ravel()[cells] for v in b)
    w = post.ravel()[cells] / det
    return [float(np.dot(w, a11 * b0 - a01 * b1)), float(np.dot(w, a00 * b1 - a01 * b0))]


def _bilinear2(m3: np.ndarray, v: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``v^T (I + M)^-1 w`` per cell, M as in :func:`_solve2`."""
    a00, a01, a11 = m3
    a00 = a00 + 1.0
    a11 = a11 + 1.0
    det = a00 * a11 - a01 * a01
    return (a11 * v[0] * w[0] - a01 * (v[0] * w[1] + v[1] * w[0]) + a00 * v[1] * w[1]) / det


def _normal_cdf(z: np.ndarray) -> np.ndarray:
    """Phi(z), vectorised (scipy's ndtr)."""
    from scipy.special import ndtr

    return ndtr(z)


def cell_likelihood(table: ModelTable, inputs: Sequence[FeatureSummary | Mapping[str, Any]],
                    calibration: Calibration | Mapping[str, Any] | None = None, *,
                    material_spread: Mapping[str, float] | None = None,
                    shared_calibration: bool = False) -> dict[str, Any]:
    """The likelihood :func:`invert` puts on every fine (t, L) cell for exactly these sphere
    sizes (no size left out), for a plate's joint map (instrument.inference.joint_map): one
    likelihood, not a second one. ``deviance`` is -2 log L (inf where the model has no
    reflection), ``misfit`` the chi^2 that ``fit`` reports, ``grid`` the first size's
    :class:`FineGrid` (axes and prior weights), ``n_terms`` the terms counted.

    ``shared_calibration``: the TOF offsets' uncertainty is not in ``deviance`` and ``misfit``
    (they hold at the stated offsets); instead ``shared`` lists the errors
    ``(diameter_m, "tof_offset_s", sd)`` with a stated sd, and
    ``shared_b`` (errors, t, L) and ``shared_q`` (errors, errors, t, L) give the deviance at
    errors ``eta``: ``deviance - 2 b.eta + eta^T Q eta`` (likewise ``misfit``)."""
    from solitonde.instrument.inference.material_spread import spread_of

    keep: dict[str, Any] = {}
    spread = dict(spread_of(table) if material_spread is None else material_spread)
    _invert_items(table, [FeatureSummary.from_any(i) for i in inputs],
                  Calibration.from_any(calibration), False, spread, keep, shared_calibration)
    return keep


summarise_marginal = _summarise
"""A marginal posterior's MAP, median, intervals and status, by the rules of :func:`invert`."""

__all__ = ["Estimate", "FeatureSummary", "InversionError", "ParameterEstimate", "TableError",
           "cell_likelihood", "fine_grid", "invert", "predict", "summarise_marginal"]
