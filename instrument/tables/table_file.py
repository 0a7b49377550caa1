"""A model table's file while it is built: its layout, one plate's points written with their
``done`` mask, the plates still pending, and the provenance recorded once it is complete.

Points come in as :class:`PointRecord` (one simulated and measured grid point) grouped by plate
in a :class:`PlateResult`; only the process that builds the table writes the file.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, TypedDict

import h5py
import numpy as np

from solitonde.instrument.tables.measured import PRETRIGGER_FRACTION, detect_options
from solitonde.instrument.tables.sweep import Sweep
from solitonde.instrument.tables.table import (
    AXES,
    FORMAT,
    FORMAT_VERSION,
    MAX_SECONDARY,
    PLATE_MODEL_NAMES,
    SCALAR_FEATURES,
    SECONDARY_FEATURES,
    STATUS_PENDING,
    Session,
    TableError,
    TableProvenance,
    reading_version_of,
)
from solitonde.signal.features import EXTRACTOR_VERSION
from solitonde.signal.pulses import FLAGS


class PointRecord(TypedDict):
    """One grid point as written to the table: its features (NaN where not read), status, flag
    bits, error text, plate model, diagnostics, and the sensor trace when traces are kept."""

    tof_s: float
    arr: float
    incident_time_s: float
    incident_peak_N: float
    reflected_peak_N: float
    snr_db: float
    arr_upper_bound: float
    secondary_times_s: list[float]
    secondary_ratios: list[float]
    flags: int
    error: str
    plate_model: str
    wall_s: float
    energy_drift: float
    dt_s: float
    mesh: dict[str, Any] | None
    """The plate mesh's description (simulation diagnostics, free-form)."""
    trace: tuple[float, float, np.ndarray] | None
    """``(t0_s, dt_s, samples)``, or None when traces are not kept."""
    status: int


class PlateResult(TypedDict):
    """One task's answer: the points of plate ``(i_t, i_l)`` by sphere-size index, and how many
    plate responses the task computed."""

    i_t: int
    i_l: int
    points: dict[int, PointRecord]
    greens_computed: int


def partial_path(out: Path) -> Path:
    """Where a table is built until it is complete: ``<out>.partial``."""
    return out.with_name(out.name + ".partial")


def create(fh: h5py.File, sweep: Sweep) -> None:
    """Lay out an empty table for ``sweep`` in a new file: attributes, axes, every dataset
    filled with its pending value."""
    shape = sweep.shape
    fh.attrs["format"] = FORMAT
    fh.attrs["format_version"] = FORMAT_VERSION
    fh.attrs["reading_version"] = EXTRACTOR_VERSION
    fh.attrs["sweep"] = json.dumps(sweep.to_dict(), sort_keys=True)
    # The chain's options every point was measured with (the reflection's travel gate, the
    # solitary wave's width law), per sphere size: what a measured shot of that size gets too.
    fh.attrs["chain_options"] = json.dumps(
        {f"{d:.6g}": detect_options(sweep.scene_at(i, 0, 0))
         for i, d in enumerate(sweep.diameters_m)}, sort_keys=True)
    fh.attrs["complete"] = False
    fh.attrs["flag_names"] = json.dumps(list(FLAGS))
    fh.attrs["plate_model_names"] = json.dumps(list(PLATE_MODEL_NAMES))
    fh.attrs["build_wall_s"] = 0.0
    axes = fh.create_group("axes")
    for name, values in zip(AXES, (sweep.diameters_m, sweep.thicknesses_m, sweep.distances_m),
                            strict=True):
        axes.create_dataset(name, data=np.asarray(values, dtype=float))
    feats = fh.create_group("features")
    for k in SCALAR_FEATURES:
        feats.create_dataset(k, shape=shape, dtype="f8", fillvalue=np.nan)
    for series in SECONDARY_FEATURES:
        feats.create_dataset(series, shape=(*shape, MAX_SECONDARY), dtype="f8", fillvalue=np.nan)
    fh.create_dataset("status", shape=shape, dtype="i1", fillvalue=STATUS_PENDING)
    fh.create_dataset("done", shape=shape, dtype="bool", fillvalue=False)
    fh.create_dataset("flags", shape=shape, dtype="i4", fillvalue=0)
    fh.create_dataset("plate_model", shape=shape, dtype="i1",
                      fillvalue=PLATE_MODEL_NAMES.index("unknown"))
    fh.create_dataset("messages", shape=shape, dtype=h5py.string_dtype(), fillvalue="")
    diag = fh.create_group("diagnostics")
    for name in ("wall_s", "energy_drift", "dt_s"):
        diag.create_dataset(name, shape=shape, dtype="f8", fillvalue=np.nan)
    if sweep.traces:
        tr = fh.create_group("traces")
        tr.create_dataset("samples", shape=shape, dtype=h5py.vlen_dtype(np.float64))
        tr.create_dataset("t0_s", shape=shape, dtype="f8", fillvalue=np.nan)
        tr.create_dataset("dt_s", shape=shape, dtype="f8", fillvalue=np.nan)


