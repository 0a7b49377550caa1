"""TOF read along thickness by a cubic spline where the plate has no support to reflect from.

Far from every support (the table's nodes simulated on the ``infinite`` plate) TOF is a smooth,
convex function of log t. Read linearly between the table's thickness nodes it comes out late
at every point between them (by up to 13 us at D 9.53 mm, t 2.07 mm), the same sign everywhere,
which an error term treated as independent noise cannot represent. A not-a-knot cubic spline in
log t through the same nodes cut that error sevenfold (rms 3.6 to 0.5 us at D 9.53 mm, 0.1 to
0.005 us at 4.76 mm; features simulated between the nodes). Nearer a support the features ripple
with t as the support's reflections come and go, and a spline there did worse than the straight
line (7.0 against 3.8 us rms at L 90 mm), so those columns stay linear. ARR gains nothing from a
spline at the size that matters (9.53 mm: 0.63 against 0.67e-3 rms) and stays linear throughout.

The spline is linear in the node values, so it is applied as a weight matrix, like the linear
read, column by column of the table (each distance has its own run of smooth nodes).
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline

from solitonde.instrument.tables.table import STATUS_OK, ModelTable

SMOOTH_PLATE_MODELS = ("infinite",)
"""Plate tiers whose features are smooth in log t: a plate with no support in reach."""
SPLINE_MIN_NODES = 5
"""Fewest consecutive smooth nodes a column needs for the spline (its leave-one-out needs four
left after one is dropped)."""
SPLINE_LOO_DIVISOR = 6.0
"""Leave-one-out error over the interpolation error between the nodes, for the spline. Measured
between the nodes at D 9.53 mm, (rms error / (LOO / 8)) was 1.17, at 4.76 mm 0.67; theory for a
smooth function (h^4) says 16, which understated the error 2.4-fold: the table's features carry
a detection jitter the spline passes through. 6 states the larger of the two measured errors
with a little to spare (rms error / stated sd 0.88)."""


def spline_runs(table: ModelTable, i_d: int) -> np.ndarray:
    """For each distance column of sphere size ``i_d``: ``(start, stop)``, the longest run of
    consecutive thickness nodes simulated on a smooth tier with a reflection, or ``(0, 0)`` where
    none reaches :data:`SPLINE_MIN_NODES`. Shape (n_l, 2); kept on the table."""
    key = f"spline_runs:{i_d}"
    if (cached := table._cache.get(key)) is not None:
        return cached
    smooth = table.simulated_on(i_d, SMOOTH_PLATE_MODELS) & (table.status[i_d] == STATUS_OK)
    runs = np.zeros((smooth.shape[1], 2), dtype=int)
    for j in range(smooth.shape[1]):
        best, start = (0, 0), None
        for i, flag in enumerate([*smooth[:, j], False]):
            if flag and start is None:
                start = i
            elif not flag and start is not None:
                if i - start > best[1] - best[0]:
                    best = (start, i)
                start = None
        if best[1] - best[0] >= SPLINE_MIN_NODES:
            runs[j] = best
    table._cache[key] = runs
    return runs


def spline_weights(log_nodes: np.ndarray, log_x: np.ndarray, start: int, stop: int
                   ) -> np.ndarray:
    """Weights W (len(log_x), len(log_nodes)) of the spline through nodes ``start:stop``, with
    f(x) = W @ f(nodes) for the points inside that run's span; rows outside it are zero."""
    w = np.zeros((log_x.size, log_nodes.size))
    inside = (log_x >= log_nodes[start]) & (log_x <= log_nodes[stop - 1])
    if inside.any():
        basis = CubicSpline(log_nodes[start:stop], np.eye(stop - start), bc_type="not-a-knot")
        w[np.ix_(inside, np.arange(start, stop))] = basis(log_x[inside])
    return w


def read_columns(values: np.ndarray, linear: np.ndarray, log_nodes: np.ndarray,
                 log_x: np.ndarray, runs: np.ndarray) -> np.ndarray:
    """``values`` (n_t, n_l) read at ``log_x`` along thickness, column by column: the linear
    weights ``linear`` (len(log_x), n_t), replaced by the spline's inside each column's run."""
    out = linear @ values
    for (start, stop) in {tuple(r) for r in runs.tolist() if r[1] > r[0]}:
        cols = np.flatnonzero((runs[:, 0] == start) & (runs[:, 1] == stop))
        w = spline_weights(log_nodes, log_x, start, stop)
        inside = w.any(axis=1)
        out[np.ix_(inside, cols)] = w[inside] @ values[:, cols]
    return out


def spline_loo_variance(values: np.ndarray, log_nodes: np.ndarray, runs: np.ndarray
                        ) -> np.ndarray:
    """The spline's interpolation variance along thickness at each node of each run, from
    leave-one-out (over :data:`SPLINE_LOO_DIVISOR`); a run's end nodes take their neighbour's,
    nodes outside a run NaN."""
    var = np.full(values.shape, np.nan)
    for j, (start, stop) in enumerate(runs.tolist()):
        if stop <= start:
            continue
        x, v = log_nodes[start:stop], values[start:stop, j]
        e2 = np.empty(x.size)
        for i in range(1, x.size - 1):
            keep = np.arange(x.size) != i
            e2[i] = ((v[i] - float(CubicSpline(x[keep], v[keep])(x[i]))) / SPLINE_LOO_DIVISOR) ** 2
        e2[0], e2[-1] = e2[1], e2[-2]
        var[start:stop, j] = e2
    return var
