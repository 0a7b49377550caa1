"""Pulse detection: baseline and noise, incident, reflected and secondary pulses, quality flags.

The steps, each chosen so that a number is never picked out of noise:

1. Baseline and noise from the pre-trigger segment: median, and the MAD about the segment's
   least-squares line (slow drift is not noise). The segment is the first tenth of the record,
   then everything before the incident's onset once that is known (or ``pretrigger_s``).
2. Optional zero-phase Butterworth low-pass (``lowpass_hz``).
3. A zero-phase triangular smoother whose width follows the largest pulse's own width (a cheap
   stand-in for a matched filter); pulses are the peaks of the smoothed trace that rise
   ``threshold_sigma`` smoothed-noise deviations (and ``min_ratio`` of the largest pulse) above the
   baseline and stand out by as much from their neighbours.
4. Incident = first such pulse; reflected = the next one (flagged ``overlapping`` if the incident
   has not decayed in between); the rest are secondary pulses.
5. Each pulse is refined on the raw samples: the baseline is a least-squares quadratic through
   every quiet sample of the record (follows slow drift), and a symmetric super-Gaussian
   ``A exp(-|(t - tc)/w|^r)`` is fitted by least squares to the part of the pulse above
   ``fit_fraction`` of its peak. ``tc`` is the sub-sample peak time and ``A`` the peak above the
   baseline; the flanks inform the fit, which makes it several times less noisy than a parabola
   through the top few samples. The price is a small bias for asymmetric pulses: on the model's
   traces the incident pulse reads about +0.1 us late and the reflected -0.1 us early (TOF
   -0.2 us). If the fit fails, a least-squares parabola through the top is used instead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

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
)
"""Every quality flag detection can raise, in the order they are reported."""

MAD_TO_SIGMA = 1.4826
MIN_PRETRIGGER = 16
SHAPE_EXPONENT = 2.45
"""Starting exponent r of the fitted shape: the chain's solitary wave at the sensor fits
``exp(-|u|^2.45)`` to within 0.7 % of its peak (Nesterenko's cos^6 is close to r = 2)."""
NOISE_FLOOR = 1e-9
"""Noise is never taken below this fraction of the largest excursion (noise-free model traces)."""


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
        Exponent r of the fitted shape ``A exp(-|(t - tc)/w|^r)``. The default 2.45 is the
        chain's solitary wave at the sensor (amplitude-independent in scaled time), which halves
        the ARR scatter against a free r; ``None`` fits r too (other pulse shapes: Nesterenko's
        cos^6 reads 3.5 % low in amplitude with r fixed, 0.5 % with r free; ratios are unaffected).
    max_secondary:
        At most this many secondary pulses are reported.
    """

    pretrigger_s: float | None = None
    threshold_sigma: float = 6.0
    min_ratio: float = 0.02
    lowpass_hz: float | None = None
    smooth_samples: int | None = None
    polarity: str = "auto"
    low_snr_db: float = 15.0
    fit_fraction: float = 0.1
    shape_exponent: float | None = 2.45
    max_secondary: int = 8

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
        if not isinstance(self.max_secondary, int) or self.max_secondary < 0:
            raise bad("max_secondary", "a non-negative integer")

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

    ``time_s`` is the sub-sample peak time, ``peak_N`` the peak above the local baseline,
    ``width_s`` the full width at half maximum of the fitted shape, ``method`` ``"template"`` or
    ``"parabola"`` (the fall-back).
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


def _lowpass(x: np.ndarray, dt: float, cutoff: float) -> np.ndarray:
    from scipy.signal import butter, sosfiltfilt

    nyquist = 0.5 / dt
    if cutoff >= nyquist:
        raise WaveformError(
            "lowpass_hz", f"{cutoff:g} Hz is not below Nyquist ({nyquist:g} Hz)",
            "0 < lowpass_hz < sample_rate / 2",
        )
    sos = butter(4, cutoff, fs=1.0 / dt, output="sos")
    return sosfiltfilt(sos, x)


def _snr_db(amplitude: float, noise: float) -> float:
    return 20.0 * math.log10(max(amplitude, 1e-300) / noise)


def _smoother_gain(h: int) -> float:
    """Standard deviation of white noise after :func:`kernels.triangle` with half-width ``h``."""
    if h < 1:
        return 1.0
    width = 2 * h + 1
    taps = width - np.abs(np.arange(-2 * h, 2 * h + 1))
    return float(np.sqrt(np.sum(taps.astype(np.float64) ** 2)) / width**2)


class _Trace:
    """Working state of one detection: raw and smoothed trace, baseline line, noise levels.

    The baseline starts as the pre-trigger median; once pulses are known it becomes the
    least-squares quadratic through every quiet sample of the record (pre-trigger, gaps, tail),
    which follows a slow drift without being pulled by the pulses.
    """

    def __init__(self, x: np.ndarray, n_pre: int, h: int) -> None:
        self.x = x
        self.idx = np.arange(x.size, dtype=np.float64)
        self.h = h
        self.set_pretrigger(n_pre)

    def set_pretrigger(self, n_pre: int) -> None:
        x = self.x
        self.n_pre = n_pre
        self.base, _ = K.median_mad(x[:n_pre])
        self.line = np.full(x.size, self.base)
        span = float(np.max(np.abs(x - self.base)))
        floor = NOISE_FLOOR * max(span, 1e-300)
        self.sigma = max(MAD_TO_SIGMA * K.detrended_mad(x[:n_pre]), floor)
        self.smooth(self.h)

    def set_baseline(self, coef: np.ndarray) -> None:
        self.line = K.poly_eval(coef, self.x.size)
        self.v = self.s - self.line

    def smooth(self, h: int) -> None:
        self.h = h
        self.s = K.triangle(self.x, h)
        self.v = self.s - self.line
        span = float(np.max(np.abs(self.v)))
        floor = NOISE_FLOOR * max(span, 1e-300)
        # The gain of the smoother is exact for white noise; the MAD of the smoothed pre-trigger
        # catches coloured noise but is itself noisy (few independent values), so take the larger.
        measured = MAD_TO_SIGMA * K.detrended_mad(self.s[: self.n_pre])
        self.sigma_s = max(_smoother_gain(h) * self.sigma, measured, floor)

    def fwhm_of_largest(self) -> int:
        ip = int(np.argmax(self.v))
        a, b = K.pulse_extent(self.v, ip, 0.5 * self.v[ip], 0, self.v.size)
        return b - a + 1


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
        For bad options, or a record too short to hold a pre-trigger segment and a pulse.
    """
    opts = options if options is not None else DetectOptions.from_kwargs(kwargs)
    x = np.asarray(waveform.force, dtype=np.float64)
    dt = waveform.dt
    n = x.size
    if opts.lowpass_hz is not None:
        x = _lowpass(x, dt, opts.lowpass_hz)

    flags: set[str] = set()
    notes: list[str] = []
    if opts.pretrigger_s is not None:
        n_pre = int(opts.pretrigger_s / dt)
        if not MIN_PRETRIGGER <= n_pre <= n - MIN_PRETRIGGER:
            raise WaveformError(
                "pretrigger_s",
                f"{opts.pretrigger_s:g} s is {n_pre} samples of a {n}-sample record",
                f"{MIN_PRETRIGGER} samples to the record length minus {MIN_PRETRIGGER}",
            )
    else:
        n_pre = _initial_pretrigger(x)

    h0 = opts.smooth_samples if opts.smooth_samples is not None else 2
    tr = _Trace(x, n_pre, h0)

    # Polarity: a sensor wired the other way round shows the pulses as dips.
    inverted = opts.polarity == "negative" or (
        opts.polarity == "auto" and -tr.v.min() > tr.v.max()
    )
    if inverted:
        flags.add("inverted_polarity")
        x = -x
        tr = _Trace(x, n_pre, h0)

    if opts.smooth_samples is None:
        for _ in range(3):
            h = max(1, tr.fwhm_of_largest() // 6)
            if 2 * h <= 3 * tr.h and 3 * h >= 2 * tr.h:
                break
            tr.smooth(h)

    peaks, thr = _peaks(tr, opts)
    if opts.pretrigger_s is None and peaks.size:
        a0, _ = K.pulse_extent(tr.v, int(peaks[0]), 0.5 * thr, 0, n)
        new_pre = a0 - 2 * tr.h
        if new_pre < MIN_PRETRIGGER:
            flags.add("truncated")
            notes.append("the incident pulse starts before a pre-trigger segment could be taken")
        elif abs(new_pre - tr.n_pre) > 0.1 * tr.n_pre:
            tr.set_pretrigger(new_pre)
            peaks, thr = _peaks(tr, opts)

    if peaks.size:
        # Drift: the baseline line through all quiet samples, then detect once more against it.
        # Iterated because the pulses' extents, hence the quiet samples, depend on the baseline.
        for _ in range(2):
            quiet = _quiet_mask(tr, peaks, thr)
            coef, count = K.quadratic_fit(x, quiet, 2)
            if count < 2 * MIN_PRETRIGGER or quiet[tr.n_pre :].sum() < MIN_PRETRIGGER:
                break
            if not quiet[2 * n // 3 :].any() or not quiet[n // 3 : 2 * n // 3].any():
                coef, _ = K.quadratic_fit(x, quiet, 1)  # too little support for a curvature
            tr.set_baseline(coef)
            peaks, thr = _peaks(tr, opts)

    pulses, overlap_next = _refine(tr, peaks, thr, dt, waveform.t0, opts, flags)
    if not pulses:
        return Detection(
            baseline_N=_sign(tr.base, inverted), noise_N=tr.sigma, threshold_N=thr,
            pretrigger_samples=tr.n_pre, smooth_samples=tr.h, pulses=(), incident=None,
            reflected=None, secondary=(), flags=_ordered(flags),
            notes=(*notes, "no pulse rises above the noise"),
        )

    incident = pulses[0]
    reflected = pulses[1] if len(pulses) > 1 else None
    secondary = tuple(pulses[2 : 2 + opts.max_secondary])
    if len(pulses) > 2 + opts.max_secondary:
        notes.append(f"{len(pulses) - 2 - opts.max_secondary} further secondary pulses not listed")
    upper = None
    if reflected is None:
        flags.add("no_reflection")
        _, b_inc = K.pulse_extent(tr.v, int(peaks[0]), 0.5 * thr, 0, n)
        after = tr.v[b_inc + 1 :]
        largest = float(after.max()) if after.size else 0.0
        upper = max(thr, largest) / incident.peak_N
    elif overlap_next[0]:
        flags.add("overlapping")
    if reflected is not None and overlap_next[1] and len(pulses) > 2:
        flags.add("overlapping")
    check = reflected if reflected is not None else incident
    if check.snr_db < opts.low_snr_db:
        flags.add("low_snr")
    if _saturated(x, tr, incident, dt):
        flags.add("saturated")

    return Detection(
        baseline_N=_sign(incident.baseline_N, inverted),
        noise_N=tr.sigma,
        threshold_N=thr,
        pretrigger_samples=tr.n_pre,
        smooth_samples=tr.h,
        pulses=tuple(pulses),
        incident=incident,
        reflected=reflected,
        secondary=secondary,
        flags=_ordered(flags),
        arr_upper_bound=upper,
        notes=tuple(notes),
    )


def _initial_pretrigger(x: np.ndarray) -> int:
    """Samples before the largest pulse's onset (a first guess; refined once pulses are known).

    The onset is where the lightly smoothed trace, walking back from its first crossing of a
    quarter of the largest excursion, falls to 2 % of it; a margin of half the rise is kept.
    """
    n = x.size
    dev = np.abs(K.triangle(x, 2) - np.median(x[:: max(1, n // 1024)]))
    big = float(dev.max())
    if big <= 0:
        return max(MIN_PRETRIGGER, n // 10)
    cross = int(np.argmax(dev > 0.25 * big))
    onset = cross
    while onset > 0 and dev[onset - 1] > 0.02 * big:
        onset -= 1
    guess = onset - max(8, (cross - onset) // 2)
    return int(min(max(guess, MIN_PRETRIGGER), max(n // 2, MIN_PRETRIGGER)))


def _sign(value: float, inverted: bool) -> float:
    return -value if inverted else value


def _ordered(flags: set[str]) -> tuple[str, ...]:
    return tuple(f for f in FLAGS if f in flags)


def _peaks(tr: _Trace, opts: DetectOptions) -> tuple[np.ndarray, float]:
    """Peak indices of the smoothed trace and the threshold they had to pass."""
    largest = float(tr.v.max())
    thr = max(opts.threshold_sigma * tr.sigma_s, opts.min_ratio * largest)
    return K.find_peaks_hysteresis(tr.v, thr, thr), thr


def _extents(tr: _Trace, peaks: np.ndarray, thr: float) -> tuple[list[tuple[int, int]], list[bool]]:
    """Each pulse's span above half the threshold, and whether it merges with the next pulse."""
    v = tr.v
    n = v.size
    low = 0.5 * thr
    m = len(peaks)
    bounds = [0]
    for j in range(m - 1):
        bounds.append(K.valley(v, int(peaks[j]), int(peaks[j + 1])))
    bounds.append(n - 1)
    extents = []
    merged = [False] * max(m, 2)
    for j in range(m):
        extents.append(K.pulse_extent(v, int(peaks[j]), low, bounds[j], bounds[j + 1] + 1))
        if j + 1 < m and v[bounds[j + 1]] > low:
            merged[j] = True
    return extents, merged


def _quiet_mask(tr: _Trace, peaks: np.ndarray, thr: float) -> np.ndarray:
    """True where no pulse (nor the smoother's spread of one) is present."""
    n = tr.x.size
    quiet = np.ones(n, dtype=np.bool_)
    margin = 2 * tr.h + 2
    for a, b in _extents(tr, peaks, thr)[0]:
        span = b - a
        quiet[max(0, a - margin - span // 4) : min(n, b + margin + span // 4 + 1)] = False
    return quiet


def _refine(
    tr: _Trace,
    peaks: np.ndarray,
    thr: float,
    dt: float,
    t0: float,
    opts: DetectOptions,
    flags: set[str],
) -> tuple[list[Pulse], list[bool]]:
    """Turn smoothed-trace peaks into pulses measured on the raw samples."""
    n = tr.x.size
    if len(peaks) == 0:
        return [], []
    extents, merged = _extents(tr, peaks, thr)
    pulses = []
    for j, ip in enumerate(peaks):
        a, b = extents[j]
        if a <= 0 or b >= n - 1:
            flags.add("truncated")
        pulses.append(_measure(tr, int(ip), a, b, dt, t0, opts, flags))
    return pulses, merged


def _measure(
    tr: _Trace, ip: int, a: int, b: int, dt: float, t0: float, opts: DetectOptions,
    flags: set[str],
) -> Pulse:
    """Sub-sample peak time and amplitude of one pulse (template fit, parabola as fall-back)."""
    x, s = tr.x, tr.s
    n = x.size
    base = tr.line[ip]
    top = s[ip] - base
    level = base + opts.fit_fraction * top
    fa, fb = K.pulse_extent(s, ip, level, a, b + 1)
    half = base + 0.5 * top
    ha, hb = K.pulse_extent(s, ip, half, a, b + 1)
    if fb - fa < 8:
        fa, fb = max(0, ip - 4), min(n - 1, ip + 4)
    if fa <= 0 or fb >= n - 1:
        flags.add("truncated")
    idx = np.arange(fa, fb + 1)
    y = (x[fa : fb + 1] - tr.line[fa : fb + 1]) / top
    tb, yb = K.block_average((idx - ip).astype(np.float64), y, K.MAX_FIT_POINTS)
    r0 = opts.shape_exponent if opts.shape_exponent is not None else SHAPE_EXPONENT
    p0 = np.array([1.0, 0.0, 0.5 * max(hb - ha, 2) / math.log(2.0) ** (1.0 / r0), r0])
    nfree = 3 if opts.shape_exponent is not None else 4
    p, ok = K.fit_pulse(tb, yb, p0, nfree, 50)
    method = "template"
    if not (ok and 0.2 < p[0] < 5.0 and tb[0] < p[1] < tb[-1]):
        method = "parabola"
        p = _parabola(tb, yb)
        width = (hb - ha + 1) * dt
    else:
        width = 2.0 * p[2] * math.log(2.0) ** (1.0 / p[3]) * dt
    amp = float(p[0] * top)
    return Pulse(
        time_s=t0 + (ip + float(p[1])) * dt,
        peak_N=amp,
        baseline_N=float(base),
        width_s=float(width),
        onset_s=t0 + a * dt,
        end_s=t0 + b * dt,
        snr_db=_snr_db(amp, tr.sigma),
        index=ip,
        method=method,
    )


def _parabola(tb: np.ndarray, yb: np.ndarray) -> np.ndarray:
    """Least-squares parabola through the top 30 % of the fit window; returns [A, tc, ...]."""
    sel = yb > 0.7 * yb.max()
    if sel.sum() >= 3:
        c2, c1, c0 = np.polyfit(tb[sel], yb[sel], 2)
        if c2 < 0:
            tc = -c1 / (2 * c2)
            if tb[sel][0] <= tc <= tb[sel][-1]:
                return np.array([c0 - c1 * c1 / (4 * c2), tc, 0.0, 2.0])
    return np.array([1.0, 0.0, 0.0, 2.0])


def _saturated(x: np.ndarray, tr: _Trace, incident: Pulse, dt: float) -> bool:
    """Clipping: the record's extreme value repeats over more than a twentieth of the pulse width.

    A quantised, noise-free peak repeats its top code over a few samples too; a clipped one over a
    sizeable part of its width.
    """
    top = float(x.max())
    tol = 1e-9 * max(abs(top), 1e-300)
    count = int(np.count_nonzero(x >= top - tol))
    return count >= max(3, 0.05 * incident.width_s / dt)
