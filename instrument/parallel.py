"""The instrument's one parallel executor: independent tasks run serially, on a local Dask cluster
or on an existing Dask cluster, and their results are handed back as they complete.

Table builds, the studies (the paper's reproduction, validation, map studies) and any other batch
the instrument spreads over cores go through :func:`run_tasks`. A local cluster runs one process
per worker with one thread each (:data:`WORKER_ENV` caps numba, BLAS and OpenMP at one thread:
the cores are the workers); an existing cluster is addressed by its scheduler
(``tcp://host:port``) and left running. Results come back in finishing order; a caller that needs
one order whatever the worker count sorts them (or keys them) itself.

The model's own pool (:mod:`solitonde.model.batch`, a forked process pool or threads) stays in the
model, which imports nothing of the instrument.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from typing import Any, TypeVar

#: Environment of Dask worker processes: one compute thread each (the cores are the workers).
WORKER_ENV = {
    "NUMBA_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
}

R = TypeVar("R")


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
    taken, quiet logs)."""
    from dask.distributed import LocalCluster

    return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                        env=dict(WORKER_ENV), dashboard_address=":0", silence_logs=40)


def run_tasks(fn: Callable[..., R], tasks: Sequence[tuple[Any, ...]], workers: int,
              scheduler: str | None) -> Iterator[R]:
    """``fn(*task)`` for every task, serially or on Dask; yields results as they complete.

    Serial when ``workers <= 1`` and no scheduler is given; else a :func:`local_cluster` of at
    most one worker a task (closed afterwards) or the cluster at ``scheduler`` (left running).
    ``fn`` must be importable by name in a worker process (a module-level function).
    """
    if scheduler is None and workers <= 1:
        for task in tasks:
            yield fn(*task)
        return
    from dask.distributed import Client, as_completed

    cluster = None
    if scheduler is None:
        cluster = local_cluster(min(workers, max(1, len(tasks))))
        client = Client(cluster)
    else:
        client = Client(scheduler, timeout="30s")
    try:
        futures = [client.submit(fn, *task, pure=False) for task in tasks]
        for future in as_completed(futures):
            result: R = future.result()
            future.release()
            yield result
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
