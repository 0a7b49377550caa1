"""Request and response bodies of the REST service (pydantic; they make the OpenAPI schema).

Request models forbid unknown keys and non-finite numbers. The per-request limits come from the
settings, so :func:`request_models` builds the measurement models for given limits; the schema
then states them (``maxItems``) and the validator enforces the same numbers.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    StringConstraints,
    create_model,
)

from solitonde.instrument.inference.measured_shots import (
    COORDINATE_MAX,
    IDENTIFIER_MAX,
    KEY_MAX,
    TEXT_MAX,
)
from solitonde.instrument.inference.sizes import SPHERE_DIAMETER_MAX, size_in_metres_message
from solitonde.signal.features import FIELD_KINDS
from solitonde.signal.waveform import MIN_SAMPLES

SCALAR = Annotated[str, StringConstraints(max_length=TEXT_MAX)] | float | int | bool | None
Key = Annotated[str, StringConstraints(max_length=KEY_MAX)]


def _in_metres(value: float) -> float:
    if value > SPHERE_DIAMETER_MAX:
        raise ValueError(size_in_metres_message(value))
    return value


SphereSize = Annotated[float, Field(gt=0, json_schema_extra={"maximum": SPHERE_DIAMETER_MAX}),
                       AfterValidator(_in_metres)]
"""A sphere size in metres; one over :data:`SPHERE_DIAMETER_MAX` is refused as a size in mm."""


class Strict(BaseModel):
    """Base for request bodies: unknown keys, NaN, infinity and type coercion (true as 1,
    "5e-7" as a number) are errors."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)


class PlateMaterialIn(Strict):
    """A plate material by its properties (SI units), optionally with the spread of its grade;
    the inversion carries that spread in its intervals (without one: the properties are exact)."""

    name: str | None = Field(None, max_length=80)
    youngs_modulus: float = Field(ge=1e6, le=1e13, description="E, Pa")
    poisson_ratio: float = Field(gt=-1.0, lt=0.5, description="nu")
    density: float = Field(ge=1.0, le=1e5, description="rho, kg/m^3")
    youngs_modulus_rel_sd: float | None = Field(None, ge=0, le=0.5,
                                                description="relative sd of E")
    poisson_ratio_sd: float | None = Field(None, ge=0, le=0.2, description="sd of nu")
    density_rel_sd: float | None = Field(None, ge=0, le=0.5, description="relative sd of rho")


PLATE_MATERIAL_HELP = ("the plate's material, a library name or its properties (with their "
                       "spread, optionally): picks the table of that family, a named table of "
                       "another family is refused, and the stated spread widens the intervals")


def plate_material_value(value: Any) -> Any:
    """A request's ``plate_material`` as the inversion takes it (a name, or a plain mapping)."""
    if isinstance(value, PlateMaterialIn):
        return value.model_dump(exclude_none=True)
    return value


MaterialName = Annotated[str, StringConstraints(max_length=80)]
"""A plate material named in text (a library name, or its properties as JSON in a form field)."""


class ShotMetadata(Strict):
    """Where and how a shot was taken."""

    plate_id: str | None = Field(None, max_length=IDENTIFIER_MAX, description="plate identifier")
    position: str | None = Field(None, max_length=IDENTIFIER_MAX,
                                 description="measurement position label on the plate")
    sphere_diameter: SphereSize | None = Field(None, description="chain sphere diameter D, m "
                                               "(sizes are in metres: 9.53 mm is 9.53e-3)")
    shot: int | None = Field(None, ge=0, le=2**31, description="shot number at this position")
    x_m: float | None = Field(None, ge=-COORDINATE_MAX, le=COORDINATE_MAX,
                              description="the chain's position on the "
                              "plate, x in the plate's own frame, m (within the plate's size "
                              "when the service's table states it)")
    y_m: float | None = Field(None, ge=-COORDINATE_MAX, le=COORDINATE_MAX,
                              description="the chain's position, y, m")
    table: str | None = Field(None, max_length=64, description="the model table to invert "
                              "against, by id (GET /v1/tables); needed when several could serve")
    plate_material: MaterialName | PlateMaterialIn | None = (
        Field(None, description=PLATE_MATERIAL_HELP))
    baseline: Literal["gap", "pre-trigger"] | None = Field(
        None, description="what the shot's baseline is measured on where its sphere size is "
        "stated: 'gap' (the default: the pre-trigger and the gap before the reflection, less the "
        "chain's simulated relaxation; a drift does not move TOF or ARR) or 'pre-trigger' (for a "
        "chain unlike the paper's)")
    extra: dict[Key, SCALAR] = Field(default_factory=dict, max_length=50,
                                     description="free-form key/value pairs, kept as given; "
                                                 "not the fields above, nor 'source' (a 422)")


