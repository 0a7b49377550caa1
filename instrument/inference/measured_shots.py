"""The measured-shot road: read waveform files, check their metadata, group shots by position,
summarise each position's shots per sphere size.

`analyze`, `calibrate`, the service's uploads and JSON shots (``POST /v1/measurements``) and the
plate maps walk it; the command line and the routes only translate their input into its calls
and its errors (:class:`ShotInputError`, the signal layer's ``WaveformError``) into theirs (a
flag named, a problem+json body).

``calibration`` keeps the two meanings its callers need, as two parameters of :func:`read_shots`:
``options["calibration"]`` is the reader's (an *override*: it converts every shot in volts, over a
calibration the file states, and a file all in newtons refuses it; the service's form field), and
``fallback_calibration`` serves only shots in volts that carry none (`analyze --calibration`, one
value given for many files of which some state their own).

The metadata limits (text lengths, keys, nesting, the sphere size and the position on the plate)
are declared here once; the service's request models take their numbers from these constants, and
:func:`check_metadata` applies them to metadata from any source: a file's header, comments,
attributes or properties, the command line's flags, a campaign manifest.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import numbers
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Required, TypedDict, TypeVar, cast

import numpy as np

from solitonde.instrument.errors import InstrumentError
from solitonde.instrument.inference import chain_geometry, shot_measure
from solitonde.instrument.inference.sizes import SPHERE_DIAMETER_MAX, size_problem
from solitonde.signal import channels as signal_channels
from solitonde.signal import io as signal_io
from solitonde.signal.errors import WaveformError
from solitonde.signal.features import FEATURES, Features
from solitonde.signal.json_ready import json_ready
from solitonde.signal.waveform import Waveform

if TYPE_CHECKING:  # the inference (scipy) loads only when shots are summarised
    from solitonde.instrument.inference.pipeline import SizeSummary

TEXT_MAX = 1000
"""Longest text value of metadata."""
IDENTIFIER_MAX = 200
"""Longest ``plate_id`` or ``position``."""
KEY_MAX = 100
"""Longest metadata key."""
METADATA_KEYS_MAX = 100
"""Most keys one shot's metadata may hold."""
NESTED_MAX = 16_384
"""Largest nested metadata value (a mapping or list), in bytes of JSON."""
COORDINATE_MAX = 1e3
"""Largest ``|x_m|``, ``|y_m|`` a request states, m (the plate's own size bounds them further
where a table gives it)."""

POSITION_KEYS = ("plate_id", "position", "x_m", "y_m")
"""The metadata that say where a shot was taken."""
LOCATION_KEYS = (*POSITION_KEYS, "sphere_diameter")
"""Where a shot was taken and with which spheres."""
CHOICE_KEYS = ("setup", "table", "plate_material")
"""What a shot's metadata (a manifest's columns) says it is estimated with: an instrument
set-up by id, a table by id, the plate's material."""


class ShotInputError(InstrumentError):
    """Metadata a measured shot cannot be used with; ``field`` names it (a dotted path when the
    caller gave one, e.g. ``shots.0.metadata.sphere_diameter``)."""

    kind = "invalid-input"
    """The problem type a service answers with."""


class ShotLimitError(ShotInputError):
    """Metadata over a stated size limit (text length, key count, nested size)."""

    kind = "limit"


PEAK_READING = ("tof_peak_s", "arr_peak")
"""A shot row's paper reading beside the template's ``tof_s`` and ``arr``: the time between the
trace's own two peaks and their heights' ratio, the paper's definition (a hand reading of the
scope)."""

class MissingSource(TypedDict):
    """A path given that holds no file to read, and why."""

    source: str
    error: str


