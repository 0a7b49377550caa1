"""The instrument's one parallel executor: independent tasks run serially, on a local Dask cluster
or on an existing Dask cluster, and their results are handed back as they complete.

Table builds, the studies (the paper's reproduction, validation, map studies) and any other batch
the instrument spreads over cores go through :func:`run_tasks`. A local cluster runs one process
per worker with one thread each (the cores are the workers), forked from this process on
Linux so that it starts with the model loaded (:func:`local_cluster`); an existing cluster is
addressed by its scheduler (``tcp://host:port``) and left running. Results come back in
finishing order; a caller that needs one order whatever the worker count sorts them (or keys
them) itself.

The model's own pool (:mod:`solitonde.model.batch`, a forked process pool or threads) stays in the
model, which imports nothing of the instrument.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

#: Environment of Dask worker processes: one compute thread each (the cores are the workers).
WORKER_ENV = {
    "NUMBA_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
}

R = TypeVar("R")

LOCAL_START_METHOD = "fork" if sys.platform == "linux" else "spawn"
"""How a local cluster's worker processes start. Forked, they inherit this process's imported
modules and the kernels it loaded: two workers take tasks 0.1-0.15 s after the cluster starts
(spawned, each imports the package and loads the model's kernels anew: about 1.3 s). A fork
copies only the forking thread (Dask's event loop, while the main thread waits for the
cluster). A table build starts its clusters before its bars; a study's bar (validate) may be
running, and its thread only writes the terminal, which a worker does not. The model's kernels
are single-threaded, and the service, whose threads serve requests, never starts a local
cluster. Elsewhere than Linux fork is unsafe (macOS's system libraries), and the workers are
spawned."""

LOCAL_START_S = 1.0
"""Seconds a local cluster costs a batch before its workers take tasks. Forked workers start in
about 0.15 s; a table build then times them on its pilot plate (0.75 s, which its plan counts as
spent). A batch whose tasks take less than that here finishes before the workers could have
been started and timed."""


@dataclass
class Runs:
    """Where :func:`run_tasks` ran a batch's tasks: ``here`` in this process, ``workers`` on
    Dask (a local cluster or the scheduler's)."""

    here: int = 0
    workers: int = 0


def default_workers() -> int:
    """Cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def runner_label(workers: int, scheduler: str | None) -> str:
    """How :func:`run_tasks` runs with these settings, as recorded in a table's provenance."""
    if scheduler:
        return f"dask scheduler {scheduler}"
    return "serial" if workers <= 1 else f"dask LocalCluster, {workers} processes x 1 thread"


def local_cluster(workers: int) -> Any:
    """A Dask ``LocalCluster`` of ``workers`` single-threaded processes (no dashboard port
    taken, quiet logs).

    On Linux the workers are forked from this process (:data:`LOCAL_START_METHOD`), so they
    start with its imported modules and loaded kernels; :func:`dask_setup` then caps their
    thread pools at one thread (the environment of :data:`WORKER_ENV` only reaches what a
    worker imports anew).
    """
    import dask
    from dask.distributed import LocalCluster

    with dask.config.set({"distributed.worker.multiprocessing-method": LOCAL_START_METHOD}):
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                            env=dict(WORKER_ENV), dashboard_address=":0", silence_logs=40,
                            preload=[__name__])


_thread_limit: int | None = None


def limit_threads(threads: int | None) -> None:
    """Threads this package's own passes may use in this process from now on (the inversion's
    grid passes, :mod:`.inference.grid_threads`); None: as many as the process has cores."""
    global _thread_limit
    _thread_limit = threads


def thread_limit() -> int | None:
    """What :func:`limit_threads` set (None: no limit)."""
    return _thread_limit


def dask_setup(worker: Any) -> None:
    """Dask's preload hook, run in each worker of a :func:`local_cluster` as it starts: numba,
    BLAS and this package's own threads (:func:`limit_threads`) at one, which a forked
    worker's inherited pools would not otherwise be.

    A forked worker's numba read its pool's size in this process; numba re-reads the environment
    before each compile and refuses a size that differs from the one its pool was started with,
    so the worker's environment keeps that size, and one thread of the pool runs."""
    import numba
    from numba.core import config
    from threadpoolctl import threadpool_limits

    os.environ["NUMBA_NUM_THREADS"] = str(config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]
    numba.set_num_threads(1)
    threadpool_limits(1)
    limit_threads(1)


def close_later(cluster: Any, waits: contextlib.ExitStack) -> None:
    """Begin closing ``cluster`` in a thread (its processes end while this one goes on) and
    have ``waits`` wait for it when it closes."""
    closer = threading.Thread(target=cluster.close, name="solitonde-cluster-close")
    closer.start()
    waits.callback(closer.join)


def run_tasks(fn: Callable[..., R], tasks: Sequence[tuple[Any, ...]], workers: int,
              scheduler: str | None, *, here_first: bool = False,
              runs: Runs | None = None) -> Iterator[R]:
    """``fn(*task)`` for every task, serially or on Dask; yields results as they complete.

    Serial when ``workers <= 1`` and no scheduler is given; else a :func:`local_cluster` of at
    most one worker a task (closed afterwards) or the cluster at ``scheduler`` (left running).
    With ``here_first`` a batch that would start a local cluster first runs its tasks here, one
    at a time, while the rest at the slowest task's pace here would take no longer than on the
    cluster, its start (:data:`LOCAL_START_S`) counted: a small batch never waits for workers,
    and a large one starts them after its first task. ``runs`` (when given) counts where the
    tasks ran. ``fn`` must be importable by name in a worker process (a module-level function).
    """
    runs = Runs() if runs is None else runs
    if scheduler is None and workers <= 1:
        for task in tasks:
            runs.here += 1
            yield fn(*task)
        return
    queue = list(tasks)
    if scheduler is None and here_first:
        slowest, ran = 0.0, 0
        while queue and (ran == 0 or slowest * len(queue) <= (
                slowest * len(queue) / min(workers, len(queue)) + LOCAL_START_S)):
            started = time.perf_counter()
            result = fn(*queue.pop(0))
            slowest = max(slowest, time.perf_counter() - started)
            ran += 1
            runs.here += 1
            yield result
        if not queue:
            return
    from dask.distributed import Client, as_completed

    cluster = None
    if scheduler is None:
        cluster = local_cluster(min(workers, max(1, len(queue))))
        client = Client(cluster)
    else:
        client = Client(scheduler, timeout="30s")
    try:
        futures = [client.submit(fn, *task, pure=False) for task in queue]
        for future in as_completed(futures):
            done: R = future.result()
            future.release()
            runs.workers += 1
            yield done
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
