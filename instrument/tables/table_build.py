"""Build the model table: a sweep over (D, t, L) simulated in parallel, written by one process.

Work is cut into one task per plate, ``(t, L)``: the Green's function of a plate (the costly
spectral-element run behind the ``greens`` tier) depends on the plate and the chain position but not
on the sphere, so a task simulates every sphere size on its plate, the largest first (the longest
record), and the smaller spheres reuse the prefix of the same response from a task-local cache.
Far from the supports ``auto`` picks the infinite plate and a task costs milliseconds.

Execution: serial in this process (``workers=1``), a Dask ``LocalCluster`` (default: one process
per core, one thread each, numba/BLAS/OpenMP threads capped at 1 in the worker environment), or an
existing Dask cluster (``scheduler='tcp://host:port'``). Whatever runs the tasks, only the driver
writes the file: results stream back, each plate's points are written and flushed together with
their ``done`` mask, so an interrupted build resumes where it stopped. The file is built as
``<out>.partial`` and renamed onto ``<out>`` (``os.replace``) only when complete.
"""

from __future__ import annotations

import copy
import json
import math
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from solitonde.instrument.tables.measured import PRETRIGGER_FRACTION, as_measured, detect_options
from solitonde.instrument.tables.table import (
    AXES,
    FORMAT,
    FORMAT_VERSION,
    MATERIAL_SLOPES,
    MAX_SECONDARY,
    PLATE_MODEL_NAMES,
    SCALAR_FEATURES,
    SECONDARY_FEATURES,
    SLOPE_COMPONENTS,
    STATUS_FAILED,
    STATUS_NO_REFLECTION,
    STATUS_OK,
    STATUS_PENDING,
    TableError,
    reading_version_of,
)
from solitonde.model import greens
from solitonde.model.errors import SceneError, SimulationError
from solitonde.model.greens import GreensCache
from solitonde.model.scene import Scene, apply_overrides, scene_from_dict
from solitonde.model.simulate import SimulationResult, simulate
from solitonde.model.tiers import MESHED_PLATE_MODELS, resolve_plate_model
from solitonde.signal.errors import WaveformError
from solitonde.signal.features import EXTRACTOR_VERSION, Features, extract
from solitonde.signal.pulses import FLAGS

#: Environment of Dask worker processes: one compute thread each (the cores are the workers).
WORKER_ENV = {
    "NUMBA_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
}
#: The paper's sphere sizes (3/16, 3/8, 3/4 in).
PAPER_DIAMETERS_M = (4.76e-3, 9.53e-3, 19.05e-3)


@dataclass
class Sweep:
    """What a table covers: the grid axes and the scene every point starts from.

    Attributes
    ----------
    diameters_m, thicknesses_m, distances_m: grid axes, m (sorted, distinct).
    scene: base scene as a nested dict (any scene keys; the axes override ``chain.diameter``,
        ``plate.thickness``, ``plate.distance_to_support``).
    traces: also store each point's sensor trace.
    detect: options passed to :func:`solitonde.signal.features.extract`.
    """

    diameters_m: list[float]
    thicknesses_m: list[float]
    distances_m: list[float]
    scene: dict[str, Any] = field(default_factory=dict)
    traces: bool = False
    detect: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in ("diameters_m", "thicknesses_m", "distances_m"):
            values = [float(v) for v in getattr(self, name)]
            if not values:
                raise TableError(name, "needs at least one value")
            if any(not math.isfinite(v) or v < 0 for v in values):
                raise TableError(name, f"values must be finite and >= 0, got {values}")
            if len(set(values)) != len(values):
                raise TableError(name, f"values must be distinct, got {values}")
            setattr(self, name, sorted(values))
        if min(self.diameters_m) <= 0 or min(self.thicknesses_m) <= 0:
            raise TableError("diameters_m", "diameters and thicknesses must be > 0")
        self.base_scene()  # validate once, here, naming the bad field

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Sweep:
        return cls(**dict(data))

    @property
    def shape(self) -> tuple[int, int, int]:
        return len(self.diameters_m), len(self.thicknesses_m), len(self.distances_m)

    def base_scene(self) -> Scene:
        return scene_from_dict(self.scene)

    def scene_at(self, i_d: int, i_t: int, i_l: int) -> Scene:
        """The scene of one grid point."""
        data = apply_overrides(self.scene, {
            "chain.diameter": self.diameters_m[i_d],
            "plate.thickness": self.thicknesses_m[i_t],
            "plate.distance_to_support": self.distances_m[i_l],
        })
        return scene_from_dict(data)

    def groups(self) -> list[tuple[int, int]]:
        """Plates ``(i_t, i_l)``, the likely costly (finite-plate, thin) ones first."""
        def cost(key: tuple[int, int]) -> tuple[int, float]:
            i_t, i_l = key
            finite = resolve_plate_model(self.scene_at(len(self.diameters_m) - 1, i_t, i_l))[0]
            return (0 if finite in MESHED_PLATE_MODELS else 1, self.thicknesses_m[i_t])
        keys = [(i, j) for i in range(len(self.thicknesses_m))
                for j in range(len(self.distances_m))]
        return sorted(keys, key=cost)


