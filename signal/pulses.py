"""Pulse detection: baseline and noise, incident, reflected and secondary pulses, quality flags.

All the work on the samples is one numba pass (:func:`solitonde.signal.kernels.analyze`);
this module holds the options, the result types and the flag logic. The steps, each chosen so
that a number is never picked out of noise:

1. Pre-trigger segment: everything before the first rise (first crossing of a quarter of the
   largest excursion, walked back to its onset), then, once pulses are known, everything before
   the incident's foot (1.5 FWHM before its peak), or ``pretrigger_s``. Baseline = its median,
   noise = the MAD about its least-squares line (slow drift is not noise). A noise-free trace
   works: the noise is floored at 1e-9 of the largest excursion.
2. Optional zero-phase Butterworth low-pass (``lowpass_hz``).
3. A zero-phase triangular smoother (two running sums) whose width follows the largest pulse's
   width; pulses are the peaks of the smoothed trace that rise ``threshold_sigma`` smoothed-noise
   deviations (and ``min_ratio`` of the largest pulse) above the baseline and stand out by as much
   from their neighbours (hysteresis search).
4. Slow trend: a least-squares quadratic through every sample further than 2 FWHM from a pulse
   (follows acquisition drift and the chain's slow level changes); detection is redone against it.
   With a travel gate, the trend under the incident and the reflection is refitted on the record
   as it stands 2.5 FWHM after the reflection's peak (the whole record's kept beyond), so that a
   shot reads the same however long its record runs on (the chain's level after the reflection
   bent the whole record's quadratic: ARR up to 0.6 % apart between records ending 4 and 10
   widths after it).
5. Incident = first pulse; reflected = the next one (flagged ``overlapping`` if the incident has
   not decayed in between); the rest are secondary pulses.
6. Each pulse is measured on the raw samples, as the paper defines TOF and ARR: its peak time,
   and its peak's height above the sensor's reading before the impact (the pre-trigger up to 3
   FWHM before the incident's peak: its mean, or its least-squares line where its slope is four
   standard errors from zero). First the skewed super-Gaussian ``A exp(-|u|^r)``,
   ``u = (t - tc) / (w (1 +- skew))``, is fitted by least squares (amplitude, time, width; ``r``
   too if asked) to the part of the pulse above ``fit_fraction`` of its height, on the level the
   sensor holds just before the pulse (the mean of the samples about the slow trend between the
   previous pulse's foot and this one's, at most 12 FWHM). The chain's incident pulse rises
   slightly faster than it falls; a reflection travels the other way up the chain, so the
   incident gets ``+skew``, later pulses ``-skew``. If the fit fails, a least-squares parabola
   through the top is used instead. That template reads a pulse of its own shape with the least
   noise, but reflections differ (from a soft plate without preload they rise slower than they
   fall, flat-topped near D/t 4, split in two humps above), and the fitted peak then misses the
   pulse's by up to several microseconds and percent. So the peak is refined on the data's top
   (:mod:`.peak_refine`): quartics over windows from a few samples to a quarter of the pulse's
   height, the widest estimate (the template's last) that agrees with every narrower one within
   its noise is kept, time and height apart. A clean trace gets the trace's own peak; a noisy one
   keeps the template's wherever the data cannot tell it wrong. The incident and the reflection
   are read on the same window for the ARR. That choice follows the noise, and so did the mean
   of what it read: the template's own peak (``time_s``, ``peak_N``: TOF and ARR) is therefore
   the reading, a fixed rule at the Cramer-Rao scatter whose mean under noise is its noise-free
   value, and the refined peak is kept beside it (``peak_time_s``, ``peak_height_N``). The
   template's height above the level before the pulse stays as ``rise_N`` (drift-immune; see
   :mod:`solitonde.signal.features`).
7. Where the chain is known (``travel_time_1n_s``, ``pulse_width_1n_s``), the reflection is the
   first pulse inside the travel gate (a heavy striker's train before it is secondary), and an
   incident whose width disagrees with a solitary wave of its force is ``implausible_units``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any, NamedTuple

import numpy as np

from . import kernel_choice
from . import kernels as K
from .errors import WaveformError
from .waveform import Waveform

FLAGS = (
    "no_reflection",
    "saturated",
    "low_snr",
    "overlapping",
    "truncated",
    "inverted_polarity",
    "implausible_units",
    "early_reflection",
    "unsteady_baseline",
)
"""Every quality flag detection can raise, in the order they are reported."""
EARLY_FROM, EARLY_RATIO = 0.5, 0.3
"""With a travel gate and no pulse inside it, a pulse of at least ``EARLY_RATIO`` of the incident
arriving between ``EARLY_FROM`` and :data:`~.kernels.GATE_LO` round trips after it is
``early_reflection``: not the incident's train (a train pulse that strong travels at 0.82 or more
of the incident's speed, F^(1/6), and leaves the striker within a few pulse widths of it, so it
follows within about a fifth of the trip) and too early for the stated chain's reflection. It is
the reflection of a chain shorter below the sensor than the one stated (the sensor sits lower),
and the shot's "no reflection" and its ARR bound would read a thick plate as a thin one."""

