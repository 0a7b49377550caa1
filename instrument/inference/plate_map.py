"""A plate's map: its positions with their estimates, and the clamped edge they locate.

The service and `solitonde map` build the same JSON: per position (a plate's measurements that
share a position name and coordinates) the coordinates, shot count and estimate, then the support
the positions' distance answers imply (instrument.inference.edge_fit) or null with the reason.
In the service the shots of every measurement at a position are summarised together and
inverted once (a position of one measurement keeps its stored answer); from an estimates file
each row is already one position.

Asked for (:class:`JointOptions`), the scan is also inverted as one unknown
(instrument.inference.joint_map: the plate's edges and every position's thickness from each
position's per-size summaries) and the next positions to measure are chosen
(instrument.inference.suggest); :func:`with_joint` adds both to the same JSON.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal, NotRequired, TypedDict, cast

from solitonde.instrument.inference import measured_shots
from solitonde.instrument.inference.calibration import Calibration
from solitonde.instrument.inference.edge_fit import SupportFitDict, locate
from solitonde.instrument.inference.inversion_inputs import FeatureSummary
from solitonde.instrument.inference.joint_map import (
    DEFAULT_SPREAD,
    JointMapError,
    ScanPosition,
    ThicknessPrior,
)
from solitonde.instrument.inference.joint_map import posterior as joint_posterior
from solitonde.instrument.inference.joint_map import summary as joint_summary
from solitonde.instrument.inference.joint_model import EdgeModelRow, ThicknessPriorRow
from solitonde.instrument.inference.joint_summary import JointFit, JointPositionRow, JointSupport
from solitonde.instrument.inference.loaded_table import EstimateUnavailable
from solitonde.instrument.inference.marginals import ParameterDict
from solitonde.instrument.inference.pipeline import (
    SizeSummary,
    TableEstimateDict,
    summarise,
)
from solitonde.instrument.inference.pipeline import estimate as estimate_from
from solitonde.instrument.inference.suggest import Suggestion, check_request
from solitonde.instrument.inference.suggest import describe as describe_gain
from solitonde.instrument.inference.suggest import suggest as suggest_positions
from solitonde.instrument.inference.table_set import TableSet

Parameter = Literal["thickness_m", "distance_m"]
PARAMETERS: tuple[Parameter, ...] = ("thickness_m", "distance_m")


class _PlacedPosition(TypedDict):
    position: str | None
    x_m: float | None
    y_m: float | None
    n_shots: int


class MapPosition(_PlacedPosition, total=False):
    """One position of the map (:func:`position_entry`): its place and shot count, then, in
    this order as the entry is built, the measurements it pools, its estimate reduced to what
    a map shows (its ``reason`` where there is none), its readings and warnings; a map adds
    where the located edge puts it and, jointly, its own answer and why it was left out."""

    measurement_ids: list[int]
    last_activity: str | None
    thickness_m: ParameterDict | None
    distance_m: ParameterDict | None
    reason: str | None
    readings: list[Any]
    warnings: list[str]
    distance_to_located_support_m: float
    per_position: dict[str, ParameterDict | None]
    joint_reason: str


class SuggestionsBasis(TypedDict):
    """What a map's suggestions are chosen for: :class:`~.suggest.Suggestions` less the
    positions, and what ``expected_gain`` measures, in words."""

    objective: str
    reason: NotRequired[str]
    interval_95_m: NotRequired[float]
    expected_interval_95_m: NotRequired[float]
    thickness_m: NotRequired[float]
    expected_gain: str


class _PlateMapBase(TypedDict):
    plate_id: str
    plate_size_m: list[float] | None
    n_positions: int
    n_scan_positions: int
    support: SupportFitDict | JointSupport | None
    support_reason: str | None


class MapOverview(_PlateMapBase, total=False):
    """A plate's map less its positions (as a report keeps it): the located support, or null
    and why, with what :func:`with_joint` adds after, in this order: whether the answer is
    joint, then the joint fit, warnings, thickness prior, edge model and table, then the
    suggestions (or why a report's joint answer failed)."""

    joint: bool
    fit: JointFit
    warnings: list[str]
    thickness_prior: ThicknessPriorRow
    edges: EdgeModelRow
    table: str
    suggestions: list[Suggestion]
    suggestions_basis: SuggestionsBasis
    joint_reason: str


class PlateMap(MapOverview):
    """A plate's map (:func:`build`): :class:`MapOverview`'s keys with the positions, which
    come after ``n_scan_positions``."""

    positions: list[MapPosition]


class _RowEstimate(TypedDict, total=False):
    """An estimates file's row read back as an estimate (:func:`from_estimate_rows`)."""

    thickness_m: ParameterDict
    distance_m: ParameterDict
    readings: list[Any]


def by_position(records: Sequence[Any]) -> dict[tuple[Any, Any, Any], list[Any]]:
    """A plate's stored measurements grouped by place, (position, x_m, y_m), as the
    measured-shot road groups shots (instrument.inference.measured_shots.position_key)."""
    return measured_shots.by_position(records, lambda r: measured_shots.position_key(
        {"position": r.position, **(r.result.get("location") or {})})[1:])


@dataclass(frozen=True)
class PositionInputs:
    """What one position of a plate's stored measurements is estimated from: the shots of all
    its measurements summarised per sphere size (the upload's own road), and the table, chain
    calibration and plate material its newest measurement was estimated with."""

    summaries: list[SizeSummary]
    table: str | None
    calibration: Calibration | None
    plate_material: Any


def position_inputs(members: Sequence[Any]) -> PositionInputs:
    """The :class:`PositionInputs` of a position's measurements (records with their shots)."""
    from solitonde.signal.features import Features

    diameters, features = [], []
    for shot in (s for m in members for s in m.shots):
        try:
            features.append(Features.from_dict(shot.features))
        except TypeError:  # features stored without the extractor's fields: nothing to read
            continue
        diameters.append(shot.metadata.get("sphere_diameter"))
    summaries = summarise(diameters, features)
    newest = members[-1]
    table = next((m.result["table"] for m in reversed(members) if m.result.get("table")), None)
    calibration = Calibration.from_any((newest.result.get("provenance") or {})
                                       .get("chain_calibration"))
    material = next((s.metadata["plate_material"] for s in newest.shots
                     if s.metadata.get("plate_material") is not None), None)
    return PositionInputs(summaries, table, calibration, material)


def from_records(records: Sequence[Any], tables: TableSet) -> list[MapPosition]:
    """One entry per position of a plate's stored measurements (oldest first, each with its
    shots), their shots summarised and inverted against ``tables`` through the one estimate
    path, as a measurement of all of them would be."""
    groups = by_position(records)
    out = []
    for (name, x, y), members in groups.items():
        estimate, reason = _stored(members, tables), None
        if estimate is None:
            given = position_inputs(members)
            try:
                estimate = estimate_from(tables, given.summaries, given.calibration,
                                         table=given.table,
                                         plate_material=given.plate_material).to_dict()
            except EstimateUnavailable as exc:
                reason = str(exc)
            except Exception as exc:  # an inversion refusing these features: say why, go on
                reason = f"inversion failed: {exc}"
            mixed = _mixed_calibrations(members)
            if estimate is not None and mixed:
                estimate["warnings"] = [*estimate.get("warnings", []), mixed]
        out.append(position_entry(name, x, y, sum(m.n_shots for m in members), estimate, reason,
                                  [m.id for m in members],
                                  max(m.created_at for m in members)))
    return out


MIXED_CALIBRATIONS = ("this position's measurements were estimated with different set-ups or "
                      "chain calibrations; their shots are pooled and read with the newest "
                      "one's")


def _mixed_calibrations(members: Sequence[Any]) -> str | None:
    """:data:`MIXED_CALIBRATIONS` where a position's measurements name more than one set-up
    revision or chain calibration, else None."""
    seen = {json.dumps([(m.result.get("provenance") or {}).get(k)
                        for k in ("setup", "chain_calibration")], sort_keys=True)
            for m in members}
    return MIXED_CALIBRATIONS if len(seen) > 1 else None


def _stored(members: Sequence[Any], tables: TableSet) -> TableEstimateDict | None:
    """A position of one measurement: its stored estimate, where the table it names is loaded
    with the same content (its SHA-256). That is what pooling its shots again would give, to
    the last bit, without the inversion's time; None otherwise (estimate again)."""
    if len(members) != 1:
        return None
    result = members[0].result
    table = (result.get("provenance") or {}).get("table") or {}
    loaded = tables.by_id.get(str(table.get("id"))) if tables.loaded else None
    if (result.get("estimate") is None or loaded is None
            or loaded.model.content_sha256 != table.get("sha256")):
        return None
    stored: TableEstimateDict = result["estimate"]
    return stored.copy()


def position_entry(name: Any, x: float | None, y: float | None, n_shots: int,
                   estimate: Mapping[str, Any] | None, reason: str | None,
                   measurement_ids: Sequence[int] = (), last: float | None = None
                   ) -> MapPosition:
    """One position of the map, its estimate reduced to what a map shows."""
    entry: MapPosition = {"position": name, "x_m": x, "y_m": y, "n_shots": int(n_shots)}
    if measurement_ids:
        entry["measurement_ids"] = list(measurement_ids)
    if last is not None:
        from solitonde.instrument.inference.estimate_rows import iso_utc

        entry["last_activity"] = iso_utc(last)
    for p in PARAMETERS:
        value = (estimate or {}).get(p)
        entry[p] = None if value is None else {
            "map": value.get("map"), "median": value.get("median"), "ci68": value.get("ci68"),
            "ci95": value.get("ci95"), "status": value.get("status")}
    entry["reason"] = reason if estimate is None else estimate.get("reason")
    entry["readings"] = list((estimate or {}).get("readings") or [])
    entry["warnings"] = list((estimate or {}).get("warnings") or [])
    return entry


def from_estimate_rows(rows: Sequence[Mapping[str, Any]]) -> list[MapPosition]:
    """Map positions from the flat rows an estimates file holds (instrument.estimate_rows)."""
    out = []
    for row in rows:
        estimate: _RowEstimate = {}
        for p in PARAMETERS:
            status = _text(row.get(f"{p}_status"))
            if status is None:
                continue
            lo68, hi68, lo95, hi95 = (_num(row.get(f"{p}_{k}")) for k in
                                      ("ci68_low", "ci68_high", "ci95_low", "ci95_high"))
            estimate[p] = {"map": _num(row.get(f"{p}_map")), "median": _num(row.get(f"{p}_median")),
                           "ci68": [lo68, hi68], "ci95": [lo95, hi95], "status": status}
        readings = _text(row.get("readings"))
        if estimate and readings:
            estimate["readings"] = json.loads(readings)
        n = _num(row.get("n_shots"))
        out.append(position_entry(_text(row.get("position")), _num(row.get("x_m")),
                                  _num(row.get("y_m")), int(n) if n is not None else 0,
                                  estimate or None, _text(row.get("reason"))))
    return out


def _num(value: Any) -> float | None:
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) else None


