"""A table's features on the inversion's fine (log t, L) grid, and the model's (TOF, ARR) at one
point read the same way.

The table's features, with each row's near-support plate at its far-field plate's level
(:mod:`.tier_match`), are interpolated in log t and in L (the axes along which TOF and ARR vary
smoothly) once per table and sphere size: linearly, but TOF along thickness by a cubic spline
where no support is in reach (:mod:`.thickness_spline`); with them the model error of each cell
(:mod:`.model_error`) and the prior mass of each cell (uniform in log t and in L).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from itertools import pairwise

import numpy as np

from solitonde.instrument.inference.inversion_inputs import InversionError
from solitonde.instrument.inference.model_error import (
    FLOOR_ARR_MAX,
    FLOOR_ARR_REL_STD,
    FLOOR_TOF_REL_STD,
    REFLECTION_D_OVER_T,
    node_variance,
    node_variances,
    single_precision,
)
from solitonde.instrument.inference.thickness_spline import (
    read_columns,
    spline_loo_variance,
    spline_runs,
)
from solitonde.instrument.inference.tier_match import matched_features
from solitonde.instrument.tables.table import STATUS_NO_REFLECTION, STATUS_OK, ModelTable

FINE_THICKNESS_STEPS = 32
"""Fine cells per table interval in thickness (log-uniform within each interval)."""
FINE_DISTANCE_STEP_M = 0.0025
"""Largest fine cell in distance (each table interval is split evenly)."""
FINE_DISTANCE_MIN_STEPS = 5
"""Fewest fine cells per table interval in distance. Next to a support TOF and ARR change fast
with L (a 1.5 mm plate: 27 us and 0.15 in ARR between the nodes 5 and 7.5 mm from the clamp), and
a grid of the nodes alone there placed a plate 6.2 mm from it at 5 or 7.5 mm, where neither fits:
its interval missed it."""


def _refine(nodes: np.ndarray, steps: Callable[[float], int]) -> np.ndarray:
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
    """The model error per cell, rounded to single precision
    (:func:`~.model_error.single_precision`)."""
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

    @functools.cached_property
    def has_floor(self) -> bool:
        """Whether any cell leans on a floor node (else every posterior's weight there is 0)."""
        return bool(np.any(self.floor_weight))

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
    tof_read, arr_read = matched_features(table, i_d)
    tof = np.where(ok, tof_read, 0.0)
    arr = np.where(ok, arr_read, 0.0)
    runs = spline_runs(table, i_d)
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
    tof_var, arr_var = node_variances(table, i_d, tof, arr, ok, has)
    # A cell whose interpolation touches a node without features has none itself.
    touched = (wt > 1e-12).astype(float) @ (~has).astype(float) @ (wl > 1e-12).astype(float).T
    valid = touched == 0
    grid = FineGrid(
        diameter_m=diameter,
        thickness_m=t_f,
        distance_m=l_f,
        tof_s=read_columns(tof, wt, np.log(t_nodes), log_t, runs) @ wl.T,
        arr=wt @ arr @ wl.T,
        valid=valid,
        penalty=np.where(valid, 0.0, np.inf),
        model_tof_var=single_precision(
            wt @ (tof_var + floor * (FLOOR_TOF_REL_STD * tof) ** 2) @ wl.T),
        model_arr_var=single_precision(
            wt @ (arr_var + floor * (FLOOR_ARR_REL_STD * arr) ** 2) @ wl.T),
        model_tof_var_strict=wt @ tof_var @ wl.T,
        model_arr_var_strict=wt @ arr_var @ wl.T,
        weight_t=_cell_widths(log_t),
        weight_l=_cell_widths(l_f),
        floor_weight=wt @ floor @ wl.T,
        reflect_weight=(h := wt @ ok.astype(float) @ wl.T),
        arr_reflecting=np.divide(wt @ np.where(ok, arr_read, 0.0) @ wl.T, h,
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
    log_t = np.array([math.log(thickness_m)])
    wt = _interp_matrix(np.log(t_nodes), log_t)
    wl = _interp_matrix(l_nodes, np.array([distance_m]))
    ok = table.status[i_d] == STATUS_OK
    if ((wt > 1e-12).astype(float) @ (~ok).astype(float) @ (wl > 1e-12).astype(float).T)[0, 0]:
        raise InversionError("thickness_m", "the model detects no reflection next to this point")
    tof_read, arr_read = matched_features(table, i_d)
    tof_n = np.where(ok, tof_read, 0.0)
    arr_n = np.where(ok, arr_read, 0.0)
    runs = spline_runs(table, i_d)
    tof = float((read_columns(tof_n, wt, np.log(t_nodes), log_t, runs) @ wl.T)[0, 0])
    arr = float((wt @ arr_n @ wl.T)[0, 0])
    if not with_error:
        return tof, arr
    ct, cl = np.log(t_nodes), l_nodes
    tof_var = node_variance(tof_n, ok, ct, cl, spline_loo_variance(tof_n, ct, runs))
    arr_var = node_variance(arr_n, ok, ct, cl)
    if table.model_variance is not None:
        tof_var = tof_var + np.where(ok, table.model_variance["tof_s"][i_d], 0.0)
        arr_var = arr_var + np.where(ok, table.model_variance["arr"][i_d], 0.0)
    tof_sd = math.sqrt(float((wt @ tof_var @ wl.T)[0, 0]))
    arr_sd = math.sqrt(float((wt @ arr_var @ wl.T)[0, 0]))
    return tof, arr, tof_sd, arr_sd