STEP_FLOOR = 0.005
"""``unsteady_baseline``: the drift fitted on the pre-trigger and the gap (:mod:`.gap_drift`)
misses one of its stretches by a mean residual above this fraction of the incident's height (and
above five standard errors of that mean). A smooth drift (a 5 % parabola over the record) and
the relaxation of any striker the model knows leave under 0.04 %; a real chain's relaxation off
by half of the model's would leave about 0.3 %; a level that jumps by 6 % of the incident between
the pulses (a range switch, a knocked cable) leaves 1.0 % and moves the ARR by 7 %, by 1.7 % at
1.5 % (0.3 % left). Such a shot's baseline under the reflection is not known."""

METHODS = ("template", "parabola", "refined")
"""Where a pulse's peak comes from, by the kernel's ``P_METHOD`` code."""
MIN_PRETRIGGER = K.MIN_PRETRIGGER
SHAPE_EXPONENT = 2.38
"""Exponent r of the fitted shape: least squares of the skewed template against the chain
model's incident pulse at the sensor (D = 4.76 to 19.05 mm) gives r = 2.35 to 2.41, residual
0.25 % of the peak (Nesterenko's cos^6 is close to r = 2)."""
WIDTH_TOLERANCE = 1.25
"""``implausible_units`` is raised when the incident's width differs from a solitary wave's of its
amplitude by more than this factor either way (a factor 10 in force moves the width by 1.47,
Nesterenko's F^(-1/6); a volt read as a millivolt by 3.2, a millisecond read as a microsecond by
1000; the chain's own spread, gravity and striker included, is within 3 %)."""
SHAPE_SKEW = 0.0045
"""Skew of the fitted shape, same fit: the model's incident pulse rises faster than it falls
(skew 0.0041 to 0.0045); its reflections fit -0.003 to -0.006 (-0.018 for D = 19.05 mm)."""
MAX_ITER = 50


DetectKeywords = dict[str, float | str | None]
"""Some of :class:`DetectOptions`' fields as JSON keywords (a model table's ``detect``)."""


