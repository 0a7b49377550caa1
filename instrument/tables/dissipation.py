"""The table's dissipation layer: the same sweep simulated with contact damping.

The table's model is elastic; real chains lose energy (contact damping, plasticity, friction), so
a measured reflection is weaker than the model's and, where the plate is thin, arrives at
another time. How much weaker is not one factor: with Kuwabara-Kono damping (tau = 1e-7 s, the
synthetic studies' chain) ARR falls by 7.7 % on a 5.5 mm aluminium plate far from the supports,
by 2-5 % on 2.4-3.0 mm plates, by 8 % within 20 mm of a clamp, and a thin plate's reflection
moves by up to tens of microseconds (docs/explanation/inversion.md, "Dissipation"). A calibration
that scales the elastic model by one ARR factor cannot follow that; runs of the model with damping
can.

The layer is the table's sweep simulated again with ``effects.dissipation`` on, at a few
Kuwabara-Kono time constants (:data:`DEFAULT_DAMPINGS_S`), stored in the table file as the group
``dissipation`` (attribute ``damping_s``, the time constants; datasets ``tof_s``, ``arr``,
``arr_upper_bound`` and ``status``, each shaped ``(K,) + the table's shape``). A calibration fits
the chain's own tau on reference plates (instrument.inference.calibration_fit), and the inversion
reads the table at it (:func:`damped`), piecewise linear in tau between the elastic table
(tau = 0) and the slices, per node.

Linear in tau holds while the loss is small and the reflection one pulse. Where the reflection is
weak (a thin plate far from the supports: a train whose largest peak can change with the damping)
it does not: on a 2.64 mm aluminium plate far out ARR falls by 1.5, 3.4, 10.7 and 13.2 % at tau
= 0.5, 1, 1.5 and 2 x 1e-7 s, and on a 3.3 mm plate 100 mm from a clamp by 5.6, 6.4 and 15.1 %
at 0.7, 1 and 2 x 1e-7 s. So a read between two slices carries as error the larger of the
segment's bend as its inner slices show it (how far a slice lies off the straight line through
its neighbours, ``d``, read as a quadratic's error mid-segment: ``d h^2 / (4 h_l h_r)``, h the
segment's width and h_l, h_r the slice's two segments) and the spread of a value anywhere
between the two slices (``|F_hi - F_lo| / sqrt 12``) times ``sqrt(1 - ARR)`` (the elastic
table's ARR at the node), times ``4 u (1 - u)``, u the read's place within its segment (all of
it mid-segment, none on a slice). A strong reflection is the incident wave turned back, and its
loss is smooth in tau. With the slices at 0.7, 1.2 and 2 x 1e-7 s, against the model run at 0.85
and 1.35 x 1e-7 s at 44 random points (D 9.53 mm, t 1.9-6 mm, L 3-450 mm), the read's misses in
units of its stated error (with the elastic table's interpolation error) had an rms of 0.91 in
ARR and 0.74 in TOF, the largest 2.2 (one point in 44 each); without the uniform spread they
were 1.57 and 0.98, the largest 4.4 (docs/explanation/inversion.md, "Dissipation"). The fitted tau's
uncertainty adds ``(sd_tau * dF/dtau)^2``. A node where a slice lost the reflection the elastic
table has takes the relative loss of its row's nearest node with both, all of it as error.

``table build --dissipation-layer TAU`` (repeatable) writes the layer; ``table dissipation FILE``
adds slices to a table built before, simulated or taken from tables built with the same sweep
and ``--set effects.dissipation=true --set effects.damping=TAU``.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from solitonde.instrument.tables.sweep import damped_scene
from solitonde.instrument.tables.table import (
    LAYER,
    LAYER_FEATURES,
    STATUS_OK,
    DissipationLayer,
    ModelTable,
    TableError,
    add_to_file,
    read_layer,
    require_complete,
)
from solitonde.model.scene import SceneDict

DEFAULT_DAMPINGS_S = (7e-8, 1.2e-7, 2e-7)
"""The slices' Kuwabara-Kono time constants, s, spaced about evenly in ln tau: chains losing up
to about 15 % of a thick plate's ARR are read between slices (the synthetic studies' chain,
1e-7 s, on none of them), and each inner slice measures how far the loss departs from a straight
line in tau."""
MAX_VIEWS = 4
"""Tables read at a damping kept per table (the calibrations in use), least recently used
dropped first."""


def write_layer(fh: h5py.File, layer: DissipationLayer) -> None:
    """Store ``layer`` in an open table file (replacing any there)."""
    if LAYER in fh:
        del fh[LAYER]
    group = fh.create_group(LAYER)
    group.attrs["damping_s"] = np.asarray(layer.damping_s, dtype=float)
    group.attrs["damping_model"] = "kuwabara-kono"
    for name, values in layer.features.items():
        group.create_dataset(name, data=np.asarray(values, dtype=float))
    group.create_dataset("status", data=np.asarray(layer.status, dtype=np.int8))


def _undamped(scene: Mapping[str, Any]) -> SceneDict:
    data: SceneDict = json.loads(json.dumps(dict(scene)))
    effects = data.get("effects") or {}
    effects.pop("dissipation", None)
    effects.pop("damping", None)
    if "effects" in data and not effects:
        del data["effects"]
    return data


def layer_from_table(table: ModelTable, damped_table: ModelTable) -> DissipationLayer:
    """One slice taken from ``damped_table``: a complete table of the same sweep as ``table`` but
    with ``effects.dissipation`` on. TableError (naming what differs) otherwise."""
    if not damped_table.complete:
        raise TableError("source", "the damped table is not complete")
    mine, theirs = table.sweep, damped_table.sweep
    effects = (theirs.get("scene") or {}).get("effects") or {}
    if not effects.get("dissipation"):
        raise TableError("source", "the damped table was built without effects.dissipation")
    for key in ("diameters_m", "thicknesses_m", "distances_m", "detect", "traces"):
        if mine.get(key) != theirs.get(key):
            raise TableError(f"source.{key}", "differs from the table's sweep")
    if _undamped(mine.get("scene") or {}) != _undamped(theirs.get("scene") or {}):
        raise TableError("source.scene", "the damped table's scene differs from the table's in "
                         "more than effects.dissipation and effects.damping")
    if damped_table.reading_version != table.reading_version:
        raise TableError("source.reading_version", f"the damped table's points were read with "
                         f"the extractor's reading {damped_table.reading_version}, the table's "
                         f"with {table.reading_version}: rebuild the table with its layer "
                         "(`table build --dissipation-layer TAU`)")
    return DissipationLayer((float(effects.get("damping", 0.0)),),
                            {k: np.array(damped_table.features[k])[None] for k in LAYER_FEATURES},
                            np.array(damped_table.status)[None])


def simulate_layer(table: ModelTable, damping_s: float, out_dir: Path, *,
                   workers: int | None = None, progress: bool = False,
                   scheduler: str | None = None,
                   responses: str | Path | bool = True) -> tuple[DissipationLayer, Path]:
    """Simulate ``table``'s sweep with damping ``damping_s`` (a table build into ``out_dir``
    named ``<stem>.damped-<tau>.h5``: an interrupted run resumes from its ``.partial``) and return
    it as a one-slice layer, with the damped table's path. The damping acts in the chain: the
    plates' responses are the elastic sweep's, read from the response store ``responses`` where
    it holds them (:func:`~.table_build.build_table`)."""
    from solitonde.instrument.tables.sweep import Sweep
    from solitonde.instrument.tables.table_build import build_table

    sweep = Sweep.from_dict(table.sweep)
    damped_sweep = dataclasses.replace(sweep, scene=damped_scene(sweep.scene, damping_s))
    stem = table.path.stem if table.path else "table"
    target = out_dir / f"{stem}.damped-{damping_s:g}.h5"
    report = build_table(damped_sweep, target, workers=workers, scheduler=scheduler,
                         progress=progress, responses=responses, slopes=False)
    if not report.complete:
        raise TableError("dissipation", f"the damped sweep did not finish ({report.path})")
    return layer_from_table(table, ModelTable.load(target)), target


def add_to_table(path: str | Path, layer: DissipationLayer) -> DissipationLayer:
    """Add ``layer``'s slices to the table at ``path`` (merged with any it has): on a copy,
    renamed onto the file only once written and read back, so an interrupted run leaves the
    table as it was. Returns the table's layer as written."""
    require_complete(path)
    table = ModelTable.load(path)
    full = layer if table.dissipation is None else table.dissipation.merged(layer)
    add_to_file(path, ".dissipation", lambda fh: write_layer(fh, full),
                lambda fh: read_layer(fh, table.shape))
    return full


