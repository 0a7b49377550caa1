"""Baseline drift and offset under noise (issue 27, item 2: not yet met; docs/waveforms.md).

Traces of the independent solve (``tests/support/scipy_chain.py``), 100 draws of white noise with
and without a drift added to the same draws: a DC offset, a 2 % ramp (of the incident's peak over
the record) with a 0.5 N offset, a 5 % ramp, and a 5 % parabola that starts flat. What holds and is
asserted: an offset moves nothing, and no drift moves TOF by more than 0.01 us. What the issue asks
and the extractor does not do yet (a strict expected failure): no drift moves the mean ARR by more
than 0.5 %. ``-m slow -s`` prints the table of docs/waveforms.md.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy_chain import ChainTrace, solve

from solitonde.signal.features import extract
from solitonde.signal.waveform import Waveform

DRAWS = 100
CELLS = {  # name: (diameter, thickness, gravity, sample rate, record after the impact, SNR dB)
    "D9.53 t4.83 g0 2MHz": (9.53e-3, 4.83e-3, False, 2e6, 0.9e-3, 40.0),
    "D9.53 t3.18 g0 1MHz": (9.53e-3, 3.18e-3, False, 1e6, 0.9e-3, 40.0),
    "D9.53 t2.70 g1 10MHz": (9.53e-3, 2.70e-3, True, 10e6, 0.9e-3, 40.0),
    "D9.53 t2.70 g1 10MHz 30dB": (9.53e-3, 2.70e-3, True, 10e6, 0.9e-3, 30.0),
    "D4.76 t2.38 g1 2MHz": (4.76e-3, 2.38e-3, True, 2e6, 0.45e-3, 40.0),
}
DRIFTS = {  # name: baseline added, from the record's position u in [0, 1] and the incident peak
    "offset 0.5 N": lambda u, peak: np.full_like(u, 0.5),
    "2 % ramp + 0.5 N": lambda u, peak: 0.02 * peak * u + 0.5,
    "5 % ramp": lambda u, peak: 0.05 * peak * u,
    "5 % parabola": lambda u, peak: 0.05 * peak * u**2,
}


def _means(trace: ChainTrace, rate: float, snr: float) -> dict[str, tuple[float, float, float]]:
    """Per drift: (mean TOF change s, mean relative ARR change, ARR sd relative) against the same
    noise draws without drift."""
    step = round(1.0 / (rate * trace.dt))
    x = trace.samples[::step]
    u = np.linspace(0.0, 1.0, x.size)
    peak = trace.truth.incident_peak_N
    sigma = peak / 10 ** (snr / 20)
    out = {}
    for name, drift in {"none": lambda u, p: np.zeros_like(u), **DRIFTS}.items():
        rng = np.random.default_rng(1)
        tof, arr = [], []
        for _ in range(DRAWS):
            f = extract(Waveform(trace.t0, trace.dt * step,
                                 x + drift(u, peak) + rng.normal(0.0, sigma, x.size)))
            tof.append(np.nan if f.tof_s is None else f.tof_s)
            arr.append(np.nan if f.arr is None else f.arr)
        out[name] = (np.array(tof), np.array(arr))
    t0, a0 = out.pop("none")
    return {name: (float(np.nanmean(t - t0)), float(np.nanmean(a) / np.nanmean(a0) - 1.0),
                   float(np.nanstd(a) / np.nanmean(a0)))
            for name, (t, a) in out.items()}


@pytest.fixture(scope="module")
def table() -> dict[str, dict[str, tuple[float, float, float]]]:
    rows = {}
    for name, (d, t, gravity, rate, t_end, snr) in CELLS.items():
        rows[name] = _means(solve(d, t, gravity, t_end), rate, snr)
    print("\n| cell | SNR | " + " | ".join(DRIFTS) + " |")
    print("|---|---|" + "---|" * len(DRIFTS))
    for name, row in rows.items():
        print(f"| {name} | {CELLS[name][5]:.0f} dB | " + " | ".join(
            f"{100 * a:+.1f} % (sd {100 * sd:.1f}), TOF {1e6 * t:+.3f} us"
            for t, a, sd in row.values()) + " |")
    return rows


@pytest.mark.slow
def test_an_offset_moves_nothing_and_no_drift_moves_tof(table) -> None:
    for name, row in table.items():
        tof, arr, _ = row["offset 0.5 N"]
        assert abs(tof) < 1e-9 and abs(arr) < 1e-6, name
        for drift, (tof, _, _) in row.items():
            assert abs(tof) <= 0.01e-6, (name, drift)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="issue 27 item 2 not met: under noise the pre-trigger's "
                   "slope is used in some shots and not in others, and the gap is no quiet "
                   "stretch with gravity on (docs/waveforms.md, Drift)")
def test_no_drift_moves_the_mean_arr_by_more_than_half_a_percent(table) -> None:
    for name, row in table.items():
        for drift, (_, arr, _) in row.items():
            assert abs(arr) <= 0.005, (name, drift, arr)