@dataclass(frozen=True)
class DetectOptions:
    """Tuning of :func:`detect`; every field can be passed as a keyword to ``detect``/``extract``.

    Attributes
    ----------
    pretrigger_s:
        Length of the pre-trigger segment from the record start, s; ``None`` finds it.
    threshold_sigma:
        Detection threshold in standard deviations of the smoothed noise.
    min_ratio:
        Pulses smaller than this fraction of the largest pulse are ignored (and bound an absent
        reflection's ARR from above).
    lowpass_hz:
        Cut-off of an optional zero-phase 4th-order Butterworth low-pass, Hz.
    smooth_samples:
        Half-width of the detection smoother in samples; ``None`` follows the pulse width.
    polarity:
        ``"auto"`` (flip and flag ``inverted_polarity`` when the largest excursion is negative),
        ``"positive"`` or ``"negative"``.
    low_snr_db:
        ``low_snr`` is raised when the reflected pulse (the incident if none) is below this SNR.
    fit_fraction:
        The shape fit uses the part of each pulse above this fraction of its peak.
    shape_exponent:
        Exponent r of the fitted shape ``A exp(-|u|^r)``. The default 2.38 is the chain's
        solitary wave at the sensor (amplitude-independent in scaled time), which halves the ARR
        scatter against a free r; ``None`` fits r too (other pulse shapes: Nesterenko's cos^6
        reads about 3.5 % low in amplitude with r fixed, 0.5 % with r free; ratios are
        unaffected).
    shape_skew:
        Skew of the fitted shape, ``u = (t - tc) / (w (1 + skew sign(t - tc)))``; the incident
        gets ``+shape_skew``, later pulses ``-shape_skew``. ``0`` for symmetric pulses.
    max_secondary:
        At most this many secondary pulses are reported.
    travel_time_1n_s:
        The chain's geometry, where known: the time a solitary wave of 1 N peak force takes from
        the sensor down to the plate and back up, s (``2 N D / V_s(1 N)``; a wave of peak F
        travels at ``V_s(1 N) F^(1/6)``, Nesterenko). The reflection is then the first pulse
        that arrives between 0.75 and 3.2 times that trip at the measured incident's speed
        after it; pulses before that belong to the incident's train (a striker heavier than the
        spheres launches several waves) and are listed as secondary. ``None``: the pulse after
        the incident is the reflection. Needs the trace in newtons.
    pulse_width_1n_s:
        The chain's solitary wave, where known: the full width at half maximum of a wave of 1 N
        peak force at the sensor, s (``1.92 D / V_s(1 N)``; a wave of peak F is ``F^(-1/6)``
        times that). An incident more than :data:`WIDTH_TOLERANCE` off that law for its
        measured amplitude raises ``implausible_units``: the force or the time axis is not in
        the units the file states. Needs the trace in newtons.
    relaxation_N:
        The chain's own level after the incident, where known: the clean sensor reading above
        the pre-impact one, N, one value per sample interval of the shot from the incident's
        peak on, up to before any reflection returns (a model trace of the chain:
        :func:`solitonde.instrument.inference.chain_geometry.relaxation`; zeros without gravity).
        The baseline drift is then measured on the gap between the incident and the reflection,
        less this, as well as on the pre-trigger (:mod:`solitonde.signal.gap_drift`): a drift
        or offset leaves TOF and ARR as the paper defines them. ``None``: the pre-trigger's
        baseline (its line where its slope stands out of the noise). Needs the trace in newtons.
    """

    pretrigger_s: float | None = None
    threshold_sigma: float = 6.0
    min_ratio: float = 0.02
    lowpass_hz: float | None = None
    smooth_samples: int | None = None
    polarity: str = "auto"
    low_snr_db: float = 15.0
    fit_fraction: float = 0.1
    shape_exponent: float | None = SHAPE_EXPONENT
    shape_skew: float = SHAPE_SKEW
    max_secondary: int = 8
    travel_time_1n_s: float | None = None
    pulse_width_1n_s: float | None = None
    relaxation_N: np.ndarray | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        def bad(name: str, allowed: str) -> WaveformError:
            return WaveformError(name, f"got {getattr(self, name)!r}", allowed)

        if self.pretrigger_s is not None and not (
            math.isfinite(self.pretrigger_s) and self.pretrigger_s > 0
        ):
            raise bad("pretrigger_s", "a positive duration in s, or None")
        if not (math.isfinite(self.threshold_sigma) and self.threshold_sigma > 0):
            raise bad("threshold_sigma", "a positive number")
        if not 0 <= self.min_ratio < 1:
            raise bad("min_ratio", "0 <= min_ratio < 1")
        if self.lowpass_hz is not None and not (
            math.isfinite(self.lowpass_hz) and self.lowpass_hz > 0
        ):
            raise bad("lowpass_hz", "a positive frequency in Hz below Nyquist, or None")
        if self.smooth_samples is not None and (
            not isinstance(self.smooth_samples, int) or self.smooth_samples < 0
        ):
            raise bad("smooth_samples", "a non-negative integer, or None")
        if self.polarity not in ("auto", "positive", "negative"):
            raise bad("polarity", "'auto', 'positive' or 'negative'")
        if not 0.05 <= self.fit_fraction <= 0.9:
            raise bad("fit_fraction", "0.05 <= fit_fraction <= 0.9")
        if self.shape_exponent is not None and not 1.2 <= self.shape_exponent <= 8:
            raise bad("shape_exponent", "1.2 <= shape_exponent <= 8, or None")
        if not (math.isfinite(self.shape_skew) and abs(self.shape_skew) <= 0.3):
            raise bad("shape_skew", "-0.3 <= shape_skew <= 0.3")
        if not isinstance(self.max_secondary, int) or self.max_secondary < 0:
            raise bad("max_secondary", "a non-negative integer")
        if self.travel_time_1n_s is not None and not (
            math.isfinite(self.travel_time_1n_s) and self.travel_time_1n_s > 0
        ):
            raise bad("travel_time_1n_s", "a positive duration in s, or None")
        if self.pulse_width_1n_s is not None and not (
            math.isfinite(self.pulse_width_1n_s) and self.pulse_width_1n_s > 0
        ):
            raise bad("pulse_width_1n_s", "a positive duration in s, or None")
        if self.relaxation_N is not None:
            try:  # the options' own copy, in the one array type the kernels take
                relax = np.array(self.relaxation_N, dtype=np.float64)
            except (TypeError, ValueError):
                raise bad("relaxation_N", "a sequence of levels in N, or None") from None
            if relax.ndim != 1 or relax.size < 2 or not np.isfinite(relax).all():
                raise bad("relaxation_N", "at least two finite levels in N, or None")
            object.__setattr__(self, "relaxation_N", relax)

    @classmethod
    def from_kwargs(cls, options: dict[str, Any]) -> DetectOptions:
        """Options from keywords; an unknown keyword is an error naming it."""
        names = {f.name for f in fields(cls)}
        for key in options:
            if key not in names:
                raise WaveformError(key, "unknown detection option", ", ".join(sorted(names)))
        return cls(**options)