# Reading the table at a damping -------------------------------------------------------------


def _slices(table: ModelTable, layer: DissipationLayer, name: str) -> tuple[np.ndarray, ...]:
    """Feature ``name`` at tau = 0 and at every slice, shape ``(K + 1,) + table``, and where
    each node lost its reflection in a slice that the elastic table has (same shape)."""
    base = table.features[name]
    out = [base]
    lost = [np.zeros(base.shape, dtype=bool)]
    ok0 = table.status == STATUS_OK
    for k in range(len(layer.damping_s)):
        both = ok0 & (layer.status[k] == STATUS_OK)
        values = layer.features[name][k]
        if name == "arr_upper_bound":  # a bound where both have one, else the elastic one
            out.append(np.where(np.isfinite(values) & np.isfinite(base), values, base))
            lost.append(np.zeros(base.shape, dtype=bool))
            continue
        delta = np.where(both, values - base, np.nan)
        if name == "arr":
            rel = np.where(both & (base > 0), delta / np.where(base > 0, base, 1.0), np.nan)
            rel = _fill_along_distance(rel, table.axes["distance_m"])
            delta = np.where(np.isnan(delta), rel * base, delta)
        out.append(np.where(np.isfinite(base), base + np.nan_to_num(delta), base))
        lost.append(~both & np.isfinite(base))
    return np.stack(out), np.stack(lost)