# One point ----------------------------------------------------------------------------------


def point_record(features: Features | None, result: SimulationResult | None,
                 error: str | None, traces: bool) -> dict[str, Any]:
    """The per-point values written to the table."""
    rec: dict[str, Any] = {k: math.nan for k in SCALAR_FEATURES}
    rec["secondary_times_s"] = [math.nan] * MAX_SECONDARY
    rec["secondary_ratios"] = [math.nan] * MAX_SECONDARY
    rec["flags"] = 0
    rec["error"] = error or ""
    rec["plate_model"] = result.plate_model if result is not None else "unknown"
    rec["wall_s"] = float(result.diagnostics.get("wall_s", math.nan)) if result else math.nan
    rec["energy_drift"] = (float(result.diagnostics.get("energy_drift", math.nan)) if result
                           else math.nan)
    rec["dt_s"] = float(result.diagnostics.get("dt_s", math.nan)) if result else math.nan
    rec["mesh"] = result.diagnostics.get("mesh") if result else None
    rec["trace"] = None
    if traces and result is not None:
        rec["trace"] = (float(result.t0), float(result.dt), np.asarray(result.samples, dtype=float))
    if features is None:
        rec["status"] = STATUS_FAILED
        return rec
    for k in SCALAR_FEATURES:
        value = getattr(features, k)
        rec[k] = math.nan if value is None else float(value)
    for k, src in (("secondary_times_s", features.secondary_times_s),
                   ("secondary_ratios", features.secondary_ratios)):
        vals = list(src)[:MAX_SECONDARY]
        rec[k] = vals + [math.nan] * (MAX_SECONDARY - len(vals))
    rec["flags"] = sum(1 << FLAGS.index(f) for f in features.flags if f in FLAGS)
    ok = features.tof_s is not None and features.arr is not None
    rec["status"] = STATUS_OK if ok else STATUS_NO_REFLECTION
    return rec


def simulate_point(scene: Scene, detect: Mapping[str, Any] | None = None,
                   traces: bool = False, greens_cache: GreensCache | None = None
                   ) -> dict[str, Any]:
    """Simulate one scene and extract its features as from a measurement."""
    try:
        result = simulate(scene, greens_cache=greens_cache)
    except (SimulationError, SceneError) as exc:
        return point_record(None, None, f"simulation: {exc}", traces)
    try:
        features = extract(as_measured(result), **{**detect_options(scene), **dict(detect or {})})
    except WaveformError as exc:
        return point_record(None, result, f"features: {exc}", traces)
    return point_record(features, result, None, traces)


def run_plate(sweep: Mapping[str, Any], i_t: int, i_l: int,
              diameters: Sequence[int] | None = None) -> dict[str, Any]:
    """One task: every sphere size (largest first) on plate ``(i_t, i_l)``.

    One Green's function serves all sizes: the plate step depends on the plate and the sample
    rate only, and the largest sphere's record is the longest, so its response covers the others.
    Returns ``{"i_t", "i_l", "points": {i_d: record}, "greens_computed": n}``.
    """
    spec = Sweep.from_dict(sweep)
    order = sorted(range(len(spec.diameters_m)) if diameters is None else diameters, reverse=True)
    # This task's responses, dropped when it ends; unbounded, so that its size counts them.
    task_cache = greens.MemoryCache(max_bytes=sys.maxsize)
    points = {i_d: simulate_point(spec.scene_at(i_d, i_t, i_l), spec.detect, spec.traces,
                                  task_cache) for i_d in order}
    computed = len(task_cache)
    return {"i_t": i_t, "i_l": i_l, "points": points, "greens_computed": computed}