@dataclass(frozen=True)
class Pulse:
    """One detected pulse, refined on the raw samples.

    ``time_s`` is the fitted template's sub-sample peak time and ``peak_N`` its peak above the
    pre-impact baseline ``baseline_N`` (the sensor's reading before the impact, at that time): a
    fixed estimator, near the Cramer-Rao bound, whose mean under noise is what it reads on the
    noise-free trace (the model tables hold that reading). ``peak_time_s`` and ``peak_height_N``
    are the peak refined on the data's top: the trace's own peak on a clean trace (the paper's
    definitions exactly), but its mean moves with the noise (see :mod:`.peak_refine`).
    ``rise_N`` is the fitted template's height above ``level_N``, the level the sensor holds just
    before the pulse (immune to baseline drift, but not the paper's amplitude: after the incident
    the chain decompresses and the sensor sits below its static reading). ``width_s`` is the full
    width at half maximum of the fitted shape; ``method`` says where ``time_s`` and ``peak_N``
    come from: ``"template"``, or ``"parabola"`` where the template fit failed (``"refined"``:
    the template's, with a refined peak that differs from it).
    """

    time_s: float
    peak_N: float
    baseline_N: float
    width_s: float
    onset_s: float
    end_s: float
    snr_db: float
    index: int
    method: str
    rise_N: float = math.nan
    level_N: float = math.nan
    peak_time_s: float = math.nan
    peak_height_N: float = math.nan


@dataclass(frozen=True)
class Detection:
    """Everything :func:`detect` found in one shot."""

    baseline_N: float
    noise_N: float
    threshold_N: float
    pretrigger_samples: int
    smooth_samples: int
    pulses: tuple[Pulse, ...]
    incident: Pulse | None
    reflected: Pulse | None
    secondary: tuple[Pulse, ...]
    flags: tuple[str, ...]
    arr_upper_bound: float | None = None
    notes: tuple[str, ...] = field(default_factory=tuple)
    record_end_s: float | None = None
    """Time of the record's last sample (how late a pulse could still be seen)."""