class ShotBase(Strict):
    """One recorded shot: uniformly sampled sensor trace."""

    t0: float = Field(0.0, ge=-1e3, le=1e3, description="time of the first sample, s")
    dt: float = Field(..., gt=0, le=1.0, description="sample period, s")
    samples: list[float]
    units: Literal["N", "V"] = Field("N", description="N (force) or V (sensor voltage)")
    calibration: float | None = Field(
        None, description="sensor sensitivity, N/V (required when units are V; not zero)")
    metadata: ShotMetadata = Field(default_factory=ShotMetadata)


BINARY_MEDIA_TYPE = "application/octet-stream"
BINARY_DTYPES = {"float32": "<f4", "float64": "<f8"}
"""``dtype`` values of a binary shot and the little-endian numpy types they name."""


class _QueryParams(Strict):
    # Query values arrive as text: numbers are parsed from it (still no NaN, no unknown keys).
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=False)


ALLOW_DUPLICATE_HELP = ("store the shots even where a stored measurement has the same samples "
                        "in the same order (default: that measurement is answered, 200, with "
                        "duplicate_of and metadata_differences)")
SETUP_HELP = ("the instrument set-up to measure with, by id (GET /v1/setups): its newest "
              "revision's sphere size (for shots that state none), table and chain calibration; "
              "a shot whose size or table contradicts it is a 422")
SetupName = Annotated[str, StringConstraints(min_length=1, max_length=128)]
"""A set-up's id as a request names it."""
_SHOT_QUERY_KEYS = ("dt", "t0", "units", "calibration")
_METADATA_QUERY_KEYS = ("plate_id", "position", "sphere_diameter", "shot")

BinaryShotParams: Any = create_model(  # type: ignore[call-overload]  # fields from dicts
    "BinaryShotParams",
    __base__=_QueryParams,
    __doc__="Query parameters of a binary shot: the body is the samples, these say what they "
            "are.\n\nThe acquisition PC's own buffer (little-endian float32 or float64, no "
            "header) is posted as it is; nothing is parsed from text. The other keys are the JSON "
            "shot's (and its metadata's), with the same limits and meanings.",
    dtype=(Literal["float32", "float64"],
           Field(..., description="little-endian IEEE 754 samples, no header: float32 or "
                                  "float64")),
    **{k: (ShotBase.model_fields[k].annotation, ShotBase.model_fields[k])
       for k in _SHOT_QUERY_KEYS},
    **{k: (ShotMetadata.model_fields[k].annotation, ShotMetadata.model_fields[k])
       for k in _METADATA_QUERY_KEYS},
    table=(ShotMetadata.model_fields["table"].annotation, ShotMetadata.model_fields["table"]),
    plate_material=(MaterialName | None, Field(None, description="the plate's material: a "
                                               "library name, or its properties as JSON; the "
                                               "table of that family is used")),
    allow_duplicate=(bool, Field(False, description=ALLOW_DUPLICATE_HELP)),
    setup=(SetupName | None, Field(None, description=SETUP_HELP)),
)


def request_models(max_shots: int, max_samples: int) -> tuple[type[Strict], type[Strict]]:
    """The shot and measurement request models with the service's limits built in."""
    shot = create_model(
        "ShotIn",
        __base__=ShotBase,
        __doc__=f"One recorded shot (at most {max_samples:,} samples).",
        samples=(list[float], Field(..., min_length=MIN_SAMPLES, max_length=max_samples,
                                    description=f"sensor samples, at most {max_samples:,}")),
    )
    measurement = create_model(
        "MeasurementIn",
        __base__=Strict,
        __doc__=(f"One or more shots taken at one position (at most {max_shots} shots, each of at "
                 f"most {max_samples:,} samples). All shots share plate_id and position. "
                 "Top-level metadata applies to every shot unless a shot sets the key itself."),
        shots=(list[shot], Field(..., min_length=1, max_length=max_shots)),
        metadata=(ShotMetadata | None, Field(None, description="metadata shared by all shots")),
        allow_duplicate=(bool, Field(False, description=ALLOW_DUPLICATE_HELP)),
        setup=(SetupName | None, Field(None, description=SETUP_HELP)),
    )
    return shot, measurement


