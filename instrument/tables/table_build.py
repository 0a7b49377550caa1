"""Build the model table: a sweep over (D, t, L) simulated in parallel, written by one process.

Work is cut into one task per plate, ``(t, L)`` (:mod:`.plate_task`): a task simulates every
sphere size on its plate, the largest first (the longest record), with a task-local cache of plate
responses in front of the on-disk response store (:mod:`.greens_cache`). On the 3-D plate
(``greens``) the response depends on the plate, its mesh, the position and the step, not on the
sphere, so the smaller spheres reuse the prefix of the largest one's response where it is long
enough (a response is computed from the chain's first load of the plate on: a smaller sphere's
shorter record after a shorter way down its chain usually fits, else it computes its own). The
mesh around the chain follows the contact radius, and the Mindlin plate's mesh
(``mindlin_greens``) each size's flexural wavelength, so sizes whose meshes differ compute a
response each. The store keeps every response for the
dissipation layers (the damping acts in the chain, not the plate) and for any later build of the
same plates, which then runs only the chains. Far from the supports ``auto`` picks the infinite
plate and a task costs milliseconds.

Execution goes through :func:`solitonde.instrument.parallel.run_tasks`: serial in this process
(``workers=1``), a Dask ``LocalCluster`` (default: one single-threaded process per core), or an
existing Dask cluster (``scheduler='tcp://host:port'``). A build too small to repay the local
workers' start (a rebuild from the store, a handful of plates) runs here: planned from the pilot,
or, without a plan, while the plates run here faster than the workers would start. Whatever runs
the tasks, only the driver writes the file (:mod:`.table_file`): results stream back, each
plate's points are written and flushed together with their ``done`` mask, so an interrupted
build resumes where it stopped. The file is built as ``<out>.partial`` and renamed onto ``<out>``
(``os.replace``) only when complete.
"""

from __future__ import annotations

import contextlib
import copy
import json
import math
import os
import tempfile
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, NamedTuple

import h5py
import numpy as np

from solitonde.instrument.parallel import (
    LOCAL_START_S,
    Runs,
    close_later,
    default_workers,
    local_cluster,
    run_tasks,
    runner_label,
)
from solitonde.instrument.tables.family import material_properties
from solitonde.instrument.tables.greens_cache import (
    DEFAULT_STORE,
)
from solitonde.instrument.tables.plate_task import run_plate, simulate_point
from solitonde.instrument.tables.sweep import Sweep, damped_scene
from solitonde.instrument.tables.table import (
    MATERIAL_SLOPES,
    SLOPE_COMPONENTS,
    SweepDict,
    TableError,
)
from solitonde.instrument.tables.table_file import (
    PlateResult,
    check_partial,
    create,
    partial_path,
    pending,
    provenance,
    start_session,
    write_plate,
)
from solitonde.model.scene import scene_from_dict
from solitonde.model.tiers import MESHED_PLATE_MODELS, resolve_plate_model
from solitonde.model.tiers.meshed import forget_plates


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