def lowpass(x: np.ndarray, dt: float, cutoff: float) -> np.ndarray:
    """Zero-phase 4th-order Butterworth low-pass of ``x``, the cut-off checked below Nyquist."""
    from scipy.signal import butter, sosfiltfilt

    nyquist = 0.5 / dt
    if cutoff >= nyquist:
        raise WaveformError(
            "lowpass_hz", f"{cutoff:g} Hz is not below Nyquist ({nyquist:g} Hz)",
            "0 < lowpass_hz < sample_rate / 2",
        )
    sos = butter(4, cutoff, fs=1.0 / dt, output="sos")
    return sosfiltfilt(sos, x)


def snr_db(amplitude: float, noise: float) -> float:
    """``20 log10(amplitude / noise)``, the SNR convention of :mod:`solitonde.signal.synth`."""
    return 20.0 * math.log10(max(amplitude, 1e-300) / noise)


def kernel_args(opts: DetectOptions, n: int, dt: float) -> tuple[Any, ...]:
    """The arguments :func:`solitonde.signal.kernels.analyze` takes after the samples, for
    ``n``-sample records at period ``dt``; raises if ``pretrigger_s`` does not fit the record."""
    n_pre = -1
    if opts.pretrigger_s is not None:
        n_pre = int(opts.pretrigger_s / dt)
        if not MIN_PRETRIGGER <= n_pre <= n - MIN_PRETRIGGER:
            raise WaveformError(
                "pretrigger_s",
                f"{opts.pretrigger_s:g} s is {n_pre} samples of a {n}-sample record",
                f"{MIN_PRETRIGGER} samples to the record length minus {MIN_PRETRIGGER}",
            )
    sign = {"auto": 0.0, "positive": 1.0, "negative": -1.0}[opts.polarity]
    free_r = opts.shape_exponent is None
    return (
        sign, n_pre, -1 if opts.smooth_samples is None else opts.smooth_samples,
        opts.threshold_sigma, opts.min_ratio, opts.fit_fraction,
        SHAPE_EXPONENT if free_r else opts.shape_exponent, opts.shape_skew, free_r, MAX_ITER,
        0.0 if opts.travel_time_1n_s is None else opts.travel_time_1n_s / dt,
        np.zeros(0) if opts.relaxation_N is None else opts.relaxation_N,
    )


def detect(waveform: Waveform, options: DetectOptions | None = None, **kwargs: Any) -> Detection:
    """Find the incident, reflected and secondary pulses of one shot and flag what is doubtful.

    Parameters
    ----------
    waveform:
        The shot; volts are converted to newtons with its calibration.
    options, **kwargs:
        A :class:`DetectOptions`, or its fields as keywords.

    Raises
    ------
    WaveformError
        For bad options, or a pre-trigger segment that does not fit the record.
    """
    opts = options if options is not None else DetectOptions.from_kwargs(kwargs)
    return _detect(waveform, opts, {})


KernelArgs = dict[tuple[int, float], tuple[Any, ...]]
""":func:`kernel_args` per record length and sample period, for one :class:`DetectOptions`."""


class Shot(NamedTuple):
    """One shot as the kernels left it: ``head[H_*]`` and one row ``rows[j][P_*]`` per pulse
    (Python floats: cheaper to read one by one than numpy scalars), and the time axis."""

    head: list[float]
    rows: list[list[float]]
    t0: float
    dt: float
    end_s: float
    """Time of the record's last sample."""


class Verdict(NamedTuple):
    """What the pulses of a :class:`Shot` with at least one pulse are, and the flags it raises:
    the one reading of the kernels' output that :func:`detect` and
    :func:`solitonde.signal.features.extract` share."""

    reflected: bool
    """``rows[1]`` is the reflection."""
    secondary: range
    """The rows listed as secondary pulses."""
    raised: dict[str, Any]
    """:func:`quality_flags`' answer."""
    flags: tuple[str, ...]
    """The raised flags, in :data:`FLAGS` order."""
    width_ratio: float
    """The incident's width over a solitary wave's of its force (:func:`width_ratio`)."""