FEATURE_DESCRIPTIONS = {
    "tof_s": "time of flight, s, the template reading: between the peaks of the solitary-wave "
             "template fitted to each pulse (what the model tables hold, so the inversion reads "
             "it); null where no reflection was detected",
    "arr": "amplitude ratio, reflection over incident, the template reading (above the level "
           "before the impact); null where no reflection was detected",
    "incident_time_s": "the incident's peak, s from the record's start (template)",
    "reflected_time_s": "the reflection's peak, s (template); null without one",
    "incident_peak_N": "the incident's peak force above the pre-impact level, N (template)",
    "reflected_peak_N": "the reflection's peak force, N (template); null without one",
    "snr_db": "the incident's peak over the noise, dB",
    "flags": "what the detector noticed (e.g. overlapping, saturated, implausible_units)",
    "arr_upper_bound": "for a shot without a reflection: the largest ARR that could hide under "
                       "the noise",
    "secondary_times_s": "the pulses after the reflection, s from the incident",
    "secondary_ratios": "their peaks over the incident's",
    "baseline_N": "the sensor's reading before the impact at the incident's peak, N",
    "noise_N": "the noise's standard deviation, N",
    "arr_local": "the ratio of the pulses' rises above the level just before each (drift-immune, "
                 "larger than arr where the chain decompresses between the pulses)",
    "incident_rise_N": "the incident's rise above the level just before it, N",
    "reflected_rise_N": "the reflection's rise above the level just before it, N",
    "tof_peak_s": "time of flight between the trace's own peaks, s: the paper's definition, a hand "
                  "reading of the scope (on a noisy shot the template's peak wherever the data "
                  "cannot tell the two apart)",
    "arr_peak": "amplitude ratio of the trace's own peaks: the paper's definition",
    "incident_width_s": "the incident's full width at half maximum, s (a solitary wave ties it to "
                        "its force and the sphere size)",
    "reflection_window_s": "the longest TOF the record could show whole, s",
    "baseline": "what the baseline was measured on: 'gap' (the chain's relaxation taken out) or "
                "'pre-trigger'",
}
"""What each shot feature is, for the schema (one line per :class:`Features` field)."""

_KIND_TYPES: dict[str, Any] = {"number": float | None, "optional": float | None,
                               "series": list[float], "flags": list[str]}


def _shot_features_model() -> type[BaseModel]:
    """The shot features as a typed model, from the one declaration of them
    (:class:`~solitonde.signal.features.Features`); keys a later extractor adds pass through."""
    fields: dict[str, Any] = {
        name: (_KIND_TYPES[kind], Field(None if kind in ("number", "optional") else [],
                                        description=FEATURE_DESCRIPTIONS.get(name)))
        for name, kind in FIELD_KINDS.items()}
    fields["baseline"] = (str | None, Field(None, description=FEATURE_DESCRIPTIONS["baseline"]))
    return create_model("ShotFeatures", __config__=ConfigDict(extra="allow"),
                        __doc__="What the extractor read of one shot: the template reading "
                        "(tof_s, arr: what the inversion uses) and the paper's peak reading "
                        "(tof_peak_s, arr_peak) beside it.", **fields)


ShotFeatures = _shot_features_model()


class ShotOut(BaseModel):
    """Features measured on one shot."""

    shot_index: int = Field(description="position of the shot in the request / file")
    metadata: dict[str, Any]
    n_samples: int
    t0: float
    dt: float
    units: str
    features: ShotFeatures = Field(  # type: ignore[valid-type]
        description="what the extractor read of the shot (each field says which reading)")


class MetadataDifferenceOut(BaseModel):
    """A metadata key a repeated post states otherwise than the stored shot."""

    shot: int = Field(description="the shot's index")
    key: str
    stored: Any = Field(description="the stored measurement's value")
    sent: Any = Field(description="the request's value")