# The file ----------------------------------------------------------------------------------


def partial_path(out: Path) -> Path:
    return out.with_name(out.name + ".partial")


def _create(fh: h5py.File, sweep: Sweep) -> None:
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
    for k in SECONDARY_FEATURES:
        feats.create_dataset(k, shape=(*shape, MAX_SECONDARY), dtype="f8", fillvalue=np.nan)
    fh.create_dataset("status", shape=shape, dtype="i1", fillvalue=STATUS_PENDING)
    fh.create_dataset("done", shape=shape, dtype="bool", fillvalue=False)
    fh.create_dataset("flags", shape=shape, dtype="i4", fillvalue=0)
    fh.create_dataset("plate_model", shape=shape, dtype="i1",
                      fillvalue=PLATE_MODEL_NAMES.index("unknown"))
    fh.create_dataset("messages", shape=shape, dtype=h5py.string_dtype(), fillvalue="")
    diag = fh.create_group("diagnostics")
    for k in ("wall_s", "energy_drift", "dt_s"):
        diag.create_dataset(k, shape=shape, dtype="f8", fillvalue=np.nan)
    if sweep.traces:
        tr = fh.create_group("traces")
        tr.create_dataset("samples", shape=shape, dtype=h5py.vlen_dtype(np.float64))
        tr.create_dataset("t0_s", shape=shape, dtype="f8", fillvalue=np.nan)
        tr.create_dataset("dt_s", shape=shape, dtype="f8", fillvalue=np.nan)


def _write_plate(fh: h5py.File, result: Mapping[str, Any]) -> int:
    """Write one task's points and mark them done; returns the number of points."""
    i_t, i_l = int(result["i_t"]), int(result["i_l"])
    for i_d, rec in result["points"].items():
        ix = (int(i_d), i_t, i_l)
        for k in SCALAR_FEATURES:
            fh["features"][k][ix] = rec[k]
        for k in SECONDARY_FEATURES:
            fh["features"][k][ix] = np.asarray(rec[k], dtype=float)
        fh["status"][ix] = rec["status"]
        fh["flags"][ix] = rec["flags"]
        name = rec["plate_model"]
        fh["plate_model"][ix] = PLATE_MODEL_NAMES.index(name if name in PLATE_MODEL_NAMES
                                                        else "unknown")
        fh["messages"][ix] = rec["error"]
        for k in ("wall_s", "energy_drift", "dt_s"):
            fh["diagnostics"][k][ix] = rec[k]
        if rec.get("trace") is not None and "traces" in fh:
            t0, dt, samples = rec["trace"]
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


def _provenance(fh: h5py.File, sweep: Sweep, runner: str, command: str | None,
                table_id: str | None = None) -> dict[str, Any]:
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


@dataclass
class BuildReport:
    """What a build call did."""

    path: Path
    complete: bool
    points_written: int
    plates_written: int
    wall_s: float
    runner: str

    @property
    def scenes_per_s(self) -> float:
        return self.points_written / self.wall_s if self.wall_s > 0 else math.nan


def _pending(fh: h5py.File, sweep: Sweep) -> list[tuple[int, int, list[int]]]:
    done = fh["done"][...]
    out = []
    for i_t, i_l in sweep.groups():
        todo = [i for i in range(done.shape[0]) if not done[i, i_t, i_l]]
        if todo:
            out.append((i_t, i_l, todo))
    return out


def _local_cluster(workers: int) -> Any:
    from dask.distributed import LocalCluster

    return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                        env=dict(WORKER_ENV), dashboard_address=":0", silence_logs=40)


def run_tasks(fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]], workers: int,
              scheduler: str | None) -> Iterator[Any]:
    """``fn(*task)`` for every task, serially or on Dask; yields results as they complete.

    Serial when ``workers <= 1`` and no scheduler is given; else a :func:`_local_cluster` (closed
    afterwards) or the cluster at ``scheduler`` (left running).
    """
    if scheduler is None and workers <= 1:
        for task in tasks:
            yield fn(*task)
        return
    from dask.distributed import Client, as_completed

    cluster = None
    if scheduler is None:
        cluster = _local_cluster(min(workers, max(1, len(tasks))))
        client = Client(cluster)
    else:
        client = Client(scheduler, timeout="30s")
    try:
        futures = [client.submit(fn, *task, pure=False) for task in tasks]
        for future in as_completed(futures):
            result = future.result()
            future.release()
            yield result
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def default_workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


