"""The map study's simulated positions (:class:`Measurer`, measured as
:func:`.validate.measure_plate` measures them, kept in a file) and the chain calibration fitted
on two reference plates, as :mod:`.validate` fits it."""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, NotRequired, TypedDict

import numpy as np

from solitonde.instrument.errors import InstrumentError
from solitonde.instrument.inference.calibration import Calibration
from solitonde.instrument.inference.calibration_fit import Reference, fit_calibration
from solitonde.instrument.inference.inversion_inputs import FeatureSummary
from solitonde.instrument.parallel import run_tasks
from solitonde.instrument.studies import validate as single
from solitonde.instrument.studies.validate_scores import MeasuredPlate, MeasuredSize
from solitonde.instrument.tables.table import ModelTable
from solitonde.signal.atomic import write_text
from solitonde.signal.features import AGGREGATE_VERSION, EXTRACTOR_VERSION


class MeasurementsFile(TypedDict):
    """A study's kept positions as its file holds them: the scene they were simulated on, each
    position's measured sizes (:meth:`Measurer.key`), the extractor's reading and, for truths on
    the 3-D plate, how that plate was meshed (:data:`.validate.TRUTH_MESH`)."""

    scene: Mapping[str, Any]
    positions: dict[str, dict[str, MeasuredSize | None]]
    reading_version: int
    aggregate_version: NotRequired[int]
    truth_mesh: NotRequired[str]


class StudyInputError(InstrumentError, ValueError):
    """A study request that cannot be run; ``field`` names what is wrong."""


class Measurer:
    """Simulated positions, measured as :func:`.validate.measure_plate` measures them; kept
    in a file (optional) so that a study can be re-scored without simulating again. The file
    records the scene its positions were simulated on (the truths' plate theory among it) and
    the extractor's reading and the rule that summarised their repeated shots: a file of another
    scene, reading or rule is refused, not mixed in."""

    def __init__(self, base: Mapping[str, Any], path: str | Path | None) -> None:
        self.base = dict(base)
        self.path = Path(path) if path is not None else None
        self.cache: dict[str, dict[str, MeasuredSize | None]] = {}
        """Per :meth:`key`, each sphere size's (as text) measured summary."""
        if self.path is not None and self.path.is_file():
            try:
                data = json.loads(self.path.read_text(encoding="utf-8"))
                self.cache = data["positions"]
                # files written before the scene was recorded hold the table's own tiers
                stored = data.get("scene")
                reading = int(data.get("reading_version", 1))
                rule = int(data.get("aggregate_version", 1))
            except (OSError, ValueError, KeyError, TypeError) as exc:
                raise StudyInputError("measurements", f"{str(self.path)!r} is not a file this "
                                      f"study wrote ({exc}); delete it or give another") from None
            if (stored is None and single.plate_theory(self.base) != "auto") or (
                    stored is not None and stored != json.loads(json.dumps(self.base))):
                raise StudyInputError("measurements", f"{str(self.path)!r} holds positions "
                                      f"simulated on another scene (its sem.plate_theory "
                                      f"{single.plate_theory(stored or {})!r}, this study's "
                                      f"{single.plate_theory(self.base)!r}); give another file")
            if (single.plate_theory(self.base) == "3d"
                    and data.get("truth_mesh") != single.TRUTH_MESH):
                raise StudyInputError("measurements", f"{str(self.path)!r} holds positions "
                                      "simulated on the 3-D plate's default mesh, coarser than "
                                      "the truths' (the flexural-wavelength rule); give "
                                      "another file")
            if reading != EXTRACTOR_VERSION:
                raise StudyInputError("measurements", f"{str(self.path)!r} holds positions read "
                                      f"with the extractor's reading {reading}, this solitonde "
                                      f"reads with {EXTRACTOR_VERSION}; give another file")
            if rule != AGGREGATE_VERSION:
                raise StudyInputError("measurements", f"{str(self.path)!r} holds positions whose "
                                      f"repeated shots were summarised by rule {rule} (before "
                                      "the outlier level depended on the number of shots), "
                                      f"this solitonde by rule {AGGREGATE_VERSION}; give "
                                      "another file")
        self.simulated = 0
        self.wall_s = 0.0

    @staticmethod
    def key(d: float, t: float, length: float, seed: int) -> str:
        return f"{d:.6e}|{t:.9e}|{length:.9e}|{seed}"

    def prefetch(self, requests: Sequence[tuple[float, float, float, int]], workers: int,
                 progress: Callable[[str, int, int], None] | None = None) -> None:
        """Simulate the requested ``(d, t, length, seed)`` not yet kept, ``workers`` at a time
        (a study's positions are independent runs)."""
        todo = {self.key(*r): r for r in requests if self.key(*r) not in self.cache}
        if not todo:
            return
        started = time.perf_counter()
        tasks = [(self.base, [d], t, max(length, 0.0), seed, k)
                 for k, (d, t, length, seed) in todo.items()]
        for done, (key, m) in enumerate(run_tasks(_measure_keyed, tasks, workers, None), 1):
            self.cache[key] = {str(k): v for k, v in m["summaries"].items()}
            self.simulated += 1
            if progress is not None:
                progress("positions simulated", done, len(tasks))
        self.wall_s += time.perf_counter() - started

    def __call__(self, d: float, t: float, length: float, seed: int) -> list[FeatureSummary]:
        key = self.key(d, t, length, seed)
        self.prefetch([(d, t, length, seed)], 1)
        return [FeatureSummary(s["diameter_m"], s["tof_s"], s["arr"], s["tof_std_s"],
                               s["arr_std"], int(s["n_shots"]), s.get("arr_upper_bound"))
                for s in self.cache[key].values() if s is not None]

    def save(self) -> None:
        if self.path is None:
            return
        data: MeasurementsFile = {"scene": self.base, "positions": self.cache,
                                  "reading_version": EXTRACTOR_VERSION,
                                  "aggregate_version": AGGREGATE_VERSION}
        if single.plate_theory(self.base) == "3d":
            data["truth_mesh"] = single.TRUTH_MESH
        write_text(self.path, json.dumps(data))


def _measure_keyed(base: Mapping[str, Any], diameters: Sequence[float], t: float,
                   length: float, seed: int, key: str) -> tuple[str, MeasuredPlate]:
    """:func:`.validate.measure_plate` with the key it is kept under (results come back in the
    order they finish)."""
    return key, single.measure_plate(base, diameters, t, length, seed)


def references(table: ModelTable, d: float, seed: int
                ) -> list[tuple[float, float, float, int]]:
    """The two reference plates' ``(d, t, length, seed)``: far from the supports, as
    :mod:`.validate` places them."""
    t_axis, l_axis = table.axes["thickness_m"], table.axes["distance_m"]
    l_ref = float(np.clip(single.REFERENCE_DISTANCE_M, l_axis[0], l_axis[-1]))
    return [(d, float(np.clip(t_ref, t_axis[0], t_axis[-1])), l_ref, seed + k)
            for k, t_ref in enumerate((single.REFERENCE_THICKNESS_M,
                                       single.REFERENCE2_THICKNESS_M))]


def reference_calibration(table: ModelTable, measure: Measurer, d: float, seed: int) -> Calibration:
    """The chain's damping, an ARR factor and TOF offset fitted on two reference plates, as
    :mod:`.validate` does."""
    refs = []
    for d_ref, t_ref, l_ref, s_ref in references(table, d, seed):
        refs += [Reference(t_ref, l_ref, s) for s in measure(d_ref, t_ref, l_ref, s_ref)
                 if not s.hidden]
    return fit_calibration(table, refs)