class ShotRow(TypedDict, total=False):
    """One shot of a file as :func:`measure_file` lists it.

    A channel left out holds ``source``, ``channel`` and ``skipped`` (why) only. Every other
    row holds where the shot was taken (:data:`LOCATION_KEYS`, as its metadata states them),
    what it is estimated with (:data:`CHOICE_KEYS`, where stated) and ``baseline``; then either
    ``error`` (the extractor could not read it), or its numbers (the features'
    :data:`~solitonde.signal.features.FEATURES` and :data:`PEAK_READING`, ``flags``,
    ``arr_upper_bound``) and, measured, its ``features`` and ``waveform`` (a shot whose pulses
    fit no standard chain has ``error`` instead)."""

    source: Required[str]
    channel: Required[str | None]
    skipped: str
    shot: Any  # the metadata's values are as the file or its sources state them
    plate_id: Any
    position: Any
    x_m: Any
    y_m: Any
    sphere_diameter: Any
    setup: Any
    table: Any
    plate_material: Any
    baseline: str
    error: str
    tof_s: float | None
    arr: float | None
    incident_time_s: float | None
    reflected_time_s: float | None
    incident_peak_N: float | None
    reflected_peak_N: float | None
    snr_db: float | None
    tof_peak_s: float | None
    arr_peak: float | None
    flags: list[str]
    arr_upper_bound: float | None
    features: Features
    waveform: Waveform


class ShotLocation(TypedDict, total=False):
    """Where the shots of one summary were taken (:data:`LOCATION_KEYS`, as their metadata
    states them), what they are estimated with (:data:`CHOICE_KEYS`, where stated), and
    ``source``: their file where it names neither plate nor position, else None."""

    plate_id: Required[Any]
    position: Required[Any]
    x_m: Required[Any]
    y_m: Required[Any]
    sphere_diameter: Required[Any]
    setup: Any
    table: Any
    plate_material: Any
    source: Required[str | None]


FieldOf = Callable[[int, str], str]
"""The field name of metadata key ``key`` of shot ``i``, for errors."""


def shot_fields(prefix: str) -> FieldOf:
    """Fields under a request's path (``prefix.i.metadata.key``); an empty prefix: the key
    alone (a lone shot whose fields are top-level, a command line's values)."""
    def field_of(i: int, key: str) -> str:
        return f"{prefix}.{i}.metadata.{key}" if prefix else key

    return field_of


# -- read ---------------------------------------------------------------------------------------

def collect(paths: Iterable[Path], fmt: str | None = None
            ) -> tuple[list[Path], list[MissingSource]]:
    """Files to read, each once, and the paths that gave none (missing, or a folder with no
    files).

    Folders are searched recursively: for the known extensions, or, with ``fmt`` given, every
    regular file whose name does not start with a dot.
    """
    files: list[Path] = []
    missing: list[MissingSource] = []
    for p in paths:
        if p.is_dir():
            found = sorted(f for f in p.rglob("*") if f.is_file() and (
                not f.name.startswith(".") if fmt is not None
                else f.suffix.lower() in signal_io.EXTENSIONS))
            if not found:
                what = ("no files" if fmt is not None else "no files with the extensions " +
                        ", ".join(sorted(signal_io.EXTENSIONS)) + " (use --format for others)")
                missing.append({"source": str(p), "error": f"{p}: {what}"})
            files.extend(found)
        elif p.exists():
            files.append(p)
        else:
            missing.append({"source": str(p), "error": f"no such file or folder: {p}"})
    seen: set[Path] = set()
    unique = []
    for f in files:  # a file named twice (itself and in its folder) is one set of shots
        key = f.resolve()
        if key not in seen:
            seen.add(key)
            unique.append(f)
    return unique, missing


def read_shots(path: Path, fmt: str | None, options: Mapping[str, Any], *,
               fallback_calibration: float | None = None, accepted_only: bool = False
               ) -> tuple[list[Waveform], bool]:
    """The shots of ``path`` and whether ``fallback_calibration`` converted any of them.

    ``options`` go to the format's reader (``calibration`` among them is an override, see the
    module docstring); with ``accepted_only`` those the reader does not take are dropped (a
    command line's options meant for some files), otherwise they are its error.
    ``fallback_calibration`` converts the shots in volts that carry no calibration of their own.

    Raises WaveformError (an OptionNeeded among them) for a file that cannot be read with these
    options: a parser's failure names ``file``, an empty file ``samples``.
    """
    opts = {k: v for k, v in options.items() if v is not None}
    accepted = signal_io.READER_OPTIONS[signal_io.detect_format(path, fmt)]
    if accepted_only:
        opts = {k: v for k, v in opts.items() if k in accepted}
    try:
        return list(signal_io.read(path, format=fmt, **opts)), False
    except signal_io.OptionNeeded as exc:
        if (exc.option != "calibration" or fallback_calibration is None
                or "calibration" not in accepted or "calibration" in opts):
            raise
    return list(signal_io.read(path, format=fmt, **opts, calibration=fallback_calibration)), True