def _text(value: Any) -> str | None:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return None
    text = str(value)
    return text if text and text != "<NA>" else None


def build(plate_id: str, positions: list[MapPosition],
          plate_size_m: Sequence[float] | None = None) -> PlateMap:
    """The map JSON: the positions, the located support (or null and why), the plate's size."""
    placed = [(p, x, y) for p in positions
              if (x := p["x_m"]) is not None and (y := p["y_m"]) is not None]
    scan = [p for p, _, _ in placed]
    fit, reason = locate([_open_sides_filled(p) for p in scan])
    support = None
    if fit is not None:
        support = fit.to_dict()
        for p, x, y in placed:  # where the located edge puts each position, beside its answer
            p["distance_to_located_support_m"] = fit.distance(x, y)
    return {"plate_id": plate_id, "plate_size_m": list(plate_size_m) if plate_size_m else None,
            "n_positions": len(positions), "n_scan_positions": len(scan),
            "positions": positions, "support": support,
            "support_reason": None if fit is not None else reason}


def _open_sides_filled(position: MapPosition) -> MapPosition:
    """A position whose one-sided answer left its open bound empty (an estimates file) as
    :func:`~.support.answers` reads it: the open side is never used."""
    out = position.copy()
    d = position.get("distance_m")
    if (d and d.get("status") in ("lower_bound_only", "upper_bound_only")
            and (ci68 := d["ci68"]) is not None and (ci95 := d["ci95"]) is not None):
        lo68, hi68 = ci68
        lo95, hi95 = ci95
        out["distance_m"] = {**d, "ci68": [lo68 if lo68 is not None else -math.inf,
                                           hi68 if hi68 is not None else math.inf],
                             "ci95": [lo95 if lo95 is not None else -math.inf,
                                      hi95 if hi95 is not None else math.inf]}
    return out


