"""TOF and ARR of a finely sampled noise-free trace, read at a coarser rate over many draws of
white noise, against the clean reading and the Cramer-Rao bound (the noise tests of issue 27)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from solitonde.signal.accuracy import Truth, cramer_rao
from solitonde.signal.features import extract
from solitonde.signal.waveform import Waveform

SNRS = (20.0, 30.0, 40.0, 60.0)
DRAWS = 200


def read(fine: Waveform, step: int, offset: int, noise: np.ndarray | None,
         options: Mapping[str, Any] | None = None) -> tuple[float, float] | None:
    """(tof_s, arr) of ``fine`` sampled every ``step`` samples from ``offset``, plus ``noise``,
    measured with the extractor's ``options``; None where no reflection is read."""
    x = fine.samples[offset::step]
    if noise is not None:
        x = x + noise[: x.size]
    f = extract(Waveform(fine.t0 + offset * fine.dt, fine.dt * step, x, fine.units),
                **(options or {}))
    if f.tof_s is None or f.arr is None:
        return None
    return f.tof_s, f.arr


def noise_rows(fine: Waveform, truth: Truth, rate: float, snrs: tuple[float, ...] = SNRS,
               draws: int = DRAWS, options: Mapping[str, Any] | None = None
               ) -> list[dict[str, float]]:
    """One row per SNR: the fraction of draws with a reflection (``found``), the mean TOF error
    (s) and relative ARR error against the clean reading averaged over the sub-sample offsets
    (``tof0``, ``arr0``: what a table holds), their standard deviations and Cramer-Rao bounds.
    Noise of standard deviation ``incident peak / 10^(SNR/20)``, at random offsets; ``options``
    go to the extractor (a function of the sample interval: ``relaxation_N`` is per sample)."""
    step = round(1.0 / (rate * fine.dt))
    clean = [read(fine, step, k, None, options) for k in range(step)]
    assert all(c is not None for c in clean), "the clean trace shows no reflection"
    tof0 = float(np.mean([c[0] for c in clean if c is not None]))
    arr0 = float(np.mean([c[1] for c in clean if c is not None]))
    rows = []
    for snr in snrs:
        rng = np.random.default_rng(int(snr))
        sigma = truth.incident_peak_N / 10 ** (snr / 20)
        tof, arr = [], []
        for _ in range(draws):
            got = read(fine, step, int(rng.integers(step)),
                       rng.normal(0.0, sigma, fine.samples.size // step + 1), options)
            if got is not None:
                tof.append(got[0])
                arr.append(got[1])
        t, a = np.array(tof), np.array(arr) / arr0 - 1.0
        bound = cramer_rao(fine.samples, fine.dt, truth, rate, sigma, fine.t0)
        many = t.size > 1
        rows.append({
            "snr": snr, "found": t.size / draws, "tof0": tof0, "arr0": arr0,
            "tof_mean": float(t.mean() - tof0) if many else float("nan"),
            "tof_sd": float(t.std(ddof=1)) if many else float("nan"),
            "tof_crb": bound["tof_samples"] / rate,
            "arr_mean": float(a.mean()) if many else float("nan"),
            "arr_sd": float(a.std(ddof=1)) if many else float("nan"),
            "arr_crb": bound["arr_rel"],
        })
    return rows