# -- check metadata -----------------------------------------------------------------------------

def _real(value: Any) -> bool:
    return (isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_)
            and math.isfinite(float(value)))


IDENTIFIERS = ("plate_id", "position")
"""The metadata that name a plate and a position: stored, listed and put in URLs."""


def check_identifier(value: str, field: str) -> None:
    """A plate id or position: printable text, not blank (any printable character, ``/`` and
    spaces included, is kept and served). ShotInputError naming ``field``."""
    if not value.strip():
        raise ShotInputError(field, f"{value!r} is blank", "printable text, not only spaces")
    odd = next((ch for ch in value if not ch.isprintable()), None)
    if odd is not None:
        raise ShotInputError(field, f"{value!r} holds the control character {odd!r}",
                             "printable text (letters, digits, spaces, punctuation, / )")


def check_sizes(meta: Mapping[str, Any], field_of: Callable[[str], str]) -> None:
    """The limits JSON metadata has, for metadata from any source: plate_id and position at most
    :data:`IDENTIFIER_MAX` characters, other text at most :data:`TEXT_MAX`, a key at most
    :data:`KEY_MAX`, at most :data:`METADATA_KEYS_MAX` keys, a nested value at most
    :data:`NESTED_MAX` bytes of JSON. ShotLimitError naming the field."""
    if len(meta) > METADATA_KEYS_MAX:
        where = field_of("")[:-1] or "metadata"
        raise ShotLimitError(where, f"{len(meta)} keys; at most {METADATA_KEYS_MAX}")
    for key, value in meta.items():
        key = str(key)
        if len(key) > KEY_MAX:
            raise ShotLimitError(field_of(key[:40]), f"a key of {len(key)} characters; at most "
                                 f"{KEY_MAX}")
        if isinstance(value, str):
            limit = IDENTIFIER_MAX if key in IDENTIFIERS else TEXT_MAX
            if len(value) > limit:
                raise ShotLimitError(field_of(key), f"{len(value):,} characters; at most "
                                     f"{limit}")
            if key in IDENTIFIERS:
                check_identifier(value, field_of(key))
        elif isinstance(value, Mapping | list | tuple):
            size = len(json.dumps(json_ready(value), default=str))
            if size > NESTED_MAX:
                raise ShotLimitError(field_of(key), f"{size:,} bytes of JSON; at most "
                                     f"{NESTED_MAX:,}")


def check_metadata(metadata: Sequence[Mapping[str, Any]], field_of: FieldOf,
                   plate_size: Sequence[float] | None = None) -> None:
    """Check the metadata the analysis reads, whatever set it (``metadata[i]`` is shot i's).

    Sizes as :func:`check_sizes`; ``sphere_diameter`` groups the shots and sizes the inversion,
    so it must be a diameter in metres (0 < D <= :data:`SPHERE_DIAMETER_MAX`); ``x_m`` and
    ``y_m`` place the position on the plate: finite metres, within ``plate_size`` when the
    caller knows the plate (its table's); ``baseline`` is one of
    :data:`~.shot_measure.BASELINES`. ShotInputError naming the field (``field_of``).
    """
    for i, meta in enumerate(metadata):
        check_sizes(meta, functools.partial(field_of, i))
        d = meta.get("sphere_diameter")
        if d is not None and (not _real(d) or size_problem(float(d)) is not None):
            why = size_problem(float(d)) if _real(d) else f"{d!r} is not a sphere diameter"
            raise ShotInputError(field_of(i, "sphere_diameter"), str(why), f"a number of "
                                 f"metres, 0 < D <= {SPHERE_DIAMETER_MAX:g}")
        b = meta.get("baseline")
        if b is not None and b not in shot_measure.BASELINES:
            raise ShotInputError(field_of(i, "baseline"), f"{b!r} is not a baseline",
                                 " or ".join(shot_measure.BASELINES))
        for axis, key in enumerate(("x_m", "y_m")):
            v = meta.get(key)
            if v is None:
                continue
            high = plate_size[axis] if plate_size else None
            if _real(v) and (high is None or 0.0 <= float(v) <= high):
                continue
            allowed = (f"0..{high:g} m, within the plate (its table's size {plate_size[0]:g} x "
                       f"{plate_size[1]:g} m)" if plate_size and high is not None
                       else "a finite number of m")
            raise ShotInputError(field_of(i, key), f"{v!r} is not a position on the plate",
                                 allowed)


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, int | float) and isinstance(b, int | float):
        return math.isclose(float(a), float(b), rel_tol=1e-9, abs_tol=1e-12)
    return str(a).strip() == str(b).strip()