# --- the scan as one unknown (instrument.inference.joint_map) ---------------------------------


@dataclass(frozen=True)
class JointOptions:
    """What a map request asks beyond the per-position map: the joint answer, its thickness
    prior, and the next positions to measure."""

    joint: bool = False
    suggest: int = 0
    suggest_for: str = "edge"
    thickness_prior: str = "free"
    thickness_spread: float = DEFAULT_SPREAD

    def __post_init__(self) -> None:
        check_request(self.suggest, self.suggest_for)
        ThicknessPrior(self.thickness_prior, self.thickness_spread)

    @property
    def wanted(self) -> bool:
        return self.joint or self.suggest > 0


def scan_from_records(records: Sequence[Any]) -> tuple[list[ScanPosition], list[str | None]]:
    """A plate's stored measurements (with their shots) as scan positions, grouped and
    summarised as :func:`from_records` does, each with its chain calibration and the table it
    was estimated with."""
    from solitonde.model.materials import material_spread

    groups = by_position(records)
    out, tables = [], []
    for (name, x, y), members in groups.items():
        if x is None or y is None:
            continue
        given = position_inputs(members)
        inputs = [s.inputs() for s in given.summaries if s.skip_reason() is None]
        if not inputs:  # only sizes without a reflection: their bounds, as the inversion takes
            inputs = _bounds_only(members)
        spread = (None if given.plate_material is None
                  else material_spread(given.plate_material))
        out.append(ScanPosition(name, x, y, inputs, given.calibration, spread))
        tables.append(given.table)
    return out, tables