def analyzed(waveform: Waveform, opts: DetectOptions, args: KernelArgs) -> Shot:
    """The kernels' output on ``waveform`` (newtons, low-passed where ``opts`` say so), taking
    the kernel's arguments from ``args`` (or adding them there)."""
    dt = waveform.dt
    x = waveform.force
    if opts.lowpass_hz is not None:
        x = lowpass(x, dt, opts.lowpass_hz)
    if x is not waveform.samples:  # a Waveform's own samples are contiguous float64 already
        x = np.ascontiguousarray(x, dtype=np.float64)
    if x.flags.writeable:  # volts scaled, or low-passed: the kernels' one type is read-only
        x = x.view()
        x.setflags(write=False)
    shot_args = args.get((x.size, dt))
    if shot_args is None:
        shot_args = args[(x.size, dt)] = kernel_args(opts, x.size, dt)
    # compiled, or interpreted while a fresh install compiles (solitonde.signal.kernel_choice)
    head, rows = kernel_choice.analyze(x, shot_args)
    t0 = waveform.t0
    return Shot(head.tolist(), rows.tolist(), t0, dt, t0 + (x.size - 1) * dt)


def judged(shot: Shot, opts: DetectOptions) -> Verdict:
    """The pulses' roles and the flags of a shot holding at least one pulse."""
    head, rows, t0, dt = shot.head, shot.rows, shot.t0, shot.dt
    inc = rows[0]
    reflected = len(rows) > 1 and not head[K.H_NOREF]
    first = 2 if reflected else 1
    secondary = range(first, min(len(rows), first + opts.max_secondary))
    noise = head[K.H_SIGMA]
    amp = inc[K.P_AMP]
    ratio = width_ratio(inc[K.P_WIDTH] * dt, amp, opts.pulse_width_1n_s)
    early_one = not reflected and len(rows) > 1 and early_pulse(
        np.array([(t0 + r[K.P_TIME] * dt) - (t0 + inc[K.P_TIME] * dt) for r in rows[1:]]),
        np.array([r[K.P_AMP] for r in rows[1:]]) / amp, trip_s(opts.travel_time_1n_s, amp))
    raised = quality_flags(
        detected=True, has_reflection=reflected, early=bool(head[K.H_EARLY]),
        saturated=bool(head[K.H_SATURATED]), sign=head[K.H_SIGN],
        incident_merged=bool(inc[K.P_MERGED]),
        reflection_merged=reflected and bool(rows[1][K.P_MERGED]), more_than_two=len(rows) > 2,
        incident_cut=bool(inc[K.P_TRUNC]), reflection_cut=reflected and bool(rows[1][K.P_TRUNC]),
        train=bool(head[K.H_TRAIN]), low_snr_db=opts.low_snr_db, width_ratio=ratio,
        check_snr_db=snr_db(rows[1][K.P_AMP] if reflected else amp, noise),
        early_pulse=bool(early_one),
        # no gap fit (misfit_n 0) is never unsteady: skip unsteady's numpy work (8 us a shot)
        unsteady=head[K.H_MISFIT_N] > 0 and bool(
            unsteady(head[K.H_MISFIT], head[K.H_MISFIT_N], noise, amp)))
    return Verdict(reflected, secondary, raised, _ordered(raised), ratio)