@dataclass
class BuildPlan:
    """What a build is about to do and how long it should take, from a pilot run.

    ``pilots`` holds, per kind of plate (``meshed``: a plate model with a mesh, near a support;
    ``dashpot``: every other tier), the seconds one point took in the pilot (the plate of middle
    thickness of that kind, all its sphere sizes, run in this process and kept in the table), timed
    on a second, warm run; ``compile_s`` is what the first runs took more (the numba kernels
    compiled, once per installation). ``eta_s`` spreads the remaining points' cost over the
    workers.
    """

    sweep: Sweep
    points_todo: int
    plates_todo: int
    points_by_kind: dict[str, int]
    pilots: dict[str, float]
    pilot_wall_s: float
    eta_s: float
    workers: int
    compile_s: float = 0.0


def _kind(sweep: Sweep, i_t: int, i_l: int) -> str:
    model = resolve_plate_model(sweep.scene_at(len(sweep.diameters_m) - 1, i_t, i_l))[0]
    return "meshed" if model in MESHED_PLATE_MODELS else "dashpot"


def _pilot(fh: h5py.File, sweep: Sweep, spec: dict[str, Any], workers: int,
           scheduler: str | None) -> tuple[BuildPlan, int, int]:
    """Run the first pending plate of each kind here, write it, and plan the rest; returns the
    plan, and the points and plates written."""
    tasks = _pending(fh, sweep)
    kinds = {(i_t, i_l): _kind(sweep, i_t, i_l) for i_t, i_l, _ in tasks}
    points_by_kind: dict[str, int] = {}
    for i_t, i_l, todo in tasks:
        points_by_kind[kinds[i_t, i_l]] = points_by_kind.get(kinds[i_t, i_l], 0) + len(todo)
    pilots: dict[str, float] = {}
    written = plates = 0
    compile_s = 0.0
    started = time.perf_counter()
    by_kind: dict[str, list[tuple[int, int, list[int]]]] = {}
    for task in tasks:
        by_kind.setdefault(kinds[task[0], task[1]], []).append(task)
    for kind, of_kind in by_kind.items():
        # the middle plate of the kind (thin plates cost more, thick ones less)
        i_t, i_l, todo = sorted(of_kind, key=lambda t: sweep.thicknesses_m[t[0]])[len(of_kind) // 2]
        t0 = time.perf_counter()
        written += _write_plate(fh, run_plate(spec, i_t, i_l, todo))
        plates += 1
        first = time.perf_counter() - t0
        # Timed again, warm: the first run of an installation compiles the numba kernels
        # (minutes), which the workers then load from the cache; that is no plate's cost.
        t0 = time.perf_counter()
        run_plate(spec, i_t, i_l, todo)
        again = time.perf_counter() - t0
        pilots[kind] = again / len(todo)
        compile_s += max(0.0, first - again)
    rest = _pending(fh, sweep)
    lanes = 1 if scheduler is None and workers <= 1 else max(1, min(workers, len(rest)))
    work = sum(len(todo) * pilots[kinds[i_t, i_l]] for i_t, i_l, todo in rest)
    plan = BuildPlan(sweep, sum(len(t[2]) for t in tasks), len(tasks), points_by_kind, pilots,
                     time.perf_counter() - started, work / lanes, lanes, compile_s)
    return plan, written, plates


def build_table(
    sweep: Sweep,
    out: str | Path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool = False,
    max_plates: int | None = None,
    command: str | None = None,
    on_plate: Callable[[dict[str, Any]], None] | None = None,
    table_id: str | None = None,
    plan: Callable[[BuildPlan], None] | None = None,
) -> BuildReport:
    """Build (or continue building) the table for ``sweep`` at ``out``.

    Parameters
    ----------
    workers: local worker processes (default: the usable cores); 1 runs serially here.
    scheduler: address of an existing Dask scheduler; overrides ``workers``.
    progress: show a progress bar (tqdm, on stderr).
    max_plates: stop after writing this many plates, leaving ``<out>.partial`` to resume from
        (what an interruption does; for tests and chunked builds).
    command: the command line, recorded in the provenance.
    table_id: the table's id, recorded in the provenance (default: the file's stem when loaded).
    plan: called with the :class:`BuildPlan` before the sweep runs: the first plate of each kind
        is run here as a pilot (and kept), and the time of the rest estimated from it.

    Raises
    ------
    TableError
        When ``<out>.partial`` exists but was started for another sweep, or ``out`` is a folder.
    SceneError
        When a grid point's scene is invalid (before any file is made, so that the corrected
        sweep is not refused as "another sweep").
    """
    out = Path(out)
    part = partial_path(out)
    if out.is_dir():  # the finished table could not be renamed onto it
        raise TableError("out", f"{str(out)!r} is a folder; give the table file's name")
    for ix in np.ndindex(sweep.shape):
        sweep.scene_at(*ix)
    workers = default_workers() if workers is None else max(1, int(workers))
    runner = (f"dask scheduler {scheduler}" if scheduler else
              "serial" if workers <= 1 else f"dask LocalCluster, {workers} processes x 1 thread")
    started = time.perf_counter()
    written = plates = 0
    spec = sweep.to_dict()
    out.parent.mkdir(parents=True, exist_ok=True)
    if part.exists():
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
        if stored != json.loads(json.dumps(spec, sort_keys=True)):
            raise TableError("sweep", f"{str(part)!r} holds an interrupted build of another sweep; "
                             "rerun with the same grid and scene to resume, or delete it")
        if reading != EXTRACTOR_VERSION:
            raise TableError("partial", f"{str(part)!r} holds points read with the extractor's "
                             f"reading {reading}, this solitonde reads with {EXTRACTOR_VERSION}: "
                             "one table holds one reading; delete it to start the build afresh")
    else:
        with h5py.File(part, "w") as fh:
            _create(fh, sweep)
    with h5py.File(part, "r+") as fh:
        # the code that computes this session's points (a resumed build may span revisions)
        sessions = json.loads(fh.attrs.get("sessions", "[]"))
        sessions.append({"started_at": datetime.now(UTC).isoformat(timespec="seconds"),
                         "git_revision": git_revision(), "runner": runner,
                         "points_done_before": int(fh["done"][...].sum())})
        fh.attrs["sessions"] = json.dumps(sessions)
        eta = None
        if plan is not None and max_plates is None and _pending(fh, sweep):
            the_plan, written, plates = _pilot(fh, sweep, spec, workers, scheduler)
            eta = the_plan.eta_s
            plan(the_plan)
        tasks = _pending(fh, sweep)
        if max_plates is not None:
            tasks = tasks[:max(0, max_plates)]
        total = sum(len(t[2]) for t in tasks)
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=total, unit="scene", desc="table", smoothing=0.05)
            if eta is not None:  # tqdm's own ETA takes over once plates come back
                bar.set_postfix_str(f"planned {eta:.0f} s", refresh=True)
        try:
            jobs = [(spec, i_t, i_l, todo) for i_t, i_l, todo in tasks]
            for result in run_tasks(run_plate, jobs, workers, scheduler):
                n = _write_plate(fh, result)
                written += n
                plates += 1
                if bar is not None:
                    if eta is not None and bar.n == 0:
                        bar.set_postfix_str("", refresh=False)  # tqdm's ETA from here on
                    bar.update(n)
                if on_plate is not None:
                    on_plate(result)
        finally:
            if bar is not None:
                bar.close()
            elapsed = time.perf_counter() - started
            fh.attrs["build_wall_s"] = float(fh.attrs["build_wall_s"]) + elapsed
            fh.flush()
        complete = bool(fh["done"][...].all())
        if complete:
            write_slopes(fh, simulate_slopes(sweep))
            fh.attrs["provenance"] = json.dumps(_provenance(fh, sweep, runner, command,
                                                            table_id))
            fh.attrs["complete"] = True
    if complete:
        os.replace(part, out)
    return BuildReport(out if complete else part, complete, written, plates,
                       time.perf_counter() - started, runner)



