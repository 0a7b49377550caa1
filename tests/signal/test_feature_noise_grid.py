"""TOF and ARR under white noise over issue 17's whole grid, the support included (issue 27).

``tests/signal/test_feature_noise.py`` draws its traces from an independent solve, which has Zener's
infinite plate only. Here every scene of the grid (``tests/support/feature_grid.py``: three sphere
sizes x D/t 0.5-4 x gravity on and off on the infinite plate, and the greens tier 10-30 mm from a
clamped support) is simulated by the model at 20 MHz, taken through ``as_measured`` as a table build
takes it, and sampled at its grid rate (1-10 MHz) at random sub-sample offsets with white noise of
standard deviation ``incident peak / 10^(SNR/20)``, 200 draws at 20, 30, 40 and 60 dB. The reference
is the clean reading averaged over the offsets, what a table holds at that point.

Asserted where the reflection is found in at least 95 % of the draws (a reflection below the noise
is an upper bound, not a reading, and the mean of the draws that cross the threshold is not the
reading's mean): the mean TOF error within 0.1 us and the mean relative ARR error within 0.3 %, or a
quarter of the draws' standard deviation where that is larger; the standard deviations within 1.5
times the Cramer-Rao bound. The table is printed (``-m slow -s``): about 20 s of simulation and
20,000 extractions on two cores.

Every pair holds them. One pair used to fall short by phase, not noise: D 19.05 mm on a 4.76 mm
plate, gravity off, 2 MHz, 60 dB, TOF sd 0.087 us against a bound of 0.047 us, because the template
fit's window ends and its last block moved by whole samples with the sampling phase. The window
now ends where the level is crossed between samples, each sample weighing its share, and no block
is dropped (``kernels._measure_pulse``): 0.068 us of TOF over the ten phases of that clean trace
became under 0.0001 us.

The grid is measured twice: with the pre-trigger's baseline (the extractor alone, as the tables
are built), and with the drift fitted on the gap too, as ``analyze`` measures a shot of a stated
sphere size (``relaxation_N`` from the model's chain: :mod:`solitonde.signal.gap_drift`). The
bound's model gives each pulse a baseline of its own, measured before its foot, so the gap's fit
is held to the same 1.5 times. Its price is scatter where the reflection is small: the
quadratic's value at the reflection is an extrapolation over the reflection's flank; the largest
ratio, 1.50, is D 4.76 mm, D/t 4, gravity on, 10 MHz, 60 dB (ARR about 0.1).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from feature_grid import grid_rates, grid_scenes
from noise_draws import noise_rows

from solitonde.instrument.inference.chain_geometry import relaxation
from solitonde.instrument.tables.measured import as_measured
from solitonde.model.batch import simulate_many
from solitonde.model.simulate import SimulationResult
from solitonde.signal.accuracy import Truth

FINE_RATE = 20e6
TOF_LIMIT_S = 0.1e-6
ARR_LIMIT = 0.003
SD_OVER_BOUND = 1.5
FOUND = 0.95
FIGURES = Path(__file__).resolve().parents[2] / "docs" / "figures"
KNOWN_SHORTFALLS: dict[str, set[tuple[str, bool, float, float, float]]] = {
    "pre-trigger": set(), "gap": set()}
"""Per baseline: (plate model, gravity, D mm, D/t, SNR dB) of the pairs outside the limits (none;
the test fails if one appears)."""


def _truth(result: SimulationResult) -> Truth:
    w = as_measured(result)
    return Truth.from_peaks(w.samples, w.dt, w.t0, result.truth)


@pytest.mark.slow
@pytest.mark.parametrize("baseline", ["pre-trigger", "gap"])
def test_means_do_not_move_with_noise_over_the_whole_grid(baseline: str) -> None:
    scenes = grid_scenes({"sample_rate": FINE_RATE})
    results = simulate_many(scenes, workers=2)
    assert all(isinstance(r, SimulationResult) for r in results), results
    print("\n| plate | g | D mm | D/t | L mm | MHz | ARR | SNR dB | found | TOF mean us "
          "| TOF sd us (bound) | ARR mean % | ARR sd % (bound) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    failures: dict[tuple[str, bool, float, float, float], str] = {}
    skipped = 0
    figures: list[dict[str, Any]] = []
    for result, rate in zip(results, grid_rates(), strict=True):
        s = result.scene
        options = {}
        if baseline == "gap":
            truth = result.truth
            options["relaxation_N"] = relaxation(
                s, truth["incident_peak_N"] - truth["static_sensor_N"], 1.0 / rate)
        for r in noise_rows(as_measured(result), _truth(result), rate, options=options):
            distance = s.plate.distance_to_support
            where = "-" if s.effects.plate_model == "infinite" else f"{distance * 1e3:.0f}"
            line = (f"| {s.effects.plate_model} | {'on' if s.effects.gravity else 'off'} | "
                    f"{s.chain.diameter * 1e3:.2f} | {s.d_over_t:.1f} | {where} | "
                    f"{rate / 1e6:g} | {r['arr0']:.3f} | {r['snr']:.0f} | {r['found']:.2f} | "
                    f"{r['tof_mean'] * 1e6:+.3f} | {r['tof_sd'] * 1e6:.3f} "
                    f"({r['tof_crb'] * 1e6:.3f}) | {100 * r['arr_mean']:+.3f} | "
                    f"{100 * r['arr_sd']:.3f} ({100 * r['arr_crb']:.3f}) |")
            print(line)
            figures.append({"plate_model": s.effects.plate_model,
                            "gravity": bool(s.effects.gravity),
                            "diameter_m": s.chain.diameter, "d_over_t": s.d_over_t,
                            "distance_to_support_m": distance, "rate_hz": rate, **r})
            if r["found"] < FOUND:
                skipped += 1
                continue
            ok = (abs(r["tof_mean"]) <= max(TOF_LIMIT_S, 0.25 * r["tof_sd"])
                  and abs(r["arr_mean"]) <= max(ARR_LIMIT, 0.25 * r["arr_sd"])
                  and r["tof_sd"] <= SD_OVER_BOUND * r["tof_crb"]
                  and r["arr_sd"] <= SD_OVER_BOUND * r["arr_crb"])
            if not ok:
                key = (s.effects.plate_model, bool(s.effects.gravity),
                       round(s.chain.diameter * 1e3, 2), round(s.d_over_t, 1), r["snr"])
                failures[key] = line
    print(f"{skipped} cell-SNR pairs with the reflection in fewer than {FOUND:.0%} of the draws "
          f"(not asserted); outside the limits: {sorted(failures)}")
    assert set(failures) == KNOWN_SHORTFALLS[baseline], "\n".join(failures.values())
    (FIGURES / f"extractor-noise-grid-{baseline}.json").write_text(json.dumps({
        "command": "pytest -m slow tests/signal/test_feature_noise_grid.py --timeout 0",
        "figures": {"baseline": baseline, "draws": 200, "pairs": len(figures),
                    "not_found": skipped, "largest": _largest(figures), "rows": figures}},
        indent=1) + "\n")


def _largest(rows: list[dict[str, Any]]) -> dict[str, float]:
    """The largest sd-to-bound ratios and, near the support, the largest |means|, over the pairs
    whose reflection is found."""
    found = [r for r in rows if r["found"] >= FOUND]
    near = [r for r in found if r["plate_model"] != "infinite"]
    return {"tof_sd_over_bound": max(r["tof_sd"] / r["tof_crb"] for r in found),
            "arr_sd_over_bound": max(r["arr_sd"] / r["arr_crb"] for r in found),
            "near_support_tof_mean_s": max((abs(r["tof_mean"]) for r in near), default=0.0),
            "near_support_arr_mean_rel": max((abs(r["arr_mean"]) for r in near), default=0.0)}