class MeasurementOut(BaseModel):
    """A stored measurement: features per shot, aggregates, estimate."""

    id: int
    created_at: float = Field(description="Unix time the measurement was stored, s")
    plate_id: str | None
    position: str | None
    n_shots: int
    source: str = Field(description="'json', 'binary' or 'upload:<format>'")
    shots: list[ShotOut]
    aggregates: list[dict[str, Any]] = Field(
        description="per sphere diameter: mean, std and count of TOF and ARR, outliers reported")
    estimate: dict[str, Any] | None = Field(
        description="thickness_m and distance_m (map, median, ci68, ci95, status: "
        "constrained, lower_bound_only, upper_bound_only, unconstrained, ambiguous, "
        "inconsistent or out_of_range), readings (an ambiguous answer's: thickness_m, "
        "distance_m, weight), fit, warnings; or null")
    estimate_reason: str | None = Field(None, description="why the estimate is null")
    table: str | None = Field(None, description="id of the model table the estimate used "
                              "(GET /v1/tables gives its plate family)")
    location: dict[str, float] | None = Field(None, description="x_m and y_m on the plate")
    provenance: dict[str, Any] | None = Field(
        None, description="what the result was computed with: software_version, extractor "
        "(function, options), table (id, sha256) or null, computed_at (Unix s); null for a "
        "measurement stored before provenance was recorded")
    earlier_results: list[dict[str, Any]] = Field(
        default_factory=list, description="results a reanalysis (`solitonde store reanalyze`) "
        "replaced, oldest first: superseded_at, provenance, table, aggregates, estimate, "
        "estimate_reason, shot_features")
    links: dict[str, str] = Field(default_factory=dict)
    duplicate_of: int | None = Field(None, description="on a 200 to a post: the stored "
                                     "measurement whose samples these shots are, in order")
    metadata_differences: list[MetadataDifferenceOut] | None = Field(
        None, description="on a 200 to a post: per shot, what the request's metadata says "
        "otherwise than the stored measurement's (shot, key, stored, sent)")
    skipped_channels: list[dict[str, str]] = Field(
        default_factory=list, description="an upload's channels not analysed: {channel, reason} "
        "(a trigger step or flat line, or not the channel asked for); not stored")


class MeasurementSummary(BaseModel):
    """One line of a measurement listing."""

    id: int
    created_at: float
    plate_id: str | None
    position: str | None
    n_shots: int
    source: str
    aggregates: list[dict[str, Any]]
    estimate: dict[str, Any] | None
    table: str | None = Field(None, description="id of the model table the estimate used")
    location: dict[str, float] | None = Field(None, description="x_m and y_m on the plate")


class MeasurementPage(BaseModel):
    """A page of measurements in id order; follow ``next`` for the rest."""

    items: list[MeasurementSummary]
    next: str | None = Field(None, description="URL of the next page, null on the last")


class InversionInput(Strict):
    """Summary of the shots with one sphere size."""

    diameter_m: SphereSize = Field(description="sphere diameter D, m")
    tof_s: float | None = Field(None, gt=0, le=1.0, description="mean time of flight, s (null "
                                "with arr for a size whose shots show no reflection)")
    tof_std_s: float | None = Field(None, ge=0, le=1.0,
                                    description="scatter of TOF, s (default: stated default)")
    arr: float | None = Field(None, ge=0, le=10.0, description="mean amplitude ratio")
    arr_std: float | None = Field(None, ge=0, le=10.0, description="scatter of ARR")
    n_shots: int = Field(1, ge=1, le=100_000)
    arr_upper_bound: float | None = Field(None, gt=0, le=1.5, description="for a size without a "
                                          "reflection (tof_s and arr null): the largest ARR that "
                                          "could hide under the noise; it bounds the thickness")
    tof_window_s: float | None = Field(
        None, gt=0, le=1.0, description="for a size without a reflection: the longest TOF its "
        "records show whole (record end - incident peak - 2.5 FWHM); a reflection arriving later "
        "is not bounded. Null: the records are taken as long enough")


