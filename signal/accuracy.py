"""Accuracy of TOF and ARR against synthetic truth: Monte Carlo over noise, drift, quantisation.

A noise-free trace sampled finely (e.g. a model trace at 50 MHz) is acquired again and again at a
coarser rate with a random sub-sample offset, degraded (:func:`solitonde.signal.synth.degrade`)
and measured; the errors against the known truth are summarised per SNR.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .features import extract
from .synth import degrade
from .waveform import Waveform


@dataclass(frozen=True)
class Truth:
    """True pulse times and peaks (above the pre-trigger level) of the noise-free trace."""

    incident_time_s: float
    reflected_time_s: float
    incident_peak_N: float
    reflected_peak_N: float

    @property
    def tof_s(self) -> float:
        return self.reflected_time_s - self.incident_time_s

    @property
    def arr(self) -> float:
        return self.reflected_peak_N / self.incident_peak_N


def study(
    fine: np.ndarray,
    fine_dt: float,
    truth: Truth,
    sample_rate: float,
    snr_db: Sequence[float | None],
    trials: int,
    seed: int = 0,
    drift: float = 0.02,
    bits: int | None = 12,
    t0: float = 0.0,
    **options: Any,
) -> list[dict[str, Any]]:
    """One row per SNR: TOF error (median and 95th percentile of |error|, in sample periods, and
    the signed median), ARR error (relative and absolute), detection rate and flag counts."""
    step = round(1.0 / (sample_rate * fine_dt))
    if step < 1 or abs(step * fine_dt * sample_rate - 1.0) > 1e-6:
        raise ValueError("sample_rate must divide the fine trace's rate")
    dt = step * fine_dt
    rows = []
    for snr in snr_db:
        rng = np.random.default_rng(seed)
        tof_err, arr_rel, arr_abs = [], [], []
        flags: dict[str, int] = {}
        for _ in range(trials):
            offset = int(rng.integers(step))
            clean = fine[offset::step]
            x = degrade(clean, snr, rng, truth.incident_peak_N, drift=drift if snr else 0.0,
                        bits=bits if snr else None)
            f = extract(Waveform(t0 + offset * fine_dt, dt, x), **options)
            for name in f.flags:
                flags[name] = flags.get(name, 0) + 1
            if f.tof_s is None or f.arr is None:
                continue
            tof_err.append((f.tof_s - truth.tof_s) / dt)
            arr_rel.append(f.arr / truth.arr - 1.0)
            arr_abs.append(f.arr - truth.arr)
        e, r, a = np.abs(tof_err), np.abs(arr_rel), np.abs(arr_abs)
        found = len(tof_err)

        def q(v: np.ndarray, p: float) -> float:
            return float(np.percentile(v, p)) if v.size else float("nan")

        rows.append({
            "snr_db": snr, "trials": trials, "detected": found,
            "tof_bias_samples": float(np.median(tof_err)) if found else float("nan"),
            "tof_err_median_samples": q(e, 50), "tof_err_p95_samples": q(e, 95),
            "arr_bias_rel": float(np.median(arr_rel)) if found else float("nan"),
            "arr_err_median_rel": q(r, 50), "arr_err_p95_rel": q(r, 95),
            "arr_err_median_abs": q(a, 50), "arr_err_p95_abs": q(a, 95),
            "flags": flags,
        })
    return rows


def format_table(rows: list[dict[str, Any]], title: str = "") -> str:
    """The study as a fixed-width text table."""
    head = (f"{'SNR dB':>7} {'found':>9} {'TOF bias':>9} {'|TOF| med':>9} {'|TOF| p95':>9} "
            f"{'ARR bias':>9} {'|ARR| med':>9} {'|ARR| p95':>9} {'|dARR| p95':>10}  flags")
    lines = [title, "TOF in sample periods; ARR relative (%), dARR absolute", head] if title \
        else [head]
    for r in rows:
        snr = "clean" if r["snr_db"] is None else f"{r['snr_db']:g}"
        lines.append(
            f"{snr:>7} {r['detected']:>4}/{r['trials']:<4} {r['tof_bias_samples']:>+9.3f} "
            f"{r['tof_err_median_samples']:>9.3f} {r['tof_err_p95_samples']:>9.3f} "
            f"{100 * r['arr_bias_rel']:>+8.2f}% {100 * r['arr_err_median_rel']:>8.2f}% "
            f"{100 * r['arr_err_p95_rel']:>8.2f}% {r['arr_err_p95_abs']:>10.4f}  {r['flags']}"
        )
    return "\n".join(lines)
