"""Features of a shot (TOF, ARR, SNR, flags) and their aggregate over repeated shots.

TOF = t_reflected - t_incident, the time between the two pulses' peaks, and ARR =
F_reflected / F_incident, the ratio of their peaks above the sensor's reading before the impact
(the paper's definitions, Secs. 4.1.2-4.1.3), both from :func:`solitonde.signal.pulses.detect`.
``tof_s`` and ``arr`` read each peak on the fitted solitary-wave template: their mean under
white noise is what they read on the noise-free trace, at the Cramer-Rao bound's scatter, and
the model tables hold the same reading of the model's traces, so the shape's offset from the
trace's own peak (up to a few microseconds and percent on flat or skewed reflections) cancels
in an estimate. ``tof_peak_s`` and ``arr_peak`` are the trace's own peaks, refined on the
data's top: exact on a clean trace, but noise moves their mean towards the template's.
``arr_local`` is the ratio of the pulses' rises above the level the sensor holds just before
each (the extractor's ARR before it measured the paper's): immune to a baseline drift that the
pre-trigger cannot show, but larger than the ARR wherever the chain decompresses between the
pulses (gravity on: by 0.8 % of the ARR at D/t 2, 7 % at D/t 4). A shot without a detectable
reflection has no TOF and no ARR; it carries ``arr_upper_bound`` instead (the largest
excursion after the incident, or the detection threshold, over the incident peak), so a number
is never made up from noise.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any, Literal, NoReturn, TypeVar

import numpy as np

from . import kernels as K
from .errors import WaveformError
from .kernels import TRUNC_SPAN
from .outliers import MIN_SHOTS, cutoff, modified_z
from .pulses import Detection, DetectOptions, KernelArgs, analyzed, judged, snr_db
from .waveform import Waveform

EXTRACTOR_VERSION = 2
"""How the extractor reads a shot, as a number a model table records (``reading_version``): a
table's features compare with shots read the same way only. 2: the incident and the reflection
read on the slow trend of the record cut 2.5 FWHM after the reflection (the same reading however
long the record runs on); 1: on the whole record's trend (tables built before 2026-11-27)."""


AGGREGATE_VERSION = 2
"""How :func:`aggregate` rejects outliers, as a number stored measurements record (a study keeps
each position's aggregate, not its shots, so a file aggregated another way is not reused).
2: the level per number of shots (:mod:`.outliers`); 1: a fixed modified z-score of 3.5
(files written before 2026-11-29)."""


NUMBER = {"kind": "number"}
"""A float every shot with a pulse has."""
OPTIONAL = {"kind": "optional"}
"""A float, or None where the shot does not support it (no reflection: no TOF)."""
SERIES = {"kind": "series"}
"""A list of floats, one per secondary pulse."""
SUMMARISED = {"summarised": True}
"""Marks the numbers :func:`aggregate` summarises (:data:`FEATURES`)."""