@dataclass
class BuildPlan:
    """What a build is about to do and how long it should take, from a pilot run.

    Per kind of plate (``meshed``: a plate model with a mesh, near a support; ``dashpot``: every
    other tier) the pilot runs the thinnest, a middle and the thickest plate of the kind (all their
    sphere sizes, in this process, kept in the table): ``costs[kind]`` holds ``(thickness_m,
    seconds a point, seconds a point of a dissipation layer)`` for each, timed warm, the second
    with the plate's responses read from the store (what a layer's point costs: only the chain).
    The rest is timed by the model's own count of each plate's work
    (:func:`solitonde.model.plan.plan`: steps times particles and plate dofs) at the pilots' rate
    per kind, whole runs and chains on stored responses apart.
    ``compile_s`` is what the first runs took more (the numba kernels compiled, once per
    installation). ``start_s`` is what the workers took to start and load the model (a local
    cluster's processes, each running one pilot plate), measured before the plan is made: paid
    once more by the dissipation layers, which start their own. ``eta_s`` spreads the remaining
    points' cost, ``layers_eta_s`` that of the ``layers`` dissipation layers that follow, over the
    workers, each with the driver's writes of its plates (one at a time, on the same cores);
    ``slopes_eta_s`` is the material slopes' runs, in this process.
    """

    sweep: Sweep
    points_todo: int
    plates_todo: int
    points_by_kind: dict[str, int]
    costs: dict[str, list[tuple[float, float, float]]]
    pilot_wall_s: float
    eta_s: float
    workers: int
    compile_s: float = 0.0
    layers: int = 0
    layers_eta_s: float = 0.0
    start_s: float = 0.0
    slopes_eta_s: float = 0.0
    elapsed_s: float = 0.0
    """Seconds the build had run when the plan was made (the pilot, the workers' start)."""
    serial_s: float = 0.0
    """The rest of the sweep's seconds run here, one plate at a time (what a small build does
    when the workers' start would cost more than they save)."""
    here: bool = False
    """The sweep runs here, not on the workers asked for: cheaper than their start."""
    layers_serial_s: float = 0.0
    """The layers' seconds run here, one plate at a time."""
    layers_here: bool = False
    """The layers run here, not on the workers asked for: cheaper than their start."""
    damped_factor: float = 1.0
    """A damped chain's time over the elastic one's on the pilot's plates (the layers' chains are
    damped), by which the layers' estimate is scaled."""
    slowdown: float = 1.0
    """A plate's time on the workers, run as a stream of tasks with every worker busy, over its
    time here alone (measured as the workers start, on a pilot plate run as the pilot ran it:
    from the store where the pilot read it), by which the sweep's and the layers' estimates are
    scaled."""

    @property
    def remaining_s(self) -> float:
        """Seconds the build should take from the plan on: the sweep, its layers, the slopes."""
        return self.eta_s + self.layers_eta_s + self.slopes_eta_s

    @property
    def pilots(self) -> dict[str, float]:
        """Per kind, the dearest pilot's seconds a point."""
        return {kind: max(c[1] for c in pairs) for kind, pairs in self.costs.items()}


def point_cost(pairs: Sequence[tuple[float, float, float]], thickness_m: float,
               layer: bool = False) -> float:
    """Seconds a point of ``thickness_m`` costs, from the pilots' ``(t, s, layer s)``: a power
    law in t between neighbouring pilots (piecewise linear in log-log), held beyond the ends."""
    col = 2 if layer else 1
    pts = sorted({math.log(p[0]): math.log(max(p[col], 1e-9)) for p in pairs}.items())
    xs, ys = [p[0] for p in pts], [p[1] for p in pts]
    return math.exp(float(np.interp(math.log(thickness_m), xs, ys)))


def plate_model_costs(sweep: Sweep, i_t: int, i_l: int) -> list[tuple[float, float]]:
    """The model's own count of one plate's work per sphere size
    (:func:`solitonde.model.plan.plan`): the whole run's, and the chain's alone (what is left when
    the plate's response comes from the store). Exact step and dof counts: a plate's cost jumps
    where the step, quantised to the sample period, halves (a 5 mm steel plate costs as much as a
    4 mm one and twice a 6 mm one), which no smooth law in the thickness follows."""
    from solitonde.model.plan import plan
    from solitonde.model.tiers import TIERS

    out = []
    for i_d in range(len(sweep.diameters_m)):
        run = plan(sweep.scene_at(i_d, i_t, i_l))
        plate = TIERS[run.plate_model].dof_weight * float(run.plate_steps) * run.plate_dofs
        out.append((run.cost, run.cost - plate))
    return out


PilotTimes = dict[str, list[tuple[tuple[int, int], list[int], float, float]]]
"""Per kind, each pilot plate's ``((i_t, i_l), sizes run, seconds whole, seconds chain only)``."""


def _plate_seconds(sweep: Sweep, kinds: Mapping[tuple[int, int], str], timed: PilotTimes
                   ) -> Callable[[int, int, Iterable[int], bool], float]:
    """``seconds(i_t, i_l, sizes, chain_only)`` of any plate: its count by
    :func:`plate_model_costs` at its kind's rate, seconds per unit of count over the pilots
    (whole runs, and chains on stored responses, apart); 0 for a kind no pilot ran (all its
    plates done before)."""
    model = {key: plate_model_costs(sweep, *key) for key in kinds}

    def counted(key: tuple[int, int], todo: Iterable[int], chain_only: bool) -> float:
        return sum(model[key][i_d][1 if chain_only else 0] for i_d in todo)

    rate = {kind: (sum(p[2] for p in plates) / max(sum(counted(k, todo, False)
                                                      for k, todo, _, _ in plates), 1.0),
                   sum(p[3] for p in plates) / max(sum(counted(k, todo, True)
                                                      for k, todo, _, _ in plates), 1.0))
            for kind, plates in timed.items()}

    def seconds(i_t: int, i_l: int, todo: Iterable[int], chain_only: bool) -> float:
        kind = kinds[i_t, i_l]
        if kind not in rate:
            return 0.0
        return rate[kind][1 if chain_only else 0] * counted((i_t, i_l), todo, chain_only)

    return seconds