def located(meta: Mapping[str, Any], sources: Sequence[tuple[str, Mapping[str, Any]]],
            where: str) -> dict[str, Any]:
    """``meta`` with the location keys and the ``baseline`` the ``sources`` (name, metadata)
    state; a key two of them (the file included) state differently is a WaveformError naming
    both."""
    out = dict(meta)
    for key in (*LOCATION_KEYS, *CHOICE_KEYS, "baseline"):
        stated = [(f"the file ({where})", meta[key])] if meta.get(key) is not None else []
        stated += [(name, m[key]) for name, m in sources if m.get(key) is not None]
        for name, value in stated[1:]:
            if not _same(stated[0][1], value):
                raise WaveformError(key, f"{stated[0][0]} says {key} = {stated[0][1]!r}, "
                                    f"{name} says {value!r}", "one value, or leave one out")
        if stated:
            out[key] = stated[0][1]
    return out


# -- measure (a file's shots, each its own row) -------------------------------------------------

def _number(value: Any) -> float | None:
    try:
        return None if value is None else float(value)
    except (TypeError, ValueError):
        return None


def measure_file(path: Path, fmt: str | None, options: Mapping[str, Any], *,
                 fallback_calibration: float | None = None, channels: Sequence[str] = (),
                 group: str | None = None,
                 stated: Sequence[tuple[str, Mapping[str, Any]]] = ()
                 ) -> tuple[list[ShotRow], bool]:
    """One row per shot of ``path`` and whether ``fallback_calibration`` was used.

    The shots are the file's channels named by ``channels``/``group``, or else those that are
    sensor traces (signal.channels: a trigger step or a flat line is left out). Each shot's
    location is its own metadata with what the ``stated`` sources (name, metadata:
    a command line, a manifest row) add; a contradiction is a WaveformError, metadata the
    service would refuse a ShotInputError (``metadata.<key>``), either for the whole file. A shot
    the extractor cannot measure is a row with ``error``; one whose pulses do not fit a
    standard chain (no sphere size stated) is listed with its numbers and an ``error``, never
    summarised; the channels left out are rows with ``skipped`` (and no features). A measured
    shot's row holds ``features`` and ``waveform``.
    """
    waves, used = read_shots(path, fmt, options, fallback_calibration=fallback_calibration,
                             accepted_only=True)
    waves, skipped = signal_channels.select(waves, list(channels) or None, group, path.name)
    rows: list[ShotRow] = [{"source": str(path), "channel": s["channel"],
                            "skipped": s["reason"]} for s in skipped]
    metas = [located(w.metadata, stated, path.name) for w in waves]
    check_metadata(metas, lambda i, key: f"metadata.{key}")
    for w, meta in zip(waves, metas, strict=True):
        row = cast(ShotRow, {"source": str(path), "shot": meta.get("shot"),
                             "channel": signal_channels.channel_name(w)
                             if meta.get("channel") is not None else None,
                             **{k: meta.get(k) for k in LOCATION_KEYS},
                             **{k: meta[k] for k in CHOICE_KEYS if meta.get(k) is not None}})
        diameter = _number(meta.get("sphere_diameter"))
        try:
            feat, row["baseline"] = measure_waveform(w, meta)
        except WaveformError as exc:
            row["error"] = str(exc)
            rows.append(row)
            continue
        d = feat.to_dict()
        row.update(cast(ShotRow, {k: json_ready(d[k]) for k in (*FEATURES, *PEAK_READING)}))
        row["flags"] = d["flags"]
        row["arr_upper_bound"] = json_ready(d["arr_upper_bound"])
        if "implausible_units" in feat.flags:  # listed with its numbers, never summarised
            row["error"] = chain_geometry.units_message(feat, diameter)
            rows.append(row)
            continue
        row["features"] = feat
        row["waveform"] = w
        rows.append(row)
    return rows, used