@dataclass(frozen=True)
class Features:
    """What one shot says: times and peaks of the incident and reflected pulses, TOF, ARR, flags.

    ``None`` marks a quantity the shot does not support (no reflection: no TOF, ARR, reflected
    time or peak). Peaks are above ``baseline_N``, the pre-impact reading at the incident's peak;
    ``*_rise_N`` and ``arr_local`` are the rises above the level just before each pulse.
    ``secondary_times_s`` and ``secondary_ratios`` list the pulses after the reflection (peak
    over the incident peak); ``incident_width_s`` is the incident's full width at half maximum
    (the fitted template's), which a solitary wave ties to its force and the sphere size.
    ``reflection_window_s`` is the longest TOF the record could measure: from the incident's
    peak to the record's end, less the reach a pulse needs to be whole (:func:`window_of`); a
    shot without a reflection says nothing about one arriving later (None: not known).

    The fields are the one declaration of a shot's features: each field's ``metadata`` says its
    kind (:data:`NUMBER`, :data:`OPTIONAL`, :data:`SERIES`; ``flags`` is the list of flag names)
    and whether :func:`aggregate` summarises it; :meth:`to_dict`, :data:`FEATURES` and the batch
    path's :class:`~solitonde.signal.batch.FeatureTable` are derived from them.
    """

    tof_s: float | None = field(metadata={**OPTIONAL, **SUMMARISED})
    arr: float | None = field(metadata={**OPTIONAL, **SUMMARISED})
    incident_time_s: float = field(metadata={**NUMBER, **SUMMARISED})
    reflected_time_s: float | None = field(metadata={**OPTIONAL, **SUMMARISED})
    incident_peak_N: float = field(metadata={**NUMBER, **SUMMARISED})
    reflected_peak_N: float | None = field(metadata={**OPTIONAL, **SUMMARISED})
    snr_db: float = field(metadata={**NUMBER, **SUMMARISED})
    flags: list[str] = field(metadata={"kind": "flags"})
    arr_upper_bound: float | None = field(default=None, metadata=OPTIONAL)
    secondary_times_s: list[float] = field(default_factory=list, metadata=SERIES)
    secondary_ratios: list[float] = field(default_factory=list, metadata=SERIES)
    baseline_N: float = field(default=0.0, metadata=NUMBER)
    noise_N: float = field(default=0.0, metadata=NUMBER)
    arr_local: float | None = field(default=None, metadata=OPTIONAL)
    incident_rise_N: float | None = field(default=None, metadata=NUMBER)
    reflected_rise_N: float | None = field(default=None, metadata=OPTIONAL)
    tof_peak_s: float | None = field(default=None, metadata=OPTIONAL)
    arr_peak: float | None = field(default=None, metadata=OPTIONAL)
    incident_width_s: float = field(default=0.0, metadata=NUMBER)
    reflection_window_s: float | None = field(default=None, metadata=OPTIONAL)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Features:
        """The features again from :meth:`to_dict`'s form (a stored shot's); keys that are no
        field (a later extractor's, a door's ``baseline`` tag) are left out."""
        values: dict[str, Any] = {
            f.name: (list(data[f.name]) if f.metadata["kind"] in ("series", "flags")
                     else data[f.name])
            for f in fields(cls) if f.name in data}
        return cls(**values)

    @classmethod
    def whole(cls, values: dict[str, Any]) -> Features:
        """The features from ``values``, which names every field and nothing else (checked), set
        at once: a frozen dataclass's ``__init__`` sets its fields one ``object.__setattr__`` at
        a time, 1.7 us of the extractor's 100 us a shot."""
        if values.keys() != _FIELD_NAMES:
            raise TypeError(f"Features.whole takes every field: missing "
                            f"{sorted(_FIELD_NAMES - values.keys())}, extra "
                            f"{sorted(values.keys() - _FIELD_NAMES)}")
        made = object.__new__(cls)
        made.__dict__.update(values)
        return made

    def to_dict(self) -> FeatureDict:
        """JSON-safe dict with unit-carrying keys, in field order; lists copied."""
        out: FeatureDict = {}
        for f in fields(self):
            value = getattr(self, f.name)
            out[f.name] = list(value) if f.metadata["kind"] in ("series", "flags") else value
        return out


FeatureValue = float | str | list[float] | list[str] | None
"""One feature's JSON value: a number or None, a list of numbers (a series) or of flag names, or
a tag a door adds (``baseline``; ``error`` where no pulse was found)."""
FeatureDict = dict[str, FeatureValue]
"""A shot's features as JSON (:meth:`Features.to_dict`), keyed by field name."""


_FIELD_NAMES = frozenset(f.name for f in fields(Features))
FEATURES = tuple(f.name for f in fields(Features) if f.metadata.get("summarised"))
"""The per-shot numbers, in the order tables and files list them."""
FIELD_KINDS: dict[str, str] = {f.name: f.metadata["kind"] for f in fields(Features)}
"""Each field of :class:`Features` and its kind (``number``, ``optional``, ``series``,
``flags``)."""


Seconds = TypeVar("Seconds", float, np.ndarray)


def window_of(record_end_s: float, incident_time_s: Seconds, incident_width_s: Seconds
              ) -> Seconds:
    """The longest TOF a record ending at ``record_end_s`` measures whole: a pulse whose peak
    lies within ``TRUNC_SPAN`` FWHM of the record's end is truncated (the reflection's width
    taken as the incident's). Per shot (floats) or for a batch (arrays, one element a shot)."""
    return record_end_s - incident_time_s - TRUNC_SPAN * incident_width_s