def _segment(nodes: np.ndarray, tau: float) -> tuple[int, float]:
    """The segment ``j`` (between nodes j and j + 1) holding ``tau`` and its place ``u`` in it
    (beyond the last node: the last segment, u > 1)."""
    j = int(np.clip(np.searchsorted(nodes, tau, side="right") - 1, 0, nodes.size - 2))
    return j, (tau - nodes[j]) / (nodes[j + 1] - nodes[j])


def _departures(nodes: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Per node (first axis), how far it lies off the straight line through its neighbours;
    0 at both ends."""
    dev = np.zeros_like(values)
    for k in range(1, nodes.size - 1):
        w = (nodes[k] - nodes[k - 1]) / (nodes[k + 1] - nodes[k - 1])
        dev[k] = values[k] - ((1 - w) * values[k - 1] + w * values[k + 1])
    return np.nan_to_num(dev)


def _bend_scale(nodes: np.ndarray, j: int, k: int) -> float:
    """How node ``k``'s departure (:func:`_departures`) reads as the error mid-segment ``j``,
    were the feature quadratic in tau: a departure ``f'' h_l h_r / 2`` over the node's two
    segments, an error ``f'' h_j^2 / 8`` mid-segment, so ``h_j^2 / (4 h_l h_r)``; 0 at an end."""
    if not 0 < k < nodes.size - 1:
        return 0.0
    h_j = nodes[j + 1] - nodes[j]
    return float(h_j**2 / (4.0 * (nodes[k] - nodes[k - 1]) * (nodes[k + 1] - nodes[k])))


def _read(table: ModelTable, layer: DissipationLayer, damping_s: Sequence[float],
          damping_std_s: Sequence[float]) -> ModelTable:
    nodes = np.concatenate([[0.0], layer.damping_s])
    features = dict(table.features)
    variance: dict[str, np.ndarray] = {}
    # how much of the reflection is the plate's doing: a strong one (ARR near 1) is the incident
    # wave turned back, and its loss is smooth in tau
    weak = np.sqrt(np.clip(1.0 - np.nan_to_num(table.features["arr"], nan=0.0), 0.0, 1.0))
    for name in LAYER_FEATURES:
        values, lost = _slices(table, layer, name)
        dev = np.abs(_departures(nodes, values))
        read = np.array(table.features[name], dtype=float)
        var = np.zeros(read.shape)
        for i_d, (tau, sd) in enumerate(zip(damping_s, damping_std_s, strict=True)):
            j, u = _segment(nodes, float(tau))
            lo, hi = values[j, i_d], values[j + 1, i_d]
            read[i_d] = lo + u * (hi - lo)
            slope = (hi - lo) / (nodes[j + 1] - nodes[j])
            # between slices the read is known no better than its slices' own bend, nor than
            # to somewhere between them (a uniform spread, |hi - lo| / sqrt 12) as far as the
            # reflection is weak
            bend = np.maximum(np.maximum(dev[j, i_d] * _bend_scale(nodes, j, j),
                                         dev[j + 1, i_d] * _bend_scale(nodes, j, j + 1)),
                              np.abs(hi - lo) / math.sqrt(12.0) * weak[i_d]) * (
                4.0 * u * (1.0 - u) if u <= 1.0 else u)
            shift = read[i_d] - table.features[name][i_d]
            gone = (lost[j, i_d] & (u < 1.0)) | (lost[j + 1, i_d] & (u > 0.0))
            var[i_d] = ((sd * slope) ** 2 + bend**2
                        + np.where(gone, shift**2, 0.0))
        features[name] = np.where(np.isfinite(table.features[name]), read, table.features[name])
        variance[name] = np.nan_to_num(var)
    view = dataclasses.replace(table, features=features,
                               model_variance={k: variance[k] for k in ("tof_s", "arr")},
                               _cache={})
    view._cache["sha256"] = table.content_sha256
    return view


def damped(table: ModelTable, damping_s: Sequence[float], damping_std_s: Sequence[float]
           ) -> ModelTable:
    """The table read at Kuwabara-Kono time constant ``damping_s[i_d]`` per sphere size (with
    its standard deviation; module docstring): a table of its own (its own fine-grid cache,
    ``model_variance`` the read's error), kept on ``table`` per damping (the last
    :data:`MAX_VIEWS`).

    Raises
    ------
    TableError
        (field ``dissipation``) When the table has no dissipation layer.
    """
    layer: DissipationLayer | None = table.dissipation
    if layer is None:
        raise TableError("dissipation", f"table {table.table_id!r} has no dissipation layer "
                         "(`solitonde table dissipation FILE` adds one)")
    key = (tuple(np.round(np.asarray(damping_s, dtype=float) * 1e12, 6)),
           tuple(np.round(np.asarray(damping_std_s, dtype=float) * 1e12, 6)))
    views: OrderedDict[Any, ModelTable] = table._cache.setdefault("damped_views", OrderedDict())
    cached = views.get(key)
    if cached is not None:
        views.move_to_end(key)
        return cached
    view = _read(table, layer, damping_s, damping_std_s)
    views[key] = view
    while len(views) > MAX_VIEWS:  # each holds its own fine grids (megabytes per sphere size)
        views.popitem(last=False)
    return view


def slice_reads(table: ModelTable) -> list[ModelTable]:
    """The table read at tau = 0 and at each slice (no error terms), uncached: a calibration
    fit's model at its references, piecewise linear in tau between these."""
    layer = table.dissipation
    if layer is None:
        raise TableError("dissipation", f"table {table.table_id!r} has no dissipation layer")
    n_d = table.shape[0]
    return [_read(table, layer, [tau] * n_d, [0.0] * n_d) for tau in (0.0, *layer.damping_s)]


def _fill_along_distance(values: np.ndarray, distances: np.ndarray) -> np.ndarray:
    """NaNs replaced, along the last axis, by the nearest finite value in distance (0 where a
    row has none)."""
    out = np.array(values)
    for ix in np.ndindex(values.shape[:-1]):
        row = values[ix]
        good = np.flatnonzero(np.isfinite(row))
        if not good.size:
            out[ix] = np.where(np.isfinite(row), row, 0.0)
            continue
        nearest = good[np.abs(distances[good][None, :] - distances[:, None]).argmin(axis=1)]
        out[ix] = row[nearest]
    return out


__all__ = ["DEFAULT_DAMPINGS_S", "LAYER", "DissipationLayer", "add_to_table", "damped",
           "damped_scene", "layer_from_table", "read_layer", "simulate_layer", "slice_reads",
           "write_layer"]
