"""The JSON a measurement is kept and served as: its result (one row of the store), the
provenance inside it, and the measurement as the API answers it.

These are annotations only: the dicts are built and stored as they always were, so the stored
rows and the responses do not change. The shots' metadata and features (free-form keys) stay
plain JSON objects.
"""

from __future__ import annotations

from typing import Any, NotRequired, TypedDict

from solitonde.instrument.inference.calibration import CalibrationDict
from solitonde.instrument.inference.pipeline import SizeSummaryDict, TableEstimateDict
from solitonde.instrument.inference.setups import SetupReference
from solitonde.signal.features import FeatureDict


class TableRef(TypedDict):
    """The table a result was computed with: its id and the SHA-256 of its file."""

    id: str
    sha256: str | None


class Extractor(TypedDict):
    """The feature extractor a result used and its settings."""

    function: str
    options: Any
    """The detector's options, JSON-ready."""
    chain_options: dict[str, dict[str, float]]
    """Per stated sphere size (as text), the options that size adds."""


class Provenance(TypedDict):
    """What a result was computed with, and when."""

    software_version: str
    extractor: Extractor
    table: TableRef | None
    setup: SetupReference | None
    """The set-up revision's reference (``{"id", "revision"}``), or None."""
    chain_calibration: CalibrationDict | None
    computed_at: float


class StoredResult(TypedDict):
    """A measurement's result as the store keeps it (``measurements.result``).

    ``location`` only where the shots state x_m and y_m; ``provenance`` is missing from
    measurements stored before it was recorded."""

    aggregates: list[SizeSummaryDict]
    """Per sphere size, the pipeline's summary of its shots."""
    estimate: TableEstimateDict | None
    estimate_reason: str | None
    table: str | None
    location: NotRequired[dict[str, float]]
    provenance: NotRequired[Provenance]


class EarlierEntry(TypedDict):
    """A result a reanalysis replaced, as the store keeps it."""

    superseded_at: float
    result: StoredResult
    shot_features: list[Any]
    """Each shot's features at the time."""


class EarlierResult(TypedDict):
    """An earlier result as the API lists it."""

    superseded_at: float
    provenance: Provenance | None
    table: str | None
    aggregates: list[SizeSummaryDict]
    estimate: TableEstimateDict | None
    estimate_reason: str | None
    shot_features: list[Any]


class ShotJSON(TypedDict):
    """A measured shot as the API shows it (and as its metadata and features are stored)."""

    shot_index: int
    metadata: dict[str, Any]
    n_samples: int
    t0: float
    dt: float
    units: str
    features: FeatureDict
    """The extractor's reading (:class:`~.api_models.ShotFeatures`'s keys, and any a later
    extractor adds) and the baseline it used."""


class MeasurementLinks(TypedDict):
    self: str
    plot: str


class MetadataDifference(TypedDict):
    """A metadata key a repeated request states otherwise than the stored shot."""

    shot: int
    key: str
    stored: Any
    sent: Any


class MeasurementHead(TypedDict):
    """What a measurement's full answer and its listing line both begin with."""

    id: int
    created_at: float
    plate_id: str | None
    position: str | None
    n_shots: int
    source: str


class MeasurementJSON(MeasurementHead):
    """A stored measurement as the API returns it (``MeasurementOut``'s keys)."""

    shots: list[ShotJSON]
    aggregates: list[SizeSummaryDict]
    estimate: TableEstimateDict | None
    estimate_reason: str | None
    table: str | None
    location: dict[str, float] | None
    provenance: Provenance | None
    earlier_results: list[EarlierResult]
    links: MeasurementLinks
    duplicate_of: NotRequired[int]
    metadata_differences: NotRequired[list[MetadataDifference]]
    skipped_channels: NotRequired[list[dict[str, str]]]
    """An upload's channels not analysed: ``{"channel", "reason"}``."""


class MeasurementLine(MeasurementHead):
    """One line of a measurement listing (``MeasurementSummary``'s keys)."""

    aggregates: list[SizeSummaryDict]
    estimate: TableEstimateDict | None
    table: str | None
    location: dict[str, float] | None


class MeasurementPageJSON(TypedDict):
    """A page of the listing and the URL of the next one."""

    items: list[MeasurementLine]
    next: str | None


class StoredShot(TypedDict):
    """One stored shot with its samples (``GET .../shots/{i}``)."""

    t0: float
    dt: float
    samples: list[float]
    units: str
    calibration: float | None
    metadata: dict[str, Any]
    features: FeatureDict