def from_detection(det: Detection) -> Features:
    """Features from a :class:`Detection`; raises if the shot holds no pulse at all."""
    inc = det.incident
    if inc is None:
        _no_pulse(det.threshold_N, det.noise_N)
    ref = det.reflected
    return Features(
        tof_s=None if ref is None else ref.time_s - inc.time_s,
        arr=None if ref is None else ref.peak_N / inc.peak_N,
        incident_time_s=inc.time_s,
        reflected_time_s=None if ref is None else ref.time_s,
        incident_peak_N=inc.peak_N,
        reflected_peak_N=None if ref is None else ref.peak_N,
        snr_db=inc.snr_db,
        flags=list(det.flags),
        arr_upper_bound=det.arr_upper_bound,
        secondary_times_s=[p.time_s for p in det.secondary],
        secondary_ratios=[p.peak_N / inc.peak_N for p in det.secondary],
        baseline_N=det.baseline_N,
        noise_N=det.noise_N,
        arr_local=None if ref is None else ref.rise_N / inc.rise_N,
        incident_rise_N=inc.rise_N,
        reflected_rise_N=None if ref is None else ref.rise_N,
        tof_peak_s=None if ref is None else ref.peak_time_s - inc.peak_time_s,
        arr_peak=None if ref is None else ref.peak_height_N / inc.peak_height_N,
        incident_width_s=inc.width_s,
        reflection_window_s=(None if det.record_end_s is None
                             else window_of(det.record_end_s, inc.time_s, inc.width_s)),
    )


def extract(waveform: Waveform, **options: Any) -> Features:
    """TOF, ARR, SNR and flags of one shot; ``options`` are :class:`DetectOptions` fields."""
    return _extracted(waveform, DetectOptions.from_kwargs(options), {})


def extract_many(waveforms: Sequence[Waveform], **options: Any) -> list[Features]:
    """:func:`extract` over many shots with the options validated, and the kernel's arguments
    worked out, once."""
    opts = DetectOptions.from_kwargs(options)
    args: KernelArgs = {}
    return [_extracted(w, opts, args) for w in waveforms]


def _extracted(waveform: Waveform, opts: DetectOptions, args: KernelArgs) -> Features:
    """:func:`from_detection` of :func:`~solitonde.signal.pulses.detect`, read straight from the
    kernels' rows: the same numbers, without the :class:`Pulse` and :class:`Detection` objects
    and the notes, which the features do not keep (a third of the Python time of a shot)."""
    shot = analyzed(waveform, opts, args)
    head, rows, t0, dt = shot.head, shot.rows, shot.t0, shot.dt
    if not rows:
        _no_pulse(head[K.H_THR], head[K.H_SIGMA])
    verdict = judged(shot, opts)
    inc = rows[0]
    inc_t = t0 + inc[K.P_TIME] * dt
    inc_a = inc[K.P_AMP]
    inc_w = inc[K.P_WIDTH] * dt
    ref = rows[1] if verdict.reflected else None
    ref_t = None if ref is None else t0 + ref[K.P_TIME] * dt
    return Features.whole({
        "tof_s": None if ref_t is None else ref_t - inc_t,
        "arr": None if ref is None else ref[K.P_AMP] / inc_a,
        "incident_time_s": inc_t,
        "reflected_time_s": ref_t,
        "incident_peak_N": inc_a,
        "reflected_peak_N": None if ref is None else ref[K.P_AMP],
        "snr_db": snr_db(inc_a, head[K.H_SIGMA]),
        "flags": list(verdict.flags),
        "arr_upper_bound": head[K.H_UPPER] if ref is None else None,
        "secondary_times_s": [t0 + rows[j][K.P_TIME] * dt for j in verdict.secondary],
        "secondary_ratios": [rows[j][K.P_AMP] / inc_a for j in verdict.secondary],
        "baseline_N": head[K.H_SIGN] * inc[K.P_BASE],
        "noise_N": head[K.H_SIGMA],
        "arr_local": None if ref is None else ref[K.P_RISE] / inc[K.P_RISE],
        "incident_rise_N": inc[K.P_RISE],
        "reflected_rise_N": None if ref is None else ref[K.P_RISE],
        "tof_peak_s": None if ref is None else ((t0 + ref[K.P_PEAK_TIME] * dt)
                                             - (t0 + inc[K.P_PEAK_TIME] * dt)),
        "arr_peak": None if ref is None else ref[K.P_PEAK_AMP] / inc[K.P_PEAK_AMP],
        "incident_width_s": inc_w,
        "reflection_window_s": window_of(shot.end_s, inc_t, inc_w),
    })


