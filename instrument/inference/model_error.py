"""The model error the inversion adds to each table node: the table's own interpolation error
(leave-one-out, of the spline where TOF is read by one), the 2-D plate's error against the 3-D
plate where a node was simulated on it, a variance the table carries (e.g. a fitted damping's),
and the looseness of the floor nodes beyond :data:`REFLECTION_D_OVER_T`, whose "reflection" is a
train at the detection floor."""

from __future__ import annotations

import numpy as np

from solitonde.instrument.inference.thickness_spline import spline_loo_variance, spline_runs
from solitonde.instrument.tables.table import ModelTable

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
there fell to 0.2-1 % of ARR, under this. Checked on validation draws measured on both plates
(one shot each, the same noise; the 3-D plate meshed by the flexural-wavelength rule), they
differ by 0.14-0.25 % rms in TOF and 0.8-1.9 % in ARR within 60 mm of the clamp; the bundled
scan, simulated on the 3-D plate, read ARR 0.9-2.4 % above the table at 8-25 mm (its mesh is
not the cause: at 12 and 25 mm its ARR is within 0.2 % of finer meshes'). Far from the
supports the table's dashpot is calibrated on reference plates of its own tier, which takes up
its error there."""
MINDLIN_PLATE_MODELS = ("mindlin", "mindlin_greens")
"""The tiers :data:`PLATE_THEORY_TOF_REL_STD` applies to."""


def single_precision(values: np.ndarray) -> np.ndarray:
    """``values`` rounded to the nearest single-precision number, kept in double precision.

    The fine grid's model variances and the material's covariance columns are known to a few
    percent; the likelihood's pass streams them as float32 (two thirds of its bytes, which bound
    it), and rounding them here, where they are made, puts every path (compiled, numpy, the
    hidden sizes' bounds, the joint maps) on the same numbers. The rounding moves a value by at
    most 3e-8 of itself."""
    return values.astype(np.float32).astype(np.float64)


def node_variance(values: np.ndarray, valid: np.ndarray, coord_t: np.ndarray,
                   coord_l: np.ndarray, along_t: np.ndarray | None = None) -> np.ndarray:
    """Variance of the table's interpolation error at each node, from leave-one-out.

    Along each axis, an interior node is predicted linearly from its two neighbours; linear
    interpolation over twice the spacing errs about four times as much as over the spacing
    itself (error ~ h^2 f''), so (LOO error / 4)^2 is the variance there. End nodes take their
    neighbour's value, nodes without valid neighbours the mean over the table; the two axes add.
    Rough regions (near a support, where guided waves make TOF and ARR oscillate with L) so get
    large errors and smooth ones small errors. ``along_t``, where finite, replaces the variance
    along thickness (the spline's, where TOF is read by one: :mod:`.thickness_spline`).
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
        if axis == 0 and along_t is not None:
            e2 = np.where(np.isfinite(along_t), along_t, e2)
        total += np.moveaxis(np.where(np.isfinite(e2), e2, fill), 0, axis)
    return np.where(valid, total, 0.0)


def node_variances(table: ModelTable, i_d: int, tof: np.ndarray, arr: np.ndarray,
                   ok: np.ndarray, has: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The variances of TOF and ARR at each node of sphere size ``i_d`` before the floor's
    looseness: the interpolation error over the nodes with a reflection (``ok``), the 2-D plate's
    error at nodes simulated on it, and the table's own variance at nodes with features
    (``has``: measured, or filled in at the floor)."""
    t_nodes, l_nodes = table.axes["thickness_m"], table.axes["distance_m"]
    two_d = table.simulated_on(i_d, MINDLIN_PLATE_MODELS)
    log_t = np.log(t_nodes)
    along_t = spline_loo_variance(tof, log_t, spline_runs(table, i_d))
    tof_var = (node_variance(tof, ok, log_t, l_nodes, along_t)
               + np.where(two_d, (PLATE_THEORY_TOF_REL_STD * tof) ** 2, 0.0))
    arr_var = (node_variance(arr, ok, log_t, l_nodes)
               + np.where(two_d, (PLATE_THEORY_ARR_REL_STD * arr) ** 2, 0.0))
    if table.model_variance is not None:  # e.g. a fitted damping's uncertainty
        tof_var = tof_var + np.where(has, table.model_variance["tof_s"][i_d], 0.0)
        arr_var = arr_var + np.where(has, table.model_variance["arr"][i_d], 0.0)
    return tof_var, arr_var
