"""Background jobs whose progress any worker process can answer for.

A job's state lives in the store's ``jobs`` table (written after every step), not in the
process that runs it: with several uvicorn workers, ``GET /v1/jobs/{id}`` reaches any of them.
A job runs in a daemon thread of the process that accepted it; should that process stop, the
job's ``updated_at`` stops moving and :func:`get` reports it ``stalled``.
"""

from __future__ import annotations

import json
import logging
import threading
import time
import uuid
from collections.abc import Callable
from typing import Literal, NotRequired, TypedDict

from solitonde.instrument.inference.setups import SetupReference
from solitonde.instrument.service.store import Store

log = logging.getLogger("solitonde.instrument")

STALLED_AFTER_S = 600.0
"""A running job whose state has not moved for this long is reported ``stalled``: the process
that ran it is gone (a restart), and its remaining steps will not run."""

class Failure(TypedDict):
    """A step that failed (a measurement by its id) and why."""

    id: int
    reason: str


class Steps(TypedDict, total=False):
    """The fields a job's work reports after a step, and returns at its end."""

    done: int
    total: int
    failed: list[Failure]


class Detail(TypedDict, total=False):
    """What a kind of job adds to its record: the set-up revision (``{"id", "revision"}``) a
    recalibration is for."""

    setup: SetupReference


class JobLinks(TypedDict):
    self: str


JobState = Literal["queued", "running", "done", "failed", "stalled"]


class Job(TypedDict):
    """A job's record as stored in the ``jobs`` table and served by ``GET /v1/jobs/{id}``."""

    id: str
    kind: str
    state: JobState
    total: int
    done: int
    failed: list[Failure]
    created_at: float
    finished_at: float | None
    setup: NotRequired[SetupReference]
    links: JobLinks
    updated_at: NotRequired[float]
    """Set on every write."""
    error: NotRequired[str]
    """Why a ``failed`` job stopped."""


Progress = Callable[[Steps], None]
"""What a job's work calls after each step with the fields to update."""


def _write(store: Store, job: Job) -> None:
    job["updated_at"] = time.time()
    with store.transaction() as c:
        c.execute("INSERT INTO jobs (id, created_at, updated_at, body) VALUES (?, ?, ?, ?) "
                  "ON CONFLICT (id) DO UPDATE SET updated_at = excluded.updated_at, "
                  "body = excluded.body",
                  (job["id"], job["created_at"], job["updated_at"], json.dumps(job)))


def get(store: Store, job_id: str) -> Job | None:
    """A job's state as last written, or None."""
    rows = store.rows("SELECT body FROM jobs WHERE id = ?", (job_id,))
    if not rows:
        return None
    job: Job = json.loads(rows[0][0])
    if job["state"] in ("queued", "running") and time.time() - job["updated_at"] > \
            STALLED_AFTER_S:
        job["state"] = "stalled"
    return job


def start(store: Store, kind: str, total: int, detail: Detail,
          work: Callable[[Progress], Steps]) -> Job:
    """Record a job (``queued``) and run ``work`` in a background thread; the job as recorded.

    ``work(progress)`` does the steps, calling ``progress({...})`` after each with the fields
    that changed (``done``, ``failed`` ...); what it returns is merged into the final state
    (``done``). An exception ends the job ``failed`` with its message."""
    job_id = uuid.uuid4().hex
    job: Job = {"id": job_id, "kind": kind, "state": "queued",
                "total": total, "done": 0, "failed": [], "created_at": time.time(),
                "finished_at": None, **detail,
                "links": {"self": f"/v1/jobs/{job_id}"}}
    _write(store, job)

    def progress(changes: Steps) -> None:
        job.update(changes)
        job["state"] = "running"
        _write(store, job)

    def run() -> None:
        try:
            job["state"] = "running"
            _write(store, job)
            job.update(work(progress))
            job["state"] = "done"
        except Exception as exc:  # the job's answer says why; the service goes on
            log.exception("job %s failed", job["id"])
            job["state"], job["error"] = "failed", f"{type(exc).__name__}: {exc}"
        job["finished_at"] = time.time()
        _write(store, job)

    thread = threading.Thread(target=run, name=f"job-{kind}", daemon=True)
    with _running_lock:
        _running.add(thread)
    thread.start()
    return job.copy()


_running: set[threading.Thread] = set()
_running_lock = threading.Lock()


def finish(timeout_s: float = 60.0) -> None:
    """Wait (up to ``timeout_s`` in all) for this process's jobs to end, before the store they
    write to closes; a job still running then is left ``stalled`` for its record to say."""
    import time as _time

    deadline = _time.monotonic() + timeout_s
    with _running_lock:
        threads = list(_running)
    for thread in threads:
        thread.join(max(0.0, deadline - _time.monotonic()))
    with _running_lock:
        _running.difference_update(t for t in threads if not t.is_alive())
