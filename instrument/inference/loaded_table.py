"""A model table loaded for estimates, or the reason there is none.

The service runs without a table (measurements come back with ``"estimate": null`` and a
reason), so a missing or broken table file is recorded here instead of raised. Estimates
themselves are made by :func:`solitonde.instrument.inference.pipeline.estimate`.
"""

from __future__ import annotations

import logging
import threading
from pathlib import Path
from typing import cast

from solitonde.instrument.errors import MessageError
from solitonde.instrument.inference.fine_grid import fine_grid
from solitonde.instrument.tables.table import ModelTable, TableSummary
from solitonde.signal.json_ready import json_ready

log = logging.getLogger("solitonde.instrument")


def _load_kernels() -> None:
    """Load the inversion's compiled passes (:mod:`.likelihood_kernel`, :mod:`.posterior_kernel`)
    where numba is loaded (where it is not, the inversion runs without them)."""
    from solitonde.instrument.inference.likelihood import use_compiled

    try:
        if use_compiled():
            from solitonde.instrument.inference import likelihood_kernel, posterior_kernel

            likelihood_kernel.warm()
            posterior_kernel.warm()
    except Exception as exc:  # only a speed-up: the first request then loads them itself
        log.warning("model table: loading the inversion's compiled passes failed: %s", exc)


class EstimateUnavailable(MessageError, RuntimeError):
    """No estimate can be made: no table loaded, or no shots that give an inversion input."""

    subject = "table"


class LoadedTable:
    """A loaded model table with its inversion grids built, or the reason there is none.

    Parameters
    ----------
    table_path:
        HDF5 model table; ``None`` or a missing file gives a LoadedTable without a table (its
        ``reason`` says why).
    """

    def __init__(self, table_path: str | Path | None, warm_up: bool = True) -> None:
        self.path = Path(table_path) if table_path is not None else None
        self.table: ModelTable | None = None
        self.reason: str | None = None
        if self.path is None:
            self.reason = "no model table configured (start with --table FILE)"
            return
        if not self.path.is_file():
            self.reason = f"model table {str(self.path)!r} does not exist"
            return
        try:
            self.table = ModelTable.load(self.path)
        except Exception as exc:  # a broken table must not stop the service; report why
            self.reason = f"model table {str(self.path)!r} could not be loaded: {exc}"
            log.warning(self.reason)
            return
        if warm_up:  # a service does it once at start; a command line inverts once
            self._warm_up()

    def _warm_up(self) -> None:
        """Build the inversion's fine grids now, not in the first request that needs them, and
        start loading (on a fresh install: compiling, about 2 s) the inversion's compiled passes
        in the background: the service is ready meanwhile, and a request that needs them before
        they are loaded waits only for the rest."""
        for i in range(len(self.model.axes["diameter_m"])):
            try:
                fine_grid(self.model, i)
            except Exception as exc:  # a sphere size the inversion cannot use: say so, go on
                log.warning("model table: no inversion grid for diameter index %d: %s", i, exc)
        threading.Thread(target=_load_kernels, daemon=True, name="inversion warm-up").start()

    @property
    def loaded(self) -> bool:
        return self.table is not None

    @property
    def model(self) -> ModelTable:
        """The table itself; only for a LoadedTable that :attr:`loaded` (a TableSet holds no
        other)."""
        if self.table is None:
            raise EstimateUnavailable(self.reason or "no model table loaded")
        return self.table

    def plate_size(self) -> list[float] | None:
        """The plate size (m) of the table's scenes, or None without a table."""
        if not hasattr(self, "_plate_size"):
            summary = self.summary()
            provenance = (summary["provenance"] if summary else None) or {}
            plate = (provenance.get("scene_defaults") or {}).get("plate") or {}
            size = plate.get("size")
            self._plate_size = [float(s) for s in size] if size else None
        return self._plate_size

    def summary(self) -> TableSummary | None:
        """The table's axes and provenance, JSON-ready."""
        if self.table is None:
            return None
        return cast(TableSummary, json_ready(self.table.summary()))