# The material slopes ------------------------------------------------------------------------

SLOPE_STEP = 0.03
"""Relative change of E (at fixed nu) and of rho either way for the central difference: about a
grade's spread, so the slope is the secant over the range the inversion uses it for, and large
against the extractor's run-to-run rounding on weak reflections."""

def _material(plate: Mapping[str, Any]) -> dict[str, Any]:
    """The plate material as a property mapping (a library name resolved)."""
    from solitonde.model.materials import material_of

    mat = plate["material"]
    if isinstance(mat, Mapping):
        return dict(mat)
    m = material_of(mat, "plate.material")
    return {"name": m.name, "youngs_modulus": m.youngs_modulus,
            "poisson_ratio": m.poisson_ratio, "density": m.density}


def simulate_slopes(sweep: Any) -> dict[str, np.ndarray]:
    """``{"tof_s": (D, t, 2), "arr": (D, t, 2)}`` for a table's sweep
    (:class:`~.table_build.Sweep`): the features' slopes along ``ln E'`` and ``ln rho`` at
    each sphere size and thickness, far from the supports; NaN where a run shows no
    reflection."""
    n_d, n_t = len(sweep.diameters_m), len(sweep.thicknesses_m)
    out = {name: np.full((n_d, n_t, 2), np.nan) for name in ("tof_s", "arr")}
    far = len(sweep.distances_m) - 1
    for i_d in range(n_d):
        for i_t in range(n_t):
            base = sweep.scene_at(i_d, i_t, far).model_dump(mode="json")
            base["effects"]["plate_model"] = "infinite"
            base["plate"]["material"] = _material(base["plate"])
            for k, key in enumerate(("youngs_modulus", "density")):
                ends = []
                for sign in (1.0, -1.0):
                    data = copy.deepcopy(base)
                    data["plate"]["material"][key] *= 1.0 + sign * SLOPE_STEP
                    data["plate"]["material"]["name"] = f"{key} {sign * SLOPE_STEP:+g}"
                    ends.append(simulate_point(scene_from_dict(data)))
                if all(e.get("tof_s") is not None and e.get("arr") is not None for e in ends):
                    span = math.log((1.0 + SLOPE_STEP) / (1.0 - SLOPE_STEP))
                    for name in out:
                        out[name][i_d, i_t, k] = (ends[0][name] - ends[1][name]) / span
    return out