def _detect(waveform: Waveform, opts: DetectOptions, args: KernelArgs) -> Detection:
    """:func:`detect` with its options checked, taking the kernel's arguments from ``args`` (or
    adding them there)."""
    shot = analyzed(waveform, opts, args)
    head, rows, t0, dt = shot.head, shot.rows, shot.t0, shot.dt
    sign = head[K.H_SIGN]
    notes: list[str] = []
    noise = head[K.H_SIGMA]
    common: dict[str, Any] = {
        "noise_N": noise, "threshold_N": head[K.H_THR], "pretrigger_samples": int(head[K.H_NPRE]),
        "smooth_samples": int(head[K.H_SMOOTH]), "record_end_s": shot.end_s}
    if head[K.H_EARLY]:
        notes.append("the incident pulse starts before a pre-trigger segment could be taken")
    if not rows:
        raised = quality_flags(
            detected=False, has_reflection=False, early=bool(head[K.H_EARLY]),
            saturated=False, sign=sign, incident_merged=False, reflection_merged=False,
            more_than_two=False, incident_cut=False, reflection_cut=False, train=False,
            check_snr_db=math.nan, low_snr_db=opts.low_snr_db, width_ratio=1.0)
        return Detection(
            baseline_N=sign * head[K.H_BASE], pulses=(), incident=None, reflected=None,
            secondary=(), flags=_ordered(raised), notes=(*notes, "no pulse rises above the noise"),
            **common,
        )
    verdict = judged(shot, opts)
    pulses = tuple(Pulse(
        time_s=t0 + row[K.P_TIME] * dt, peak_N=row[K.P_AMP], baseline_N=sign * row[K.P_BASE],
        width_s=row[K.P_WIDTH] * dt, onset_s=t0 + row[K.P_ONSET] * dt,
        end_s=t0 + row[K.P_END] * dt, snr_db=snr_db(row[K.P_AMP], noise),
        index=int(row[K.P_INDEX]), method=METHODS[int(row[K.P_METHOD])], rise_N=row[K.P_RISE],
        level_N=sign * row[K.P_LEVEL_N], peak_time_s=t0 + row[K.P_PEAK_TIME] * dt,
        peak_height_N=row[K.P_PEAK_AMP],
    ) for row in rows)
    # The shot is truncated when a measured pulse is (quality_flags); a cut secondary is only
    # noted.
    if any(row[K.P_TRUNC] for row in rows[1 + verdict.reflected:]):
        notes.append("a secondary pulse runs past the end of the record (TOF and ARR are whole)")
    incident = pulses[0]
    reflected = pulses[1] if verdict.reflected else None
    unlisted = len(pulses) - verdict.secondary.stop
    if unlisted > 0:
        notes.append(f"{unlisted} further secondary pulses not listed")
    train = int(head[K.H_TRAIN])
    if train:
        notes.append(f"{train} pulse(s) follow the incident sooner than a reflection can arrive "
                     "(the incident's train: a striker heavier than the spheres); listed as "
                     "secondary")
    upper = None
    if reflected is None:
        upper = head[K.H_UPPER]
        if head[K.H_NOREF] and len(pulses) > 1:
            notes.append("no pulse arrives when the chain's geometry puts the reflection")
    if reflected is not None and not rows[1][K.P_LEVEL]:
        notes.append("no quiet samples before the reflection: its baseline is the slow trend")
    raised = verdict.raised
    if raised["unsteady_baseline"]:
        share = head[K.H_MISFIT] / rows[0][K.P_AMP]
        notes.append(f"the baseline fitted on the pre-trigger and the gap misses them by "
                     f"{head[K.H_MISFIT]:.3g} on average ({share:.2%} of the incident): the "
                     "level jumped between the pulses")
    if raised["early_reflection"]:
        notes.append("a pulse arrives between the incident's train and where the stated chain "
                     "puts the reflection: the chain below the sensor is shorter than stated")
    if raised["implausible_units"]:
        notes.append(f"the incident pulse is {incident.width_s:.3g} s wide at {incident.peak_N:.3g}"
                     f" N, {verdict.width_ratio:.3g} times a solitary wave of that force in this "
                     "chain")
    return Detection(
        baseline_N=incident.baseline_N, pulses=pulses, incident=incident, reflected=reflected,
        secondary=pulses[verdict.secondary.start : verdict.secondary.stop],
        flags=verdict.flags, arr_upper_bound=upper, notes=tuple(notes), **common,
    )


def trip_s(travel_time_1n_s: float | None, peak_N: Any) -> Any:
    """The sensor-to-plate round trip of a solitary wave of ``peak_N`` (its speed grows as
    F^(1/6)); NaN without a travel gate."""
    if travel_time_1n_s is None:
        return np.nan * np.asarray(peak_N, dtype=float)
    return travel_time_1n_s * np.maximum(np.asarray(peak_N, dtype=float), 1e-300) ** (-1.0 / 6.0)


