"""One path from measured shots to an estimate, typed from end to end.

    features per shot --summarise--> [SizeSummary] --estimate(tables, ...)--> TableEstimate

``analyze --invert``, ``invert``, ``calibrate``, ``POST /v1/measurements``, ``POST /v1/invert``
and plate maps all go through :func:`estimate`; dictionaries appear only where data leaves or
enters (JSON over HTTP and on the command line, the measurement store). A sphere size whose shots
show no reflection still gives an input, the ARR bound of its hidden reflection (a reflection
that small bounds the thickness from above); one that gives none (no size in the metadata, no
reflection and no bound) is left out with its reason in ``TableEstimate.skipped``; the other
sizes are still inverted.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NotRequired, TypedDict, cast

from solitonde.instrument.inference.calibration import Calibration
from solitonde.instrument.inference.estimate import Estimate, EstimateDict
from solitonde.instrument.inference.inversion import invert
from solitonde.instrument.inference.inversion_inputs import FeatureSummary
from solitonde.instrument.inference.loaded_table import EstimateUnavailable, LoadedTable
from solitonde.instrument.inference.table_set import TableSet
from solitonde.signal.features import (
    EARLY_REASON,
    SATURATED_REASON,
    TRUNCATED_REASON,
    UNSTEADY_REASON,
    Aggregate,
    Features,
    aggregate,
)
from solitonde.signal.json_ready import json_ready


class StatDict(TypedDict):
    """One feature's mean, sample standard deviation and count over the kept shots."""

    mean: float | None
    std: float | None
    count: int


class RejectedShot(TypedDict):
    """A shot an aggregate left out: the feature that condemned it, its value and why."""

    index: int
    feature: str
    value: float | None
    modified_z: float | None
    reason: str
    source: NotRequired[str]
    """Where `analyze` names the shot: its file and shot number."""
    shot: NotRequired[Any]


class AggregateDict(TypedDict):
    """:meth:`~solitonde.signal.features.Aggregate.to_dict`'s keys: the shot count, one
    :class:`StatDict` per summarised feature, what was left out and why."""

    n_shots: int
    tof_s: StatDict
    arr: StatDict
    incident_time_s: StatDict
    reflected_time_s: StatDict
    incident_peak_N: StatDict
    reflected_peak_N: StatDict
    snr_db: StatDict
    rejected: list[RejectedShot]
    no_reflection: list[int]
    arr_upper_bound: float | None
    flag_counts: dict[str, int]
    reflection_window_s: float | None


class SizeSummaryDict(AggregateDict):
    """A sphere size's summary as stored and served (``aggregates`` of a measurement):
    ``sphere_diameter``, then the aggregate's keys."""

    sphere_diameter: float | None


MISSING_SIZE = "metadata.sphere_diameter is missing: the inversion needs the sphere size"
"""Why shots without a sphere size give no input (the command line names its flag instead)."""


ALL_TRUNCATED = "every shot is truncated"
ALL_SATURATED = "every shot is saturated"
ALL_EARLY = "every shot is early_reflection"
ALL_UNSTEADY = "every shot is unsteady_baseline"
ALL_REJECTED = "every shot is rejected"
"""Where a size's skip reason says its records cannot be read (too short, clipped, another chain,
a jumping level, or a mix of these): ``analyze --invert`` then exits 1."""


def no_reflection(diameter_m: float) -> str:
    """Why a sphere size whose shots show no reflection is left out."""
    return (f"no shot with D = {diameter_m} m has a detected reflection (no TOF, no ARR); see "
            "the aggregate's arr_upper_bound")


@dataclass(frozen=True)
class SizeSummary:
    """The shots of one sphere size at one position: their aggregate (outliers reported, shots
    without a reflection counted) and, through :meth:`inputs`, what the inversion reads."""

    diameter_m: float | None
    aggregate: Aggregate

    def skip_reason(self) -> str | None:
        """Why these shots give no inversion input, or None when they give one."""
        if self.diameter_m is None:
            return MISSING_SIZE
        implausible = [r for r in self.aggregate.rejected
                       if str(r.get("reason", "")).startswith("implausible_units")]
        if implausible and len(implausible) == self.aggregate.n_shots:
            return (f"sphere_diameter {self.diameter_m:g} m: every shot is implausible_units "
                    "(its incident's width and force disagree with this chain's solitary wave: "
                    "check the calibration, the units of the file's force and time columns)")
        for reason, every in ((TRUNCATED_REASON, ALL_TRUNCATED),
                              (SATURATED_REASON, ALL_SATURATED), (EARLY_REASON, ALL_EARLY),
                              (UNSTEADY_REASON, ALL_UNSTEADY)):
            these = [r for r in self.aggregate.rejected if r.get("reason") == reason]
            if self.hidden and these and len(these) == self.aggregate.n_shots:
                return (f"sphere_diameter {self.diameter_m:g} m: {every}"
                        f"{reason[reason.index(':'):]}")
        flagged = [str(r["reason"]).split(":")[0] for r in self.aggregate.rejected
                   if r.get("modified_z") is None]
        if self.hidden and flagged and len(flagged) == self.aggregate.n_shots:
            counts = ", ".join(f"{name} {flagged.count(name)}" for name in dict.fromkeys(flagged))
            return (f"sphere_diameter {self.diameter_m:g} m: {ALL_REJECTED} ({counts}); see the "
                    "aggregate's rejected shots for each reason")
        if self.hidden and self.aggregate.arr_upper_bound is None:
            return no_reflection(self.diameter_m)
        return None

    @property
    def hidden(self) -> bool:
        """Whether no shot shows a reflection (the input is then the ARR bound alone)."""
        return self.aggregate["tof_s"].mean is None or self.aggregate["arr"].mean is None

    def inputs(self) -> FeatureSummary:
        """Mean TOF and ARR with their shot scatter and count, or for shots without a
        reflection the ARR bound of the hidden one (EstimateUnavailable if neither)."""
        reason = self.skip_reason()
        if reason is not None:
            raise EstimateUnavailable(reason)
        assert self.diameter_m is not None  # skip_reason() says so otherwise
        if self.hidden:
            assert self.aggregate.arr_upper_bound is not None  # likewise
            return FeatureSummary(float(self.diameter_m), None, None,
                                  n_shots=max(int(self.aggregate.n_shots), 1),
                                  arr_upper_bound=float(self.aggregate.arr_upper_bound),
                                  tof_window_s=self.aggregate.reflection_window_s)
        tof, arr = self.aggregate["tof_s"], self.aggregate["arr"]
        assert tof.mean is not None and arr.mean is not None  # not hidden
        return FeatureSummary(float(self.diameter_m), float(tof.mean), float(arr.mean),
                              tof.std, arr.std, max(int(tof.count), 1))

    def to_dict(self) -> SizeSummaryDict:
        """The stored and served form: ``sphere_diameter`` then the aggregate's fields."""
        return cast(SizeSummaryDict, json_ready({"sphere_diameter": self.diameter_m,
                                                 **self.aggregate.to_dict()}))