def _kind(sweep: Sweep, i_t: int, i_l: int) -> str:
    model = resolve_plate_model(sweep.scene_at(len(sweep.diameters_m) - 1, i_t, i_l))[0]
    return "meshed" if model in MESHED_PLATE_MODELS else "dashpot"


def _ends(tasks: Sequence[tuple[int, int, list[int]]]) -> list[tuple[int, int, list[int]]]:
    """The pilot's plates of one kind: at its thickest, middle and thinnest thickness (fewer if
    some are the same), each at the middle of that thickness's distances (the cost varies less
    with the distance than with the thickness; the middle one stands for them). The thickest,
    usually the cheapest (its step is the longest), comes first: the kind's first plate loads
    or compiles the kernels and is run twice, the others once."""
    present = sorted({t[0] for t in tasks})
    out = []
    for i_t in sorted({present[0], present[len(present) // 2], present[-1]}, reverse=True):
        same = sorted((t for t in tasks if t[0] == i_t), key=lambda t: t[1])
        out.append(same[len(same) // 2])
    return out


LAYER_TIMING_DAMPING_S = 1.2e-7
"""The damping at which the pilot times a dissipation layer's chain: the bundled layers' middle
time constant (:data:`.dissipation.DEFAULT_DAMPINGS_S`; the chain's cost hardly follows it)."""


class WarmPlate(NamedTuple):
    """A pilot plate every worker runs before the sweep, and how the pilot timed it here: its
    seconds, and the response store it read (None: it computed its responses)."""

    task: tuple[int, int, list[int]]
    seconds: float
    store: str | None


def _pilot(fh: h5py.File, sweep: Sweep, spec: SweepDict, workers: int,
           scheduler: str | None, responses: str | None, layers: int, slopes: bool
           ) -> tuple[BuildPlan, int, int, WarmPlate]:
    """Run the thinnest, a middle and the thickest pending plate of each kind here, write them,
    and plan the rest; returns the plan, the points and plates written, and the cheapest pilot
    plate of the dearest kind with its seconds here (what each worker runs before the sweep)."""
    tasks = pending(fh, sweep)
    all_points = [(i_t, i_l, len(sweep.diameters_m)) for i_t, i_l in sweep.groups()]
    kinds = {(i_t, i_l): _kind(sweep, i_t, i_l) for i_t, i_l, _ in all_points}
    points_by_kind: dict[str, int] = {}
    for i_t, i_l, todo in tasks:
        points_by_kind[kinds[i_t, i_l]] = points_by_kind.get(kinds[i_t, i_l], 0) + len(todo)
    costs: dict[str, list[tuple[float, float, float]]] = {}
    stored: dict[str, bool] = {}  # every pilot of the kind found its responses in the store
    write_s: list[float] = []  # the driver's time to write and flush a plate
    written = plates = 0
    compile_s = 0.0
    warm: tuple[str, WarmPlate] | None = None
    # a layer's chain is damped (Kuwabara-Kono), which costs more than the elastic chain
    damped = (replace(sweep, scene=damped_scene(sweep.scene, LAYER_TIMING_DAMPING_S)).to_dict()
              if layers else None)
    chains: list[tuple[float, float]] = []  # (elastic, damped) chains' seconds per pilot plate
    timed: PilotTimes = {}
    started = time.perf_counter()
    by_kind: dict[str, list[tuple[int, int, list[int]]]] = {}
    for task in tasks:
        by_kind.setdefault(kinds[task[0], task[1]], []).append(task)
    with tempfile.TemporaryDirectory(prefix="solitonde-pilot-") as scratch:
        # without a store the pilot's layer timing needs one: a scratch folder, dropped after
        store = responses if responses is not None else scratch
        for kind, of_kind in by_kind.items():
            ends = _ends(of_kind)
            costs[kind] = []
            for i_t, i_l, todo in ends:
                t0 = time.perf_counter()
                result = run_plate(spec, i_t, i_l, todo, store)
                t_write = time.perf_counter()
                ran = t_write - t0
                written += write_plate(fh, result)
                write_s.append(time.perf_counter() - t_write)
                plates += 1
                first = time.perf_counter() - t0
                stored[kind] = stored.get(kind, True) and result["greens_computed"] == 0
                # Timed again, warm: the first run of an installation compiles the numba kernels
                # (minutes), which the workers then load from the cache; that is no plate's
                # cost. Once with the store (a layer's cost), and the kind's first plate once
                # without it (a point's, unless the store held this plate's responses: a rebuild
                # needs no more); the kind's later plates ran with its kernels loaded, so their
                # first run is their point's cost. Each run builds its plate as a worker does.
                forget_plates()
                chain = _timed_plate(spec, i_t, i_l, todo, store)
                if damped is not None:
                    if (i_t, i_l, todo) == ends[0]:
                        # a kind's first damped chain compiles its kernels (a second on the
                        # dashpot against its 4 ms): run once untimed
                        _timed_plate(damped, i_t, i_l, todo, store)
                    chains.append((chain, _timed_plate(damped, i_t, i_l, todo, store)))
                again, again_store = chain, responses  # (not the scratch: dropped after)
                if result["greens_computed"] > 0 and (i_t, i_l, todo) == ends[0]:
                    again, again_store = _timed_plate(spec, i_t, i_l, todo), None
                elif result["greens_computed"] > 0:  # the kind's kernels ran before: no compile
                    again, again_store = ran, None
                costs[kind].append((sweep.thicknesses_m[i_t], again / len(todo),
                                    chain / len(todo)))
                timed.setdefault(kind, []).append(((i_t, i_l), todo, again, chain))
                compile_s += max(0.0, first - again)
                if warm is None or (kind == "meshed") > (warm[0] == "meshed") or (
                        kind == warm[0] and again < warm[1].seconds):
                    warm = (kind, WarmPlate((i_t, i_l, todo), again, again_store))
    rest = pending(fh, sweep)
    lanes = 1 if scheduler is None and workers <= 1 else max(1, min(workers, len(rest) or 1))
    plate_s = _plate_seconds(sweep, kinds, timed)
    # a store that held the pilots' responses is taken to hold the rest (a rebuild): chains only
    work = sum(plate_s(i_t, i_l, todo, stored[kinds[i_t, i_l]] and responses is not None)
               for i_t, i_l, todo in rest)
    elastic_chains = sum(c[0] for c in chains)
    damped_factor = sum(c[1] for c in chains) / elastic_chains if elastic_chains > 0 else 1.0
    layer_work = layers * damped_factor * sum(plate_s(i_t, i_l, range(n), responses is not None)
                                              for i_t, i_l, n in all_points)
    layer_lanes = 1 if scheduler is None and workers <= 1 else max(1, workers)
    # the driver writes the plates one at a time, on the cores the workers use: measured on the
    # tutorial's plate, a layer (whose plates come back fast) takes about its chains' time and
    # its writes' together, and so does a rebuild
    write = float(np.median(write_s)) if write_s else 0.0
    layer_writes = layers * len(all_points) * write
    # the slopes: four chains on the infinite plate per size and thickness, here, as far points
    # cost (or a layer's chain where the sweep has none)
    far = "dashpot" if "dashpot" in costs else next(iter(costs))
    slope_runs = 4 * len(sweep.diameters_m) if slopes else 0
    slopes_s = sum(slope_runs * point_cost(costs[far], t, layer=far != "dashpot")
                   for t in sweep.thicknesses_m) if costs else 0.0
    plan = BuildPlan(sweep, sum(len(t[2]) for t in tasks), len(tasks), points_by_kind, costs,
                     time.perf_counter() - started, work / lanes + len(rest) * write, lanes,
                     compile_s, layers, layer_work / layer_lanes + layer_writes,
                     slopes_eta_s=slopes_s, damped_factor=damped_factor,
                     serial_s=work + len(rest) * write,
                     layers_serial_s=layer_work + layer_writes)
    assert warm is not None  # the pilot ran at least one plate
    return plan, written, plates, warm[1]


def build_table(
    sweep: Sweep,
    out: str | Path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool = False,
    max_plates: int | None = None,
    command: str | None = None,
    on_plate: Callable[[PlateResult], None] | None = None,
    table_id: str | None = None,
    plan: Callable[[BuildPlan], None] | None = None,
    responses: str | Path | bool = True,
    layers: int = 0,
    slopes: bool = True,
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
    plan: called with the :class:`BuildPlan` before the sweep runs: three plates of each kind
        (thinnest, middle, thickest) are run here as a pilot (and kept), and the time of the rest
        estimated from them.
    responses: the plate responses' store (:mod:`.greens_cache`): True, the default folder; a
        folder (one the workers share, on a cluster); False, none (each task computes its own).
        The table is the same either way: a stored response is the computed one, bit for bit.
    layers: how many dissipation layers the caller builds after this sweep (the plan counts
        their time; they are built by :func:`.dissipation.simulate_layer`).
    slopes: also simulate the material slopes into the table (a dissipation layer's sweep, whose
        features alone are kept, goes without).

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
    runner = runner_label(workers, scheduler)
    # the default store is each worker's own (its machine's); a folder named is made absolute,
    # since workers elsewhere resolve a relative one against their own working folder
    store = (DEFAULT_STORE if responses is True else None if responses is False
             else str(Path(responses).resolve()))
    started = time.perf_counter()
    written = plates = 0
    spec = sweep.to_dict()
    out.parent.mkdir(parents=True, exist_ok=True)
    _start_partial(part, sweep)
    with contextlib.ExitStack() as closing:  # waits for a local cluster closing meanwhile
        with h5py.File(part, "r+") as fh:
            start_session(fh, runner)
            eta = None
            runs = Runs()
            with contextlib.ExitStack() as stack:
                sweep_scheduler, sweep_workers = scheduler, workers
                if plan is not None and max_plates is None and pending(fh, sweep):
                    the_plan, written, plates, sweep_scheduler = _plan_build(
                        fh, sweep, spec, stack, workers, scheduler, store, layers, slopes,
                        closing)
                    if sweep_scheduler is None:
                        sweep_workers = the_plan.workers
                    eta = the_plan.eta_s
                    the_plan.elapsed_s = time.perf_counter() - started
                    plan(the_plan)
                tasks = pending(fh, sweep)
                if max_plates is not None:
                    tasks = tasks[:max(0, max_plates)]
                try:
                    more, more_plates = _run_plates(fh, spec, tasks, sweep_workers,
                                                    sweep_scheduler, progress, eta, on_plate, store,
                                                    runs)
                finally:
                    fh.attrs["build_wall_s"] = (float(fh.attrs["build_wall_s"])
                                                + time.perf_counter() - started)
                    fh.flush()
            written, plates = written + more, plates + more_plates
            if scheduler is None and runs.workers == 0:
                runner = runner_label(1, None)  # every plate ran here
            complete = _finish(fh, sweep, slopes, runner, command, table_id)
        if complete:
            os.replace(part, out)
    return BuildReport(out if complete else part, complete, written, plates,
                       time.perf_counter() - started, runner)


def _start_partial(part: Path, sweep: Sweep) -> None:
    """Create ``part`` for ``sweep``, or check that the one there was started for it."""
    if part.exists():
        check_partial(part, sweep)
    else:
        with h5py.File(part, "w") as fh:
            create(fh, sweep)


def _finish(fh: h5py.File, sweep: Sweep, slopes: bool, runner: str, command: str | None,
            table_id: str | None) -> bool:
    """Whether every point is done; if so, the slopes (with ``slopes``) and the provenance
    written and the file marked complete."""
    if not bool(fh["done"][...].all()):
        return False
    if slopes:
        write_slopes(fh, simulate_slopes(sweep))
    fh.attrs["provenance"] = json.dumps(provenance(fh, sweep, runner, command, table_id))
    fh.attrs["complete"] = True
    return True


def _plan_build(fh: h5py.File, sweep: Sweep, spec: SweepDict, stack: contextlib.ExitStack,
                workers: int, scheduler: str | None, store: str | None, layers: int,
                slopes: bool, closing: contextlib.ExitStack
                ) -> tuple[BuildPlan, int, int, str | None]:
    """The pilot, then the workers started (a local cluster, its close begun with ``stack``
    and waited for with ``closing``) and timed: the plan, the points and plates the pilot wrote,
    and the scheduler the sweep runs on."""
    the_plan, written, plates, warm = _pilot(fh, sweep, spec, workers, scheduler, store, layers,
                                             slopes)
    local = scheduler is None and workers > 1
    if local and layers and the_plan.layers_serial_s <= the_plan.layers_eta_s + LOCAL_START_S:
        # the layers are cheaper here than on workers started for them
        the_plan.layers_eta_s, the_plan.layers_here = the_plan.layers_serial_s, True
    if not pending(fh, sweep) or (scheduler is None and not local):
        return the_plan, written, plates, scheduler
    if local and the_plan.serial_s <= the_plan.eta_s + LOCAL_START_S:
        # cheaper here than the workers' start: the sweep runs serially
        the_plan.eta_s, the_plan.workers, the_plan.here = the_plan.serial_s, 1, True
        if layers and not the_plan.layers_here:
            the_plan.layers_eta_s += LOCAL_START_S  # their own workers start
        return the_plan, written, plates, None
    address, the_plan.start_s, the_plan.slowdown = _start_workers(stack, spec, warm,
                                                                  the_plan.workers, scheduler,
                                                                  closing)
    the_plan.eta_s *= the_plan.slowdown
    if not the_plan.layers_here:
        the_plan.layers_eta_s *= the_plan.slowdown
        if layers and scheduler is None:
            the_plan.layers_eta_s += the_plan.start_s  # they start their own local cluster
    return the_plan, written, plates, address


PARALLEL_SLOWDOWN_RANGE = (1.0, 4.0)
"""Bounds on the measured ratio of a worker's time for a plate with every worker busy to its
time alone: beyond them the measurement itself is taken to be disturbed. The same plate on the
same cores, each shared with the other workers, is never faster than here alone: a ratio under 1
is the timing here caught in a slow moment (the workers' start, the machine's bursts), and
counting it made the plans of builds on two cores a third short (measured 0.62-0.71x, and the
sweeps ran at the pilot's rate)."""


WARM_TIMING_S = 0.5
"""The pilot plate is timed again, for at least this many seconds with every worker busy, one
task a run as the sweep runs its plates, and half as long here, with the workers idle. A plate
read from the store takes 20-100 ms: one run per worker against the pilot's one run here
measured 0.8-1.1x where the sweep's plates ran 1.4x. A plate runs about 1.3x slower in a worker
than here even alone (the worker's own messages share its process), and what a stream of short
tasks adds shows only in such a stream."""


def _timed_plate(spec: SweepDict, i_t: int, i_l: int, todo: list[int],
                 store: str | None = None) -> float:
    """Run one (already written) plate as the pilot timed it (with ``store``, or computing its
    responses); returns its seconds."""
    started = time.perf_counter()
    run_plate(spec, i_t, i_l, todo, store)
    forget_plates()
    return time.perf_counter() - started


def _start_workers(stack: contextlib.ExitStack, spec: SweepDict,
                   warm: WarmPlate, workers: int, scheduler: str | None,
                   closing: contextlib.ExitStack) -> tuple[str, float, float]:
    """Start the sweep's local cluster (its close begun with ``stack`` and waited for with
    ``closing``; an existing ``scheduler`` is used as it is), have every worker load the model
    on the pilot plate ``warm``, then run that plate as a stream of tasks on every worker at
    once (:data:`WARM_TIMING_S`): returns the scheduler's address, the seconds taken (which the
    plan then counts as spent, not guessed), and how much slower a plate runs in the sweep than
    here alone (cores that share a physical core or memory bandwidth run slower together; a
    worker runs slower than this process, and short tasks share the cores with their
    messages)."""
    from dask.distributed import Client

    started = time.perf_counter()
    if scheduler is None:
        cluster = local_cluster(workers)
        stack.callback(close_later, cluster, closing)
        scheduler = str(cluster.scheduler_address)
    task = (spec, *warm.task, warm.store)
    with Client(scheduler, timeout="30s") as client:
        addresses = list(client.scheduler_info()["workers"])
        # one run each loads the model's kernels in that worker
        client.gather([client.submit(_timed_plate, *task, workers=[address], pure=False,
                                     allow_other_workers=False) for address in addresses])
        alone = _repeat_here(task, WARM_TIMING_S / 2, warm.seconds)
        together = _stream(client, task, addresses, WARM_TIMING_S)
    return scheduler, time.perf_counter() - started, parallel_slowdown(together, alone)


def parallel_slowdown(together_s: float, alone_s: float) -> float:
    """How much slower a plate runs with every worker busy than here alone, within
    :data:`PARALLEL_SLOWDOWN_RANGE` (1 where nothing was timed here)."""
    if alone_s <= 0:
        return 1.0
    low, high = PARALLEL_SLOWDOWN_RANGE
    return min(max(together_s / alone_s, low), high)


def _repeat_here(task: tuple[Any, ...], seconds: float, before: float) -> float:
    """The median seconds of a plate run here, again and again for at least ``seconds`` (and
    twice), the pilot's run of it (``before`` seconds) counted as the first."""
    times = [before]
    started = time.perf_counter() - before
    while len(times) < 2 or time.perf_counter() - started < seconds:
        times.append(_timed_plate(*task))
    return float(np.median(times))


def _stream(client: Any, task: tuple[Any, ...], addresses: list[str], seconds: float) -> float:
    """The median seconds of a plate run as a stream of tasks, two in flight per worker at
    ``addresses``, for at least ``seconds`` (and two runs a worker)."""
    from dask.distributed import as_completed

    def submit() -> Any:
        return client.submit(_timed_plate, *task, workers=addresses, pure=False,
                             allow_other_workers=False)

    started = time.perf_counter()
    runs = as_completed([submit() for _ in range(2 * len(addresses))])
    times = []
    for future in runs:
        times.append(future.result())
        if time.perf_counter() - started < seconds:
            runs.add(submit())
    return float(np.median(times))


def _run_plates(fh: h5py.File, spec: SweepDict, tasks: Sequence[tuple[int, int, list[int]]],
                workers: int, scheduler: str | None, progress: bool, eta: float | None,
                on_plate: Callable[[PlateResult], None] | None,
                responses: str | None = None, runs: Runs | None = None) -> tuple[int, int]:
    """Run the pending plates ``tasks`` through the executor and write each as it comes back;
    returns the points and plates written (those of a plate that raised are not counted).
    Without a scheduler the first plates run here while that is cheaper than starting local
    workers (:func:`~solitonde.instrument.parallel.run_tasks`; ``runs`` counts where)."""
    written = plates = 0
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=sum(len(t[2]) for t in tasks), unit="scene", desc="table",
                   smoothing=0.05)
        if eta is not None:  # tqdm's own ETA takes over once plates come back
            bar.set_postfix_str(f"planned {eta:.0f} s", refresh=True)
    try:
        jobs = [(spec, i_t, i_l, todo, responses) for i_t, i_l, todo in tasks]
        for result in run_tasks(run_plate, jobs, workers, scheduler, here_first=True,
                                runs=runs):
            n = write_plate(fh, result)
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
    return written, plates


# The material slopes ------------------------------------------------------------------------

SLOPE_STEP = 0.03
"""Relative change of E (at fixed nu) and of rho either way for the central difference: about a
grade's spread, so the slope is the secant over the range the inversion uses it for, and large
against the extractor's run-to-run rounding on weak reflections."""

def simulate_slopes(sweep: Sweep) -> dict[str, np.ndarray]:
    """``{"tof_s": (D, t, 2), "arr": (D, t, 2)}`` for a table's sweep: the features' slopes along
    ``ln E'`` and ``ln rho`` at each sphere size and thickness, far from the supports; NaN where a
    run shows no reflection."""
    n_d, n_t = len(sweep.diameters_m), len(sweep.thicknesses_m)
    out = {name: np.full((n_d, n_t, 2), np.nan) for name in ("tof_s", "arr")}
    far = len(sweep.distances_m) - 1
    for i_d in range(n_d):
        for i_t in range(n_t):
            base = sweep.scene_at(i_d, i_t, far).model_dump(mode="json")
            base["effects"]["plate_model"] = "infinite"
            base["plate"]["material"] = material_properties(base["plate"]["material"])
            for k, key in enumerate(("youngs_modulus", "density")):
                ends = []
                for sign in (1.0, -1.0):
                    data = copy.deepcopy(base)
                    data["plate"]["material"][key] *= 1.0 + sign * SLOPE_STEP
                    data["plate"]["material"]["name"] = f"{key} {sign * SLOPE_STEP:+g}"
                    ends.append(simulate_point(scene_from_dict(data)))
                if all(e.get("tof_s") is not None and e.get("arr") is not None for e in ends):
                    span = math.log((1.0 + SLOPE_STEP) / (1.0 - SLOPE_STEP))
                    out["tof_s"][i_d, i_t, k] = (ends[0]["tof_s"] - ends[1]["tof_s"]) / span
                    out["arr"][i_d, i_t, k] = (ends[0]["arr"] - ends[1]["arr"]) / span
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