def _bounds_only(members: Sequence[Any]) -> list[FeatureSummary]:
    """The estimate's own inputs of a position whose sizes show no reflection."""
    for m in reversed(members):
        inputs = ((m.result.get("estimate") or {}).get("inputs")) or []
        if inputs:
            return [FeatureSummary.from_any(i) for i in inputs]
    return []


def scan_from_rows(rows: Sequence[Mapping[str, Any]]
                   ) -> tuple[list[ScanPosition], list[str | None]]:
    """Scan positions from an estimates file's rows (its ``size_summaries``, ``calibration``,
    ``material_spread`` and ``table`` columns, instrument.inference.estimate_rows).

    Raises JointMapError (``size_summaries``) for a row that lacks them."""
    from solitonde.instrument.inference.calibration import Calibration

    out, tables = [], []
    for row in rows:
        x, y = _num(row.get("x_m")), _num(row.get("y_m"))
        if x is None or y is None:
            continue
        name = _text(row.get("position"))
        text = _text(row.get("size_summaries"))
        if text is None:
            if _text(row.get("reason")) is not None and _text(row.get("thickness_m_status")) \
                    is None:
                continue  # no estimate was possible: nothing to invert
            raise JointMapError("size_summaries", f"position {name!r} has no per-size summaries "
                                "(an estimates file written before they were kept: run "
                                "`solitonde analyze --estimates-out` again)")
        try:
            inputs = [FeatureSummary.from_any(i) for i in json.loads(text)]
            cal_text = _text(row.get("calibration"))
            cal = Calibration.from_any(json.loads(cal_text)) if cal_text else None
            spread_text = _text(row.get("material_spread"))
            spread = json.loads(spread_text) if spread_text else None
        except (ValueError, TypeError) as exc:
            raise JointMapError("size_summaries", f"position {name!r}: {exc}") from None
        out.append(ScanPosition(name, x, y, inputs, cal, spread))
        tables.append(_text(row.get("table")))
    return out, tables