def measure_waveform(waveform: Waveform, meta: Mapping[str, Any] | None = None
                     ) -> tuple[Any, str]:
    """A shot's features and the baseline they were measured on: the one measurement every
    door makes (``analyze``, the service's uploads and JSON shots, reanalysis).

    ``meta`` (the shot's metadata by default) gives the sphere size and the ``baseline`` asked
    for; a shot without a size whose pulses fit no standard chain is flagged
    ``implausible_units``. WaveformError where the extractor cannot read the shot."""
    meta = waveform.metadata if meta is None else meta
    diameter = _number(meta.get("sphere_diameter"))
    feat, baseline = shot_measure.measure_shot_baseline(
        waveform, diameter, baseline=meta.get("baseline") or "gap")
    if diameter is None and not chain_geometry.fits_some_chain(
            feat, chain_geometry.STANDARD_DIAMETERS):
        feat = dataclasses.replace(feat, flags=[*feat.flags, "implausible_units"])
    return feat, baseline


# -- group by position, summarise ---------------------------------------------------------------

PositionKey = tuple[Any, Any, float | None, float | None]
T = TypeVar("T")


def position_key(meta: Mapping[str, Any]) -> PositionKey:
    """Where a shot was taken: (plate_id, position, x_m, y_m); labels as text, coordinates as
    numbers (``0.25`` stated by a file and by a flag is one place)."""
    plate, pos = meta.get("plate_id"), meta.get("position")
    return (None if plate is None else str(plate), None if pos is None else str(pos),
            _coordinate(meta.get("x_m")), _coordinate(meta.get("y_m")))


def _coordinate(value: Any) -> Any:
    """A coordinate as a float, or as it is when it is none (None, or text a check refused)."""
    number = _number(value)
    return value if number is None else number


def by_position(items: Iterable[T], key: Callable[[T], Any]) -> dict[Any, list[T]]:
    """``items`` grouped by ``key(item)``, groups and members in the order they first appear."""
    groups: dict[Any, list[T]] = {}
    for item in items:
        groups.setdefault(key(item), []).append(item)
    return groups


def one_position(metadata: Sequence[Mapping[str, Any]], field_of: FieldOf
                 ) -> tuple[str | None, str | None]:
    """The plate and position every shot shares (one measurement is one position); a shot at
    another is a ShotInputError naming its ``plate_id`` or ``position``."""
    first = position_key(metadata[0])[:2]
    for i, meta in enumerate(metadata[1:], start=1):
        here = position_key(meta)[:2]
        if here != first:
            which = "plate_id" if here[0] != first[0] else "position"
            raise ShotInputError(field_of(i, which), f"{here} differs from shot 0's {first}; "
                                 "one measurement holds the shots of one position")
    return first


@dataclass(frozen=True)
class PositionShots:
    """The measured shots of one sphere size at one position and their summary."""

    location: ShotLocation
    summary: SizeSummary
    rows: list[ShotRow]


def summarise_positions(rows: Sequence[ShotRow]) -> list[PositionShots]:
    """Per (plate_id, position, x_m, y_m, sphere_diameter) the summary of its measured shots
    (rows from :func:`measure_file` that hold ``features``; instrument.inference.pipeline), in
    the order the groups first appear.

    Shots whose file names neither plate nor position are summarised per file (``source`` is
    then set), never pooled with other files' shots: nothing says they are one position.
    """
    from solitonde.instrument.inference.pipeline import summarise

    def key(r: ShotRow) -> tuple[Any, ...]:
        named = r.get("plate_id") is not None or r.get("position") is not None
        return (*position_key(r), _number(r.get("sphere_diameter")),
                None if named else r["source"])

    out = []
    for members in by_position((r for r in rows if "features" in r), key).values():
        first = members[0]
        location = cast(ShotLocation, {
            **{k: first.get(k) for k in LOCATION_KEYS},
            **{k: first.get(k) for k in CHOICE_KEYS if first.get(k) is not None},
            "source": key(first)[-1]})
        (summary,) = summarise([_number(location["sphere_diameter"])] * len(members),
                               [m["features"] for m in members])
        out.append(PositionShots(location, summary, members))
    return out


def summarise_shots(waveforms: Sequence[Waveform], features: Sequence[Any]
                    ) -> list[SizeSummary]:
    """The shots of one position (one measurement) summarised per sphere size."""
    from solitonde.instrument.inference.pipeline import summarise

    return summarise([wf.metadata.get("sphere_diameter") for wf in waveforms], features)
