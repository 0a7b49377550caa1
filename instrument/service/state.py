"""What the service's routes share while it runs: the :class:`Service` record and its lanes.

The lifespan in :mod:`.app` makes one Service and puts it on the application; every route gets
it through :data:`.dependencies.ServiceDep`. Kept apart from :mod:`.app` so that routes never
import the application that includes them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from solitonde.instrument.inference.table_set import TableSet
from solitonde.instrument.service.api_models import Strict
from solitonde.instrument.service.settings import Settings
from solitonde.instrument.service.store import Store
from solitonde.instrument.service.uploads import UploadDir

INGEST_THREADS = 1
"""Worker threads per process that parse, measure and store posted shots (one FIFO lane).

The ingest holds the GIL most of the time, so more threads add no throughput: they only share
the interpreter in 5 ms switch slices in no particular order, so a request can wait behind
later ones. One lane serves them in arrival order (equal shots wait about equally long) and
costs less switching; the event loop still reads bodies and answers ``/healthz`` meanwhile.
Uploaded files get a lane of their own (:attr:`Service.upload_lane`).
"""
PLOT_THREADS = 2
"""Plots drawn at the same time per process."""
LARGE_UPLOAD_BYTES = 4 * 1024 * 1024
"""Uploads above this size (4 MiB) have a lane of their own (:attr:`Service.lane_for`)."""


@dataclass
class Service:
    """What the routes share: settings, store, model tables, request models, upload folder."""

    settings: Settings
    store: Store
    tables: TableSet
    """The model tables loaded at start (none, one or several plate families)."""
    uploads: UploadDir
    shot_model: type[Strict]
    measurement_model: type[Strict]
    ingest_lane: Any = None
    """``anyio.CapacityLimiter`` the JSON and binary ingest runs under (made in the lifespan)."""
    upload_lane: Any = None
    """The same for uploaded files, which can take seconds: shots never queue behind them."""
    large_upload_lane: Any = None
    """Uploads larger than :data:`LARGE_UPLOAD_BYTES`, one at a time: a 60 MB file takes a
    second or two and a few hundred MB to read, and an ordinary upload does not wait for it."""
    plot_lane: Any = None
    """Plots (PNG of a trace or a map), :data:`PLOT_THREADS` at a time; a plot whose client
    left while it waited is skipped (:func:`.work_lanes.run_for_client`)."""

    def lane_for(self, size: int | None) -> Any:
        """The lane an upload of ``size`` bytes is parsed in."""
        if size is not None and size > LARGE_UPLOAD_BYTES and self.large_upload_lane is not None:
            return self.large_upload_lane
        return self.upload_lane

    def close(self) -> None:
        from solitonde.instrument.service import jobs

        jobs.finish()  # a recalibration's last writes land before the store closes
        self.store.close()
        self.uploads.close()