class DistanceEntry(Strict):
    """A sphere size's ARR factor and TOF offset fitted at one distance to the support."""

    distance_m: float = Field(ge=0, le=100.0, description="the references' distance, m")
    arr_factor: float = Field(gt=0, le=10.0)
    tof_offset_s: float = Field(ge=-1e-2, le=1e-2)
    arr_factor_std: float | None = Field(None, ge=0, le=10.0)
    tof_offset_std_s: float | None = Field(None, ge=0, le=1e-2)
    n_references: int | None = Field(None, ge=1, le=100_000)


class CalibrationEntry(Strict):
    """One sphere size's calibration, as ``solitonde calibrate`` writes it."""

    diameter_m: SphereSize = Field(description="sphere diameter D, m")
    arr_factor: float = Field(1.0, gt=0, le=10.0)
    tof_offset_s: float = Field(0.0, ge=-1e-2, le=1e-2)
    arr_factor_std: float | None = Field(None, ge=0, le=10.0)
    arr_factor_transfer_std: float | None = Field(None, ge=0, le=10.0)
    tof_offset_std_s: float | None = Field(None, ge=0, le=1e-2)
    tof_offset_transfer_std_s: float | None = Field(None, ge=0, le=1e-2)
    n_references: int | None = Field(None, ge=1, le=100_000)
    damping_s: float | None = Field(None, ge=0, le=1e-3, description="the chain's fitted "
                                    "Kuwabara-Kono time constant, s: the table is read at it "
                                    "(needs a table with a dissipation layer)")
    damping_std_s: float | None = Field(None, ge=0, le=1e-3)
    shot_tof_rel_std: float | None = Field(
        None, ge=0, le=1.0, description="the references' per-shot TOF scatter, pooled, relative "
        "to the TOF: an input without tof_std_s is read with it (widened to Student's t)")
    shot_arr_std: float | None = Field(
        None, ge=0, le=10.0, description="the references' per-shot ARR scatter, pooled: an "
        "input without arr_std is read with it")
    shot_scatter_dof: int | None = Field(None, ge=1, le=10_000_000, description="the pooled "
                                         "scatter's degrees of freedom, sum(shots - 1)")
    by_distance: list[DistanceEntry] | None = Field(
        None, min_length=2, max_length=64, description="the factor and offset fitted at each "
        "reference distance (references near a support and far from it), sorted by distance: "
        "read piecewise linear in 1/distance between them, constant beyond")


class Calibration(Strict):
    """Experiment calibration: multiply model ARR by arr_factor, add tof_offset_s to model TOF;
    ``per_diameter`` entries override the global pair for their sphere size. The JSON file
    ``solitonde calibrate`` writes is accepted as it is."""

    arr_factor: float = Field(1.0, gt=0, le=10.0)
    tof_offset_s: float = Field(0.0, ge=-1e-2, le=1e-2)
    per_diameter: list[CalibrationEntry] = Field(default_factory=list, max_length=16)
    reference: dict[str, Any] | None = Field(
        None, description="where the calibration came from (kept, not used)")


class InvertIn(Strict):
    """Features in, estimate out."""

    inputs: list[InversionInput] = Field(min_length=1, max_length=16)
    calibration: Calibration | None = None
    table: str | None = Field(None, max_length=64, description="the model table, by id")
    plate_material: MaterialName | PlateMaterialIn | None = (
        Field(None, description=PLATE_MATERIAL_HELP))


class InvertOut(BaseModel):
    estimate: dict[str, Any]


class SimulateIn(Strict):
    """A scene (same keys as a scene file) to simulate; noise is not added."""

    scene: dict[str, Any] = Field(default_factory=dict,
                                  description="chain, striker, plate, effects, output sections")
    include_trace: bool = Field(True, description="return the sensor samples")


class SimulateOut(BaseModel):
    t0: float
    dt: float
    n_samples: int
    samples: list[float] | None
    units: Literal["N"] = "N"
    features: dict[str, Any]
    diagnostics: dict[str, Any]
    cost: dict[str, Any]


class TableOut(BaseModel):
    loaded: bool
    path: str | None
    reason: str | None = None
    summary: dict[str, Any] | None = None
    limits: dict[str, int | float]


class Health(BaseModel):
    status: Literal["ok"] = "ok"
    version: str


class Ready(BaseModel):
    ready: bool
    store: str
    table_loaded: bool
    estimates: bool
    reason: str | None = None