def early_pulse(delay_s: np.ndarray, ratio: np.ndarray, trip: Any) -> Any:
    """Whether a pulse after the incident (``delay_s``, its peak over the incident's ``ratio``;
    along the last axis, one row a shot for a batch) is an :data:`EARLY_RATIO`-strong one between
    :data:`EARLY_FROM` and ``GATE_LO`` round trips ``trip``; NaN delays and trips are no pulse."""
    trip = np.asarray(trip, dtype=float)[..., None] if np.ndim(trip) else float(trip)
    with np.errstate(invalid="ignore"):
        hit = ((delay_s >= EARLY_FROM * trip) & (delay_s < K.GATE_LO * trip)
               & (ratio >= EARLY_RATIO))
    return np.any(hit, axis=-1) if np.ndim(hit) else bool(hit)


def unsteady(misfit: Any, misfit_n: Any, noise: Any, incident_amp: Any) -> Any:
    """Whether the drift fit's largest mean residual ``misfit`` (over ``misfit_n`` samples, the
    kernel's ``H_MISFIT``, ``H_MISFIT_N``; 0 without a gap fit) stands above :data:`STEP_FLOOR`
    of the incident's height and five standard errors of a mean of ``noise``."""
    n = np.maximum(np.asarray(misfit_n, dtype=float), 1.0)
    limit = np.maximum(STEP_FLOOR * np.abs(incident_amp), 5.0 * np.asarray(noise) / np.sqrt(n))
    return (np.asarray(misfit_n) > 0) & (np.asarray(misfit) > limit)


def width_ratio(width_s: float, peak_N: float, width_1n_s: float | None) -> float:
    """A pulse's width over a solitary wave's of the same peak force (``width_1n_s``
    ``F^(-1/6)``); 1.0 when the chain's wave is not known, NaN for a non-positive peak."""
    if width_1n_s is None:
        return 1.0
    if not peak_N > 0:
        return math.nan
    return width_s / (width_1n_s * peak_N ** (-1.0 / 6.0))


def quality_flags(*, detected: Any, has_reflection: Any, early: Any, saturated: Any, sign: Any,
                  incident_merged: Any, reflection_merged: Any, more_than_two: Any,
                  incident_cut: Any, reflection_cut: Any, train: Any, check_snr_db: Any,
                  low_snr_db: float, width_ratio: Any, early_pulse: Any = False,
                  unsteady: Any = False) -> dict[str, Any]:
    """Which of :data:`FLAGS` a shot raises, from what the kernels found: the one statement of
    the flag rules, for one shot (bools and floats, :func:`detect`) or for many at once
    (arrays, one element a shot, :mod:`solitonde.signal.batch`).

    ``check_snr_db`` is the reflection's SNR where there is one, else the incident's; ``train``
    says pulses follow the incident sooner than a reflection can arrive (its merging then is
    the train's, not an overlap); ``width_ratio`` is the incident's width over a solitary
    wave's of its force (:func:`width_ratio`); ``early_pulse`` that a strong pulse arrived
    between the train and the travel gate (:func:`early_pulse`); ``unsteady`` that the drift's
    fit misses its own quiet samples (:func:`unsteady`). A flag needs a detected pulse except
    ``inverted_polarity`` and the pre-trigger's ``truncated``.
    """
    in_band = (width_ratio >= 1.0 / WIDTH_TOLERANCE) & (width_ratio <= WIDTH_TOLERANCE)
    return {
        "no_reflection": detected & _not(has_reflection),
        "saturated": detected & saturated,
        "low_snr": detected & (check_snr_db < low_snr_db),
        "overlapping": has_reflection & ((incident_merged & _not(train))
                                         | (more_than_two & reflection_merged)),
        "truncated": early | (detected & incident_cut) | (has_reflection & reflection_cut),
        "inverted_polarity": sign < 0,
        "implausible_units": detected & _not(in_band),
        "early_reflection": detected & _not(has_reflection) & early_pulse,
        "unsteady_baseline": detected & has_reflection & unsteady,
    }


def _not(value: Any) -> Any:
    """Logical not of a bool or of a boolean array (``~True`` is -2)."""
    return not value if isinstance(value, bool) else ~value


def _ordered(raised: dict[str, Any]) -> tuple[str, ...]:
    return tuple([f for f in FLAGS if raised[f]])