def write_slopes(fh: h5py.File, slopes: Mapping[str, np.ndarray]) -> None:
    """Store ``slopes`` in an open table file (replacing any there)."""
    if MATERIAL_SLOPES in fh:
        del fh[MATERIAL_SLOPES]
    group = fh.create_group(MATERIAL_SLOPES)
    group.attrs["components"] = list(SLOPE_COMPONENTS)
    group.attrs["step"] = SLOPE_STEP
    group.attrs["plate_model"] = "infinite"
    for name, values in slopes.items():
        group.create_dataset(name, data=np.asarray(values, dtype=float))


# The default table's sweep -----------------------------------------------------------------


def default_distances_m() -> list[float]:
    """L for the default table: dense within 200 mm (where the support matters), then to the
    plate centre (457 mm). 2.5 mm apart next to the clamp and 5 mm to 70 mm:

    * next to the clamp ARR rises steeply and bends toward it: with nodes 10 mm apart, linear
      interpolation read ARR up to 0.08 low at 3-5 mm (up to 7 times the error the table
      stated) and TOF up to 10 us late, against the model simulated there (the error falls as
      the square of the spacing);
    * from 30 to 70 mm a weak reflection oscillates with distance (about 25 mm long: the
      clamp's echo against the direct reflection), and nodes at 35, 50 and 70 mm sat on its
      mean: each lay on the line through its neighbours, so the table stated 0.0003 in ARR
      where it missed by up to 0.0036 (10 times). Nodes 5 mm apart follow it.
    """
    near = [0.0, 0.0025, 0.005, 0.0075, 0.01, 0.015, 0.02, 0.025, 0.03, 0.035, 0.04, 0.045,
            0.05, 0.055, 0.06, 0.065, 0.07, 0.08, 0.09, 0.115, 0.14, 0.17, 0.2]
    far = [0.26, 0.34, 0.457]
    return near + far


THICKNESS_NODES = 16


def default_thicknesses_m() -> list[float]:
    """t for the default table: 1.5 to 6 mm, geometric (ARR is a function of D/t), 16 nodes
    (10 % apart): TOF bends sharply where the reflection weakens (D/t 3-4), and with 8 nodes
    linear interpolation there erred by 13 us (a 2.5 mm plate read with 9.53 mm spheres), more
    than every other term of the error budget; the error falls as the square of the spacing."""
    return [float(round(x, 6)) for x in np.geomspace(1.5e-3, 6e-3, THICKNESS_NODES)]


def default_sweep() -> Sweep:
    return Sweep(list(PAPER_DIAMETERS_M), default_thicknesses_m(), default_distances_m())