def _no_pulse(threshold_N: float, noise_N: float) -> NoReturn:
    """The error of a shot in which no pulse rises above the detection threshold."""
    raise WaveformError(
        "samples",
        f"no pulse rises above the noise (threshold {threshold_N:.3g} N over a noise of "
        f"{noise_N:.3g} N)",
        "a shot holding at least the incident pulse",
    )


@dataclass(frozen=True)
class Stat:
    """Mean, sample standard deviation and count of one feature over the kept shots."""

    mean: float | None
    std: float | None
    count: int

    def to_dict(self) -> dict[str, Any]:
        return {"mean": self.mean, "std": self.std, "count": self.count}


@dataclass(frozen=True)
class Aggregate:
    """Repeated shots at one position: statistics per feature and what was left out, and why.

    ``rejected`` lists every shot index dropped as an outlier with the feature, value and
    modified z-score that condemned it; ``no_reflection`` the shots without a reflection (they
    count for ``arr_upper_bound`` only, which holds for a reflection arriving within
    ``reflection_window_s`` of the incident: the shortest record's window, None when a shot's is
    not known).
    """

    n_shots: int
    stats: dict[str, Stat]
    rejected: list[dict[str, Any]]
    no_reflection: list[int]
    arr_upper_bound: float | None
    flag_counts: dict[str, int]
    reflection_window_s: float | None = None

    def __getitem__(self, name: str) -> Stat:
        return self.stats[name]

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"n_shots": self.n_shots}
        for name, stat in self.stats.items():
            out[name] = stat.to_dict()
        out["rejected"] = [dict(r) for r in self.rejected]
        out["no_reflection"] = list(self.no_reflection)
        out["arr_upper_bound"] = self.arr_upper_bound
        out["flag_counts"] = dict(self.flag_counts)
        out["reflection_window_s"] = self.reflection_window_s
        return out


TRUNCATED_REASON = ("truncated: a pulse it measures runs past the record's start or end (the "
                    "reflection cut by the end of the record, or the incident by its start); "
                    "record longer after the trigger, or start it earlier")
"""Why :func:`aggregate` rejects a truncated shot (the pipeline names it when every shot is)."""
SATURATED_REASON = ("saturated: the record's top value repeats over the incident's peak (the "
                    "sensor, amplifier or scope clipped it), so the peak and every ratio to it "
                    "read wrong; lower the gain or widen the scope's range")
"""Why :func:`aggregate` rejects a saturated shot."""
EARLY_REASON = ("early_reflection: a strong pulse arrives after the incident's train and before "
                "the stated chain's reflection can, and none where it should: the chain below the "
                "sensor is shorter than stated (the sensor's place, the number of spheres); a "
                "table of your chain (table build --scene) reads it")
"""Why :func:`aggregate` rejects a shot whose reflection came too early for the stated chain."""
UNSTEADY_REASON = ("unsteady_baseline: the sensor's level jumped between the pulses (the drift "
                   "fitted on the pre-trigger and the gap misses them), so the reflection's "
                   "baseline is not known; check the amplifier's range and the cabling")
"""Why :func:`aggregate` rejects a shot whose baseline jumped."""
UNITS_REASON = ("implausible_units: the incident's width and amplitude disagree with the "
                "chain's solitary wave (the units or the calibration)")
REJECTING = {
    "implausible_units": ("incident_width_s", UNITS_REASON),
    "truncated": ("reflection_window_s", TRUNCATED_REASON),
    "early_reflection": ("secondary_times_s", EARLY_REASON),
    "unsteady_baseline": ("baseline_N", UNSTEADY_REASON),
    "saturated": ("incident_peak_N", SATURATED_REASON),
}
"""The flags that reject a shot from :func:`aggregate`, first match first: the feature its
row names (with that feature's value, none for a series) and the reason."""


