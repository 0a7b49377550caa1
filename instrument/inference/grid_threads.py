"""The fine grid's heaviest compiled pass split into bands of thickness rows, run on two threads
at once.

Adding the likelihood's terms streams every term's per-cell arrays (about 14 MB for three sphere
sizes with the material's spread) from memory: one core waits on memory for about half of the
pass. Two threads, each adding every term over its own band of rows, take the pass in about two
thirds of the time; each cell sees the same operations in the same order, so the numbers are the
same to the bit. The kernel releases the GIL (``nogil``), so the bands run in parallel from
Python threads, which (unlike numba's own ``parallel`` pools) any number of the service's request
threads may do at once.

A process meant to use one core (a local cluster's Dask worker in a table build or a study: its
preload hook limits it) runs the pass whole on its own thread.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor, wait
from itertools import pairwise
from typing import Any

from solitonde.instrument.parallel import default_workers, thread_limit

MAX_THREADS = 2
"""Bands per pass: memory, not arithmetic, bounds the pass, and two cores' streams are most of
what it gains (three sizes with the spread, the logs and the sum included: about 2.2 ms on one
thread, 1.2-1.5 ms on two)."""

MIN_ROWS = 64
"""A grid with fewer thickness rows runs whole: handing a band to a thread costs about 50 us."""

_pool: tuple[int, ThreadPoolExecutor] | None = None
_lock = threading.Lock()


def threads() -> int:
    """How many bands a pass is split into in this process: its cores (or the limit a Dask
    worker's hook set, :func:`solitonde.instrument.parallel.limit_threads`), at most
    :data:`MAX_THREADS`."""
    limit = thread_limit()
    if limit is None:
        limit = default_workers()
    return max(1, min(limit, MAX_THREADS))


def _helpers() -> ThreadPoolExecutor:
    """The process's helper threads, made on first use; a forked child (a Dask worker) makes its
    own, since a fork copies the pool's object but not its thread."""
    global _pool
    with _lock:
        if _pool is None or _pool[0] != os.getpid():
            _pool = (os.getpid(), ThreadPoolExecutor(MAX_THREADS - 1,
                                                     thread_name_prefix="solitonde-grid"))
        return _pool[1]


def bands(n_rows: int, parts: int) -> list[tuple[int, int]]:
    """``parts`` consecutive row ranges ``(start, stop)`` covering ``0..n_rows-1``, as even as
    whole rows allow."""
    edges = [n_rows * k // parts for k in range(parts + 1)]
    return [(a, b) for a, b in pairwise(edges) if b > a]


def run_in_bands(kernel: Callable[..., Any], n_rows: int, *args: Any) -> None:
    """``kernel(*args, start, stop)`` over every band of the ``n_rows`` rows: the first band on
    this thread, the others on a helper thread, returning when all are done. A band the helper
    has not started by the time this thread is done with its own (every core busy, or another
    request's band ahead of it), or cannot take (the interpreter shutting down), runs here
    instead, so a busy machine costs no more than one thread would. An error in this thread's
    band is raised once the helper has stopped (nothing writes the arrays after this returns);
    else the first error of the other bands, in row order. The kernel must write only its own
    rows."""
    parts = threads() if n_rows >= MIN_ROWS else 1
    first, *others = bands(n_rows, parts)
    pending: list[tuple[Future[Any] | None, tuple[int, int]]] = []
    for span in others:
        try:
            pending.append((_helpers().submit(kernel, *args, *span), span))
        except RuntimeError:  # no new threads while the interpreter shuts down
            pending.append((None, span))
    try:
        kernel(*args, *first)
    except BaseException:
        for future, _ in pending:
            if future is not None:
                future.cancel()
        wait([future for future, _ in pending if future is not None])
        raise
    for future, span in pending:
        if future is None or future.cancel():
            kernel(*args, *span)
        else:
            future.result()
