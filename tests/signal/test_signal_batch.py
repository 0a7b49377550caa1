"""The batch path (signal.batch.extract_batch) gives, shot for shot, exactly what extract gives."""

from __future__ import annotations

import numpy as np
import pytest

from solitonde.signal.batch import FLAG_BITS, extract_batch
from solitonde.signal.errors import WaveformError
from solitonde.signal.features import extract, extract_many, from_detection
from solitonde.signal.pulses import FLAGS, detect
from solitonde.signal.synth import degrade, pulse_train
from solitonde.signal.waveform import Waveform

DT = 1e-7
N = 2000


def _varied_shots(count: int, seed: int) -> np.ndarray:
    """Shots of every kind the flags describe: clean and noisy, drifting, clipped, inverted,
    pulses cut by either end of the record, merged pulses, lone pulses and no pulse at all."""
    rng = np.random.default_rng(seed)
    out = np.empty((count, N))
    for k in range(count):
        support = rng.uniform(40, 400) * DT
        pulses = [(rng.uniform(-0.05, 1.05) * N * DT, rng.uniform(-1, 30),
                   support * rng.uniform(0.7, 1.3)) for _ in range(int(rng.integers(0, 5)))]
        x = pulse_train(N, DT, pulses, baseline=rng.uniform(-2, 2))
        snr = rng.choice([np.nan, 12.0, 20.0, 40.0])
        x = degrade(x, None if np.isnan(snr) else float(snr), rng, 30.0,
                    drift=float(rng.choice([0.0, 0.02, 0.2])), bits=rng.choice([None, 12]),
                    full_scale=(-5.0, 18.0) if rng.uniform() < 0.25 else None)
        out[k] = x * rng.choice([1.0, -1.0])
    return out


def _per_shot(x: np.ndarray, t0: float = 0.0, **options: object) -> list:
    feats = []
    for row in x:
        try:
            feats.append(extract(Waveform(t0, DT, row), **options))
        except WaveformError as exc:
            assert exc.field == "samples" and "no pulse" in str(exc)
            feats.append(None)
    return feats


@pytest.fixture(scope="module")
def shots() -> np.ndarray:
    return _varied_shots(160, seed=11)


def test_batch_equals_extract_on_every_kind_of_shot(shots):
    table = extract_batch(shots, DT, t0=-3e-5)
    expected = _per_shot(shots, t0=-3e-5)
    assert table.to_features() == expected
    seen = {flag for f in expected if f is not None for flag in f.flags}
    # implausible_units needs the chain's width law, early_reflection its gate (the next test),
    # unsteady_baseline its relaxation (tests/instrument/test_baseline_step.py)
    assert seen == set(FLAGS) - {"implausible_units", "early_reflection", "unsteady_baseline"}, \
        "the shots must exercise every flag"
    assert any(f is None for f in expected) and any(f and f.secondary_times_s for f in expected)
    for i, f in enumerate(expected):
        assert table.detected[i] == (f is not None)
        if f is not None:
            assert table.flags[i] == sum(FLAG_BITS[name] for name in f.flags)
            assert (f.tof_s is None) == np.isnan(table.tof_s[i])


@pytest.mark.parametrize("chain", [{}, {"travel_time_1n_s": 1.5e-4, "pulse_width_1n_s": 2.5e-5,
                                    "max_secondary": 1}], ids=["plain", "chain"])
def test_extract_equals_the_features_of_detect(shots, chain):
    """extract reads the features straight from the kernels' rows; detect builds every pulse
    and from_detection reads them there: the same features, flags and error, shot for shot."""
    for row in shots:
        wave = Waveform(-3e-5, DT, row)
        try:
            expected = from_detection(detect(wave, **chain))
        except WaveformError as exc:
            with pytest.raises(WaveformError) as got:
                extract(wave, **chain)
            assert str(got.value) == str(exc)
            continue
        assert extract(wave, **chain) == expected
        assert extract_many([wave, wave], **chain) == [expected, expected]


def test_batch_equals_extract_with_the_chains_gate_and_width_law(shots):
    """With a travel gate and a width law (a chain of known spheres) the batch still equals
    ``extract`` shot for shot: gated reflections, trains listed as secondary, gates holding no
    pulse, and ``implausible_units`` and ``early_reflection`` both raised and not."""
    chain = {"travel_time_1n_s": 1.5e-4, "pulse_width_1n_s": 2.5e-5}
    table = extract_batch(shots, DT, t0=-3e-5, **chain)
    expected = _per_shot(shots, t0=-3e-5, **chain)
    assert table.to_features() == expected
    for flag in ("implausible_units", "early_reflection"):
        flagged = [f is not None and flag in f.flags for f in expected]
        assert any(flagged) and not all(flagged), flag
    plain = _per_shot(shots, t0=-3e-5)
    moved = [a.reflected_time_s != b.reflected_time_s for a, b in zip(expected, plain, strict=True)
             if a is not None]
    assert any(moved)  # the gate chose another pulse, or none, for some shots


@pytest.mark.parametrize("options", [
    {"polarity": "negative"},
    {"pretrigger_s": 20e-6},
    {"max_secondary": 1},
    {"shape_exponent": None, "shape_skew": 0.0},
    {"lowpass_hz": 500e3, "smooth_samples": 3},
])
def test_batch_equals_extract_with_options(shots, options):
    x = shots[:40]
    assert extract_batch(x, DT, **options).to_features() == _per_shot(x, **options)


def test_volts_and_threads(shots):
    volts = shots[:30] / 2.5
    table = extract_batch(volts, DT, units="V", calibration=2.5, threads=2)
    expected = [extract(Waveform(0.0, DT, row, units="V", calibration=2.5)) if f else None
                for row, f in zip(volts, _per_shot(volts * 2.5), strict=True)]
    assert table.to_features() == expected
    one = extract_batch(volts, DT, units="V", calibration=2.5, threads=1)
    for name in ("tof_s", "arr", "snr_db", "flags", "secondary_ratios", "n_pulses"):
        np.testing.assert_array_equal(getattr(one, name), getattr(table, name))


@pytest.mark.parametrize(("call", "field"), [
    (lambda x: extract_batch(x[0], DT), "samples"),
    (lambda x: extract_batch(x[:, :10], DT), "samples"),
    (lambda x: extract_batch(np.where(np.arange(N) == 7, np.nan, x), DT), "samples"),
    (lambda x: extract_batch(x, 0.0), "dt"),
    (lambda x: extract_batch(x, DT, t0=float("inf")), "t0"),
    (lambda x: extract_batch(x, DT, units="V"), "calibration"),
    (lambda x: extract_batch(x, DT, units="mV", calibration=1.0), "units"),
    (lambda x: extract_batch(x, DT, threads=0), "threads"),
    (lambda x: extract_batch(x, DT, window=3), "window"),
    (lambda x: extract_batch(x, DT, pretrigger_s=1.0), "pretrigger_s"),
])
def test_bad_input_names_the_field(shots, call, field):
    with pytest.raises(WaveformError) as info:
        call(shots[:3])
    assert info.value.field == field


def test_nan_error_names_shot_and_sample(shots):
    x = shots[:4].copy()
    x[2, 7] = np.nan
    with pytest.raises(WaveformError, match="shot 2, sample 7"):
        extract_batch(x, DT)