def aggregate(
    features: Sequence[Features], outlier_z: float | Literal["auto"] | None = "auto",
    min_for_rejection: int = MIN_SHOTS,
) -> Aggregate:
    """Mean, standard deviation and count per feature over repeated shots, with outliers reported.

    A shot flagged ``implausible_units`` is rejected first (its numbers are in units nobody
    stated), and so is one flagged ``truncated``: a pulse it measures runs past the record's
    start or end, so its peak (or the reflection's very presence) is not whole, and neither its
    TOF and ARR nor the absence of a reflection says anything; and one flagged ``saturated``: its
    incident's peak was clipped, so its ARR reads high (a 4.0 mm steel plate cut at 25 N of its
    33.7 N read ARR 0.84 for 0.67); one flagged ``early_reflection``, whose "no reflection"
    (and its ARR bound) holds only for a chain it was not recorded on; and one flagged
    ``unsteady_baseline``, whose level jumped between the pulses. A shot is rejected when
    its TOF or ARR has a modified z-score above ``outlier_z`` among the shots with a reflection
    (only with at least ``min_for_rejection`` of them; ``None`` turns rejection off). The
    default, ``"auto"``, is the level for that many shots that sets of good shots cross in 1 %
    of sets (:func:`.outliers.level`; :data:`.outliers.FLAT_LEVEL` where most values are
    equal). Rejected shots are listed, never dropped silently.
    """
    if not features:
        raise WaveformError("features", "nothing to aggregate", "at least one shot's features")
    n = len(features)
    rejected: list[dict[str, Any]] = []
    dropped: set[int] = set()
    for i, f in enumerate(features):
        # the first of the shot's flags that rejects it, in REJECTING order
        flag = next((name for name in REJECTING if name in f.flags), None)
        if flag is not None:
            dropped.add(i)
            feature, reason = REJECTING[flag]
            value = None if FIELD_KINDS[feature] == "series" else getattr(f, feature)
            rejected.append({"index": i, "feature": feature, "value": value,
                             "modified_z": None, "reason": reason})
    with_ref = [i for i, f in enumerate(features)
                if f.tof_s is not None and f.arr is not None and i not in dropped]
    no_ref = [i for i in range(n) if i not in set(with_ref) and i not in dropped]
    testable = min_for_rejection if outlier_z != "auto" else max(min_for_rejection, MIN_SHOTS)
    if outlier_z is not None and len(with_ref) >= testable:
        for name in ("tof_s", "arr"):
            values = np.array([getattr(features[i], name) for i in with_ref])
            z, flat = modified_z(values)
            cut, why = cutoff(outlier_z, len(with_ref), flat)
            for i, zi, vi in zip(with_ref, z, values, strict=True):
                if zi > cut and i not in dropped:
                    dropped.add(i)
                    finite = bool(np.isfinite(vi))
                    rejected.append({
                        "index": i, "feature": name, "value": float(vi) if finite else None,
                        "modified_z": float(zi) if finite else None,
                        "reason": why if finite else "not a finite number",
                    })
    kept = [i for i in range(n) if i not in dropped]
    stats: dict[str, Stat] = {}
    for name in FEATURES:
        vals = np.array([v for i in kept if (v := getattr(features[i], name)) is not None],
                        dtype=np.float64)
        vals = vals[np.isfinite(vals)]
        if vals.size == 0:
            stats[name] = Stat(None, None, 0)
        else:
            std = float(np.std(vals, ddof=1)) if vals.size > 1 else None
            stats[name] = Stat(float(np.mean(vals)), std, int(vals.size))
    bounds = [b for i in no_ref if (b := features[i].arr_upper_bound) is not None]
    windows = [w for i in no_ref if (w := features[i].reflection_window_s) is not None]
    counts: dict[str, int] = {}
    for f in features:
        for flag in f.flags:
            counts[flag] = counts.get(flag, 0) + 1
    return Aggregate(
        n_shots=n,
        stats=stats,
        rejected=rejected,
        no_reflection=no_ref,
        arr_upper_bound=max(bounds) if bounds and not with_ref else None,
        flag_counts=counts,
        reflection_window_s=(min(windows) if windows and len(windows) == len(no_ref)
                             and not with_ref else None),
    )