def summarise(diameters: Sequence[float | None],
              features: Sequence[Features]) -> list[SizeSummary]:
    """One summary per sphere diameter (the inversion combines sizes, never mixes them), in the
    order the sizes first appear; ``diameters[i]`` is shot i's sphere size (None if unknown)."""
    groups: dict[float | None, list[Features]] = {}
    for d, f in zip(diameters, features, strict=True):
        groups.setdefault(None if d is None else float(d), []).append(f)
    return [SizeSummary(d, aggregate(members)) for d, members in groups.items()]


class SkippedSize(TypedDict):
    """A sphere size an estimate leaves out, and why."""

    sphere_diameter: float | None
    reason: str


class TableEstimateDict(EstimateDict):
    """An estimate's JSON form with the table it used and the sphere sizes left out."""

    table: str
    skipped: list[SkippedSize]


@dataclass
class TableEstimate:
    """An inversion's estimate, the table it used and the sphere sizes left out (and why)."""

    estimate: Estimate
    table_id: str
    skipped: list[SkippedSize] = field(default_factory=list)

    def to_dict(self, posterior: bool = False) -> TableEstimateDict:
        """The estimate's JSON form (:class:`~.estimate.EstimateDict`) with ``table`` and
        ``skipped``, JSON-ready."""
        return cast(TableEstimateDict, json_ready({**self.estimate.to_dict(posterior=posterior),
                                                   "table": self.table_id,
                                                   "skipped": self.skipped}))


def estimate(
    tables: TableSet,
    summaries: Sequence[SizeSummary | FeatureSummary],
    calibration: Calibration | Mapping[str, Any] | None = None,
    *,
    table: str | LoadedTable | None = None,
    plate_material: Any = None,
    posterior: bool = False,
    skipped: Sequence[Mapping[str, Any]] = (),
) -> TableEstimate:
    """Thickness and distance to the support from per-size summaries, against the table of
    their family (:meth:`TableSet.choose`: named by ``table`` or ``plate_material``, else the
    one that covers the sizes; a table a caller already chose is used as it is).

    ``skipped`` lists sizes the caller already left out (``{"sphere_diameter", "reason"}``).
    ``plate_material`` (a library name or a property mapping, which may state its spread) also
    sets the material spread the intervals carry; without it, the library's for the table's
    plate material (instrument.inference.material_spread).

    Raises
    ------
    EstimateUnavailable
        No table is loaded, or no size gives an inversion input (the reasons joined).
    TableChoiceError
        No table fits, or several could and none is named.
    InversionError, TableError, CalibrationError
        The inversion refuses the inputs or the calibration.
    """
    if not tables.loaded:
        raise EstimateUnavailable(tables.reason or "no model table loaded")
    inputs: list[FeatureSummary] = []
    left_out = [cast(SkippedSize, dict(s)) for s in skipped]  # as the docstring says
    for s in summaries:
        if isinstance(s, FeatureSummary):
            inputs.append(s)
        elif (reason := s.skip_reason()) is not None:
            left_out.append({"sphere_diameter": s.diameter_m, "reason": reason})
        else:
            inputs.append(s.inputs())
    if not inputs:
        raise EstimateUnavailable("; ".join(s["reason"] for s in left_out)
                                  or "no shot gave a usable TOF")
    from solitonde.instrument.inference.material_spread import spread_of

    chosen = (table if isinstance(table, LoadedTable)
              else tables.choose([i.diameter_m for i in inputs], table, plate_material))
    result = invert(chosen.model, inputs, calibration, return_posterior=posterior,
                    material_spread=spread_of(chosen.model, plate_material))
    return TableEstimate(result, chosen.model.table_id, left_out)
