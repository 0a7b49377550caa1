"""Channels of a file: a trigger step, a gate, a digital edge or a flat line is never taken for a
sensor trace; sensor traces at the SNRs the project handles are kept; a choice by name is
honoured, and a name the file lacks is an error listing those it has."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from solitonde.signal import io
from solitonde.signal.channels import FLAT, SENSOR, TRIGGER, classify, select
from solitonde.signal.errors import WaveformError
from solitonde.signal.synth import degrade, pulse_train
from solitonde.signal.waveform import Waveform

DATA = Path(__file__).resolve().parents[2] / "data_samples" / "waveforms"
DT = 5e-7
N = 4000


def _wave(samples: np.ndarray, channel: str, group: str | None = None, dt: float = DT
          ) -> Waveform:
    meta = {"channel": channel, **({"group": group} if group else {})}
    return Waveform(0.0, dt, samples, "V", 20.0, meta)


def _sensor(snr_db: float, seed: int = 0) -> np.ndarray:
    clean = pulse_train(N, DT, [(400e-6, 2.0, 120e-6), (1100e-6, 0.6, 140e-6)])
    return degrade(clean, snr_db, np.random.default_rng(seed), 2.0, drift=0.01)


def _step(level: float = 5.0, at: float = 350e-6, seed: int = 1) -> np.ndarray:
    t = DT * np.arange(N)
    return level * (t >= at) + 0.003 * np.random.default_rng(seed).standard_normal(N)


@pytest.mark.parametrize("snr_db", [20.0, 30.0, 40.0, 60.0])
@pytest.mark.parametrize("seed", range(5))
def test_sensor_traces_are_sensor_traces(snr_db, seed):
    assert classify(_wave(_sensor(snr_db, seed), "ai0")).kind == SENSOR


def test_the_sample_files_are_sensor_traces():
    for path in sorted(DATA.glob("synthetic_*")):
        for w in io.read(path):
            assert classify(w).kind == SENSOR, (path.name, classify(w))


def test_triggers_gates_edges_and_flat_lines_are_not():
    rng = np.random.default_rng(3)
    t = DT * np.arange(N)
    white = 0.001 * rng.standard_normal(N)
    smooth = np.convolve(rng.standard_normal(N + 40), np.ones(41) / 41, mode="valid") * 0.01
    cases = {
        "step up": (_step(), TRIGGER, "step"),
        "step down": (5.0 - _step(), TRIGGER, "step"),
        "gate": (5.0 * ((t > 200e-6) & (t < 1200e-6)) + white, TRIGGER, "gate"),
        "ttl pulse": (5.0 * ((t > 300e-6) & (t < 310e-6)) + white, TRIGGER, "edge"),
        "white noise": (white, FLAT, "flat"),
        "smoothed noise": (smooth, FLAT, "flat"),
        "constant": (np.full(N, 0.25), FLAT, "flat"),
    }
    for name, (samples, kind, word) in cases.items():
        verdict = classify(_wave(samples, name))
        assert verdict.kind == kind and word in verdict.reason, (name, verdict)


def test_without_a_choice_the_sensor_is_kept_and_the_trigger_skipped_with_its_reason():
    waves = [_wave(_sensor(40.0), "Dev1/ai0", "Measured Data"),
             _wave(_step(), "Dev1/ai1", "Measured Data")]
    kept, skipped = select(waves, where="daq.tdms")
    assert [w.metadata["channel"] for w in kept] == ["Dev1/ai0"]
    assert skipped == [{"channel": "Measured Data/Dev1/ai1", "reason": skipped[0]["reason"]}]
    assert "step" in skipped[0]["reason"]


def test_a_choice_by_name_by_group_path_or_bare_name():
    waves = [_wave(_sensor(40.0), "Dev1/ai0", "Measured Data"),
             _wave(_step(), "Dev1/ai1", "Measured Data")]
    for spec in ("Dev1/ai0", "Measured Data/Dev1/ai0"):
        kept, skipped = select(waves, [spec], where="daq.tdms")
        assert len(kept) == 1 and kept[0].metadata["channel"] == "Dev1/ai0"
        assert skipped == [{"channel": "Measured Data/Dev1/ai1", "reason": "not chosen"}]
    kept, _ = select(waves, None, "Measured Data", where="daq.tdms")
    assert len(kept) == 1


def test_a_channel_the_file_lacks_is_an_error_listing_those_it_has():
    waves = [_wave(_sensor(40.0), "CH1"), _wave(_step(), "CH2")]
    with pytest.raises(WaveformError) as err:
        select(waves, ["CH3"], where="scope.csv")
    assert err.value.field == "channel" and "CH3" in str(err.value)
    assert err.value.allowed == "CH1, CH2"
    with pytest.raises(WaveformError) as err:
        select(waves, None, "Raw", where="scope.csv")
    assert err.value.field == "group"


def test_choosing_the_trigger_is_refused_not_analysed():
    waves = [_wave(_sensor(40.0), "CH1"), _wave(_step(), "CH2")]
    with pytest.raises(WaveformError) as err:
        select(waves, ["CH2"], where="scope.csv")
    assert "CH2" in str(err.value) and "not a sensor trace" in str(err.value)


def test_a_file_with_no_sensor_trace_is_refused_listing_every_channel():
    waves = [_wave(_step(), "CH1"), _wave(0.001 * np.random.default_rng(0).standard_normal(N),
                                         "CH2")]
    with pytest.raises(WaveformError) as err:
        select(waves, where="scope.csv")
    text = str(err.value)
    assert "no channel is a sensor trace" in text and "CH1: trigger" in text and "CH2: flat" in text


def test_a_coarsely_sampled_channel_it_cannot_call_is_refused():
    """At 100 kHz a 40 us pulse rises most of its height in one sample, like an edge: the file is
    refused, listing the channels, rather than guessed."""
    t = 1e-5 * np.arange(400)
    noise = 0.002 * np.random.default_rng(0).standard_normal(400)
    pulse = np.exp(-(((t - 1e-3) / 8e-6) ** 2)) + noise
    waves = [_wave(pulse, "CH1", dt=1e-5), _wave(5.0 * (t > 9e-4), "CH2", dt=1e-5)]
    with pytest.raises(WaveformError) as err:
        select(waves, where="slow.csv")
    assert "cannot tell" in str(err.value) and "CH1: unclear" in str(err.value)
    kept, _ = select(waves[:1], None, where="slow.csv")  # one channel: nothing to tell apart
    assert len(kept) == 1


def test_a_files_own_shots_are_all_kept():
    """This project's multi-shot files (columns or channels shot_000, shot_001) lose nothing."""
    for path in sorted(DATA.glob("synthetic_*")):
        waves = io.read(path)
        kept, skipped = select(waves, where=path.name)
        assert len(kept) == len(waves) and not skipped
