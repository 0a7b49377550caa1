"""Synthetic traces for tests, benchmarks and accuracy studies: pulse shapes, acquisition defects.

The pulse shape is Nesterenko's long-wave solitary wave: the strain goes as cos^4 of
sqrt(10) x / (5 D) and Hertz contact turns it into a force going as cos^6 over a support of about
five diameters. Acquisition defects are what a DAQ adds: white noise at a stated SNR, baseline
drift, clipping and quantisation to a number of bits.

SNR convention (also what :func:`solitonde.signal.features.extract` reports as ``snr_db``):
``20 log10(incident peak above baseline / noise standard deviation per sample)``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def solitary_pulse(t: np.ndarray, t_peak: float, amplitude: float, support: float) -> np.ndarray:
    """Nesterenko solitary-wave force at times ``t``: ``A cos^6(pi (t - t_peak) / support)``.

    ``support`` is the full duration of the pulse (zero outside ``|t - t_peak| < support / 2``);
    its half-maximum width is 0.30 of it.
    """
    u = np.pi * (np.asarray(t, dtype=np.float64) - t_peak) / support
    c = np.cos(np.clip(u, -np.pi / 2, np.pi / 2))
    c2 = c * c
    return amplitude * c2 * c2 * c2


def pulse_train(
    n: int,
    dt: float,
    pulses: Sequence[tuple[float, float, float]],
    t0: float = 0.0,
    baseline: float = 0.0,
) -> np.ndarray:
    """``n`` samples holding solitary pulses given as ``(t_peak, amplitude, support)``."""
    t = t0 + dt * np.arange(n)
    out = np.full(n, float(baseline))
    for t_peak, amplitude, support in pulses:
        lo = np.searchsorted(t, t_peak - support / 2)
        hi = np.searchsorted(t, t_peak + support / 2)
        out[lo:hi] += solitary_pulse(t[lo:hi], t_peak, amplitude, support)
    return out


def degrade(
    clean: np.ndarray,
    snr_db: float | None,
    rng: np.random.Generator,
    reference: float,
    drift: float = 0.0,
    bits: int | None = None,
    full_scale: tuple[float, float] | None = None,
) -> np.ndarray:
    """What an acquisition makes of ``clean``: noise, drift, clipping and quantisation.

    Parameters
    ----------
    clean:
        The noise-free samples.
    snr_db:
        Noise level as ``20 log10(reference / sigma)``; ``None`` adds no noise.
    rng:
        Random generator (the caller seeds it).
    reference:
        The incident peak above baseline that the SNR refers to, N.
    drift:
        Baseline drift as a fraction of ``reference``: a linear ramp of that size over the record
        plus a quarter-period sine of half that size, with a random sign each.
    bits:
        Quantise to this many bits over ``full_scale``; ``None`` keeps full precision.
    full_scale:
        ADC range (low, high); samples outside are clipped. Default: the clean trace's range
        widened by a quarter of ``reference`` on each side.
    """
    x = np.array(clean, dtype=np.float64)
    n = x.size
    if drift:
        s = np.linspace(0.0, 1.0, n)
        x += drift * reference * (rng.choice((-1.0, 1.0)) * s
                                  + 0.5 * rng.choice((-1.0, 1.0)) * np.sin(0.5 * np.pi * s))
    if snr_db is not None:
        x += rng.normal(0.0, reference / 10 ** (snr_db / 20), n)
    if full_scale is None and bits is not None:
        full_scale = (float(clean.min()) - 0.25 * reference, float(clean.max()) + 0.25 * reference)
    if full_scale is not None:
        lo, hi = full_scale
        x = np.clip(x, lo, hi)
        if bits is not None:
            lsb = (hi - lo) / (2**bits - 1)
            x = lo + np.round((x - lo) / lsb) * lsb
    return x