def of_records(plate_id: str, records: Sequence[Any], tables: TableSet,
               options: JointOptions | None = None) -> PlateMap:
    """The map of a plate's stored measurements (:func:`from_records`, :func:`build`), with the
    joint answer and suggestions ``options`` asks for. Raises JointMapError, TableChoiceError
    (with the position by position map left for the caller to keep, if it wants)."""
    result = build(plate_id, from_records(records, tables), tables.plate_size())
    if options is None or not options.wanted:
        return result
    scan, table_ids = scan_from_records(records)
    return with_joint(result, scan, table_ids, tables, options)


def with_joint(plate_map: PlateMap, scan: Sequence[ScanPosition],
               table_ids: Sequence[str | None], tables: TableSet,
               options: JointOptions) -> PlateMap:
    """``plate_map`` with the joint answer (``options.joint``: positions' thickness and
    distance, ``support``, ``fit``, ``warnings``, ``thickness_prior``, each position's own answer
    kept under ``per_position``) and ``suggestions`` (``options.suggest``).

    Raises JointMapError, TableChoiceError."""
    if not options.wanted:
        return plate_map
    named = {t for t in table_ids if t}
    if len(named) > 1:
        raise JointMapError("table", f"the plate's positions were estimated with different "
                            f"tables ({', '.join(sorted(named))}); a joint map needs one family")
    if not tables.loaded:
        raise JointMapError("table", tables.reason or "no model table loaded")
    diameters = sorted({i.diameter_m for p in scan for i in p.inputs})
    chosen = tables.choose(diameters, next(iter(named), None))
    prior = ThicknessPrior(options.thickness_prior, options.thickness_spread)
    post = joint_posterior(chosen.model, scan, prior)
    plate_map = plate_map.copy()
    plate_map["joint"] = options.joint
    if options.joint:
        answer = joint_summary(post)
        by_key: dict[tuple[str | None, float | None, float | None], JointPositionRow] = {
            (p["position"], p["x_m"], p["y_m"]): p for p in answer["positions"]}
        left_out = {(e["position"]): e["reason"] for e in answer["excluded"]}
        positions = []
        for entry in plate_map["positions"]:
            entry = entry.copy()
            joint = by_key.get((entry["position"], entry["x_m"], entry["y_m"]))
            if joint is not None:
                entry["per_position"] = {p: entry.get(p) for p in PARAMETERS}
                entry["thickness_m"] = joint["thickness_m"]
                entry["distance_m"] = joint["distance_m"]
                entry["distance_to_located_support_m"] = joint["distance_to_located_support_m"]
            elif entry["x_m"] is not None and entry["y_m"] is not None:
                entry["joint_reason"] = left_out.get(entry["position"],
                                                     "no inversion input at this position")
            positions.append(entry)
        plate_map["positions"] = positions
        plate_map["support"] = answer["support"]
        plate_map["support_reason"] = None
        plate_map["fit"] = answer["fit"]
        plate_map["warnings"] = answer["warnings"]
        plate_map["thickness_prior"] = answer["thickness_prior"]
        plate_map["edges"] = answer["edges"]
        plate_map["table"] = chosen.model.table_id
    if options.suggest:
        found = suggest_positions(post, options.suggest, objective=options.suggest_for,
                                  plate_size_m=plate_map.get("plate_size_m"))
        plate_map["suggestions"] = found["suggestions"]
        basis = cast(SuggestionsBasis, {k: v for k, v in found.items() if k != "suggestions"})
        basis["expected_gain"] = describe_gain(options.suggest_for)
        plate_map["suggestions_basis"] = basis
    return plate_map