def write_plate(fh: h5py.File, result: PlateResult) -> int:
    """Write one task's points and mark them done; returns the number of points."""
    i_t, i_l = int(result["i_t"]), int(result["i_l"])
    for i_d, rec in result["points"].items():
        ix = (int(i_d), i_t, i_l)
        for k in SCALAR_FEATURES:
            fh["features"][k][ix] = rec[k]
        for series in SECONDARY_FEATURES:
            fh["features"][series][ix] = np.asarray(rec[series], dtype=float)
        fh["status"][ix] = rec["status"]
        fh["flags"][ix] = rec["flags"]
        model = rec["plate_model"]
        fh["plate_model"][ix] = PLATE_MODEL_NAMES.index(model if model in PLATE_MODEL_NAMES
                                                        else "unknown")
        fh["messages"][ix] = rec["error"]
        fh["diagnostics"]["wall_s"][ix] = rec["wall_s"]
        fh["diagnostics"]["energy_drift"][ix] = rec["energy_drift"]
        fh["diagnostics"]["dt_s"][ix] = rec["dt_s"]
        trace = rec.get("trace")
        if trace is not None and "traces" in fh:
            t0, dt, samples = trace
            fh["traces"]["samples"][ix] = samples
            fh["traces"]["t0_s"][ix] = t0
            fh["traces"]["dt_s"][ix] = dt
        if rec.get("mesh") and "mesh" not in fh.attrs:
            fh.attrs["mesh"] = json.dumps(rec["mesh"])
        fh["done"][ix] = True
    fh.flush()
    return len(result["points"])


def git_revision() -> str | None:
    """The source tree's git commit now (``+dirty`` when modified), or None; a build records it
    when each session starts, since the tree may change while it runs."""
    root = Path(__file__).resolve().parents[2]  # the checkout: instrument/tables/ is two down
    try:
        rev = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True,
                             text=True, timeout=5, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain",
                                "--untracked-files=no"], capture_output=True, text=True,
                               timeout=10, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return rev + ("+dirty" if dirty else "") if rev else None


def solitonde_version() -> str:
    """This software's version (:func:`solitonde.model.version.package_version`)."""
    from solitonde.model.version import package_version

    return package_version()


def provenance(fh: h5py.File, sweep: Sweep, runner: str, command: str | None,
               table_id: str | None = None) -> TableProvenance:
    """How, where and from what code a complete table was built (the attribute ``provenance``:
    metadata, free-form JSON that later versions may extend)."""
    models = np.unique(fh["plate_model"][...])
    dt = fh["diagnostics"]["dt_s"][...]
    return {
        "solitonde_version": solitonde_version(),
        "git_revision": git_revision(),
        "sessions": json.loads(fh.attrs.get("sessions", "[]")),
        "built_at": datetime.now(UTC).isoformat(timespec="seconds"),
        "build_wall_s": float(fh.attrs["build_wall_s"]),
        "point_cpu_s": float(np.nansum(fh["diagnostics"]["wall_s"][...])),
        "runner": runner,
        "command": command,
        "machine": {"node": platform.node(), "system": platform.platform(),
                    "processor": platform.processor() or platform.machine(),
                    "cpus": os.cpu_count(), "python": platform.python_version()},
        "scene_defaults": sweep.base_scene().to_dict(),
        **({"table_id": table_id} if table_id else {}),
        "tiers": [PLATE_MODEL_NAMES[int(m)] for m in models],
        "mesh": json.loads(fh.attrs["mesh"]) if "mesh" in fh.attrs else None,
        "step_s": {"min": float(np.nanmin(dt)), "max": float(np.nanmax(dt))}
        if np.isfinite(dt).any() else None,
        "pretrigger_fraction": PRETRIGGER_FRACTION,
        "feature_extractor": "solitonde.signal.features.extract",
    }


def pending(fh: h5py.File, sweep: Sweep) -> list[tuple[int, int, list[int]]]:
    """The plates still to run, in :meth:`Sweep.groups` order, each with its sphere sizes not
    yet done: ``(i_t, i_l, [i_d, ...])``."""
    done = fh["done"][...]
    out = []
    for i_t, i_l in sweep.groups():
        todo = [i for i in range(done.shape[0]) if not done[i, i_t, i_l]]
        if todo:
            out.append((i_t, i_l, todo))
    return out


def check_partial(part: Path, sweep: Sweep) -> None:
    """Refuse to resume from ``part`` unless it is an interrupted build of ``sweep`` read with
    this extractor's reading (the file is left as it is).

    Raises
    ------
    TableError
        When ``part`` is not HDF5, holds no table build, or holds a build of another sweep or
        another reading.
    """
    not_ours = (f"{str(part)!r} exists but is not an interrupted table build ({{}}); it is "
                "left as it is: delete it (or move it away) to start the build afresh")
    try:
        with h5py.File(part, "r") as fh:
            ours = fh.attrs.get("format") == FORMAT and "done" in fh
            stored = json.loads(fh.attrs.get("sweep", "null")) if ours else None
            reading = reading_version_of(fh) if ours else EXTRACTOR_VERSION
    except (OSError, ValueError) as exc:  # not HDF5 (empty, garbage, truncated); bad JSON
        raise TableError("partial", not_ours.format(exc)) from None
    if not ours:
        raise TableError("partial", not_ours.format("an HDF5 file without a solitonde "
                                                    "table build in it"))
    if stored != json.loads(json.dumps(sweep.to_dict(), sort_keys=True)):
        raise TableError("sweep", f"{str(part)!r} holds an interrupted build of another sweep; "
                         "rerun with the same grid and scene to resume, or delete it")
    if reading != EXTRACTOR_VERSION:
        raise TableError("partial", f"{str(part)!r} holds points read with the extractor's "
                         f"reading {reading}, this solitonde reads with {EXTRACTOR_VERSION}: "
                         "one table holds one reading; delete it to start the build afresh")


def start_session(fh: h5py.File, runner: str) -> None:
    """Record the session starting now with the code that computes its points (a resumed build
    may span revisions)."""
    sessions: list[Session] = json.loads(fh.attrs.get("sessions", "[]"))
    sessions.append({"started_at": datetime.now(UTC).isoformat(timespec="seconds"),
                     "git_revision": git_revision(), "runner": runner,
                     "points_done_before": int(fh["done"][...].sum())})
    fh.attrs["sessions"] = json.dumps(sessions)
