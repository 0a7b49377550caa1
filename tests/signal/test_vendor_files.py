"""Files saved the way instruments' software saves them give the trace's own TOF and ARR.

Every fixture in tests/data/vendor/ holds one noisy simulated sensor trace in volts (20 N/V
sensor), written by make_fixtures.py in a vendor's layout (each writer there names it):

- tek_mso5_save_waveform.csv: Tektronix MSO 4/5/6 "Save Waveform" (Key,Value header, TIME,CH1)
- tek_tbs_legacy.csv: Tektronix TDS/TBS (metadata in the first columns beside the data)
- keysight_infiniivision_2ch.csv: Keysight InfiniiVision (x-axis,1,2 / second,Volt,Volt);
  channel 2 is a trigger step
- rigol_ds1000z.csv: Rigol (X,CH1,Start,Increment; X counts samples)
- picoscope6_ms_mv.csv: PicoScope 6 (Time,Channel A / (ms),(mV) / blank line)
- picoscope7_us_v_2ch.csv: PicoScope 7 in us and V; channel B an unconnected input
- lecroy_waverunner.csv: Teledyne LeCroy (LECROY... header, Time,Ampl)
- generic_*.csv: spreadsheet exports with units in the column names, comma, semicolon with
  decimal commas, tab; force in kN and N
- ni_daq_trigger.tdms: NI DAQmx logging, group "Measured Data", Dev1/ai0 sensor, Dev1/ai1 trigger

The command line reads each with at most --calibration and must find the reference trace's TOF
within 1 us and ARR within 1 % (what the printed digits allow), the trigger never a shot.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app
from solitonde.signal import io as signal_io
from solitonde.signal.features import extract
from solitonde.signal.waveform import Waveform

HERE = Path(__file__).resolve().parents[1] / "data" / "vendor"
FILES = {  # file -> (layout the reader reports or None, channel analysed, needs --calibration)
    "tek_mso5_save_waveform.csv": ("tektronix", "CH1", True),
    "tek_tbs_legacy.csv": ("tektronix-legacy", "CH1", True),
    "keysight_infiniivision_2ch.csv": ("keysight", "1", True),
    "rigol_ds1000z.csv": ("rigol", "CH1", True),
    "picoscope6_ms_mv.csv": ("picoscope", "Channel A", True),
    "picoscope7_us_v_2ch.csv": ("picoscope", "Channel A", True),
    "lecroy_waverunner.csv": ("lecroy", "Ampl", True),
    "generic_time_s_voltage_mv.csv": (None, "Voltage (mV)", True),
    "generic_semicolon_decimal_comma.csv": (None, "Voltage [V]", True),
    "generic_tab_force_kN.csv": (None, "force_kN", False),
    "generic_force_N.csv": (None, "Force (N)", False),
    "ni_daq_trigger.tdms": (None, "Measured Data/Dev1/ai0", True),
}


@pytest.fixture(scope="module")
def reference():
    ref = np.load(HERE / "reference.npz")
    wave = Waveform(float(ref["t0"]), float(ref["dt"]), ref["volts"], "V",
                    float(ref["calibration"]))
    return extract(wave)


def _analyze(*args: str):
    return CliRunner().invoke(build_app(), ["analyze", *map(str, args), "--json"])


@pytest.mark.parametrize("name", sorted(FILES))
def test_each_vendor_layout_gives_the_traces_own_tof_and_arr(name, reference):
    layout, channel, volts = FILES[name]
    res = _analyze(HERE / name, *(["--calibration", "20"] if volts else []))
    assert res.exit_code == 0, res.output
    report = json.loads(res.stdout)
    (shot,) = report["shots"]
    assert shot["channel"] == channel
    assert abs(shot["tof_s"] - reference.tof_s) < 1e-6, (shot["tof_s"], reference.tof_s)
    assert abs(shot["arr"] / reference.arr - 1.0) < 0.01, (shot["arr"], reference.arr)
    assert "no_reflection" not in shot["flags"]
    if layout is not None:
        (wave,) = [w for w in signal_io.read(HERE / name, calibration=20.0)
                   if w.metadata.get("channel") == channel.split("/")[-1]]
        assert wave.metadata["layout"] == layout


def test_the_reference_has_a_clear_reflection(reference):
    assert 0.1 < reference.arr < 0.9 and reference.snr_db > 40
    assert not reference.flags


@pytest.mark.parametrize("name", ["keysight_infiniivision_2ch.csv", "picoscope7_us_v_2ch.csv"])
def test_a_scopes_second_channel_is_skipped_with_its_reason(name):
    report = json.loads(_analyze(HERE / name, "--calibration", "20").stdout)
    (skipped,) = report["skipped_channels"]
    assert skipped["channel"] in ("2", "Channel B")
    assert ("step" if skipped["channel"] == "2" else "flat") in skipped["reason"]


def test_the_daq_trigger_is_never_a_shot_with_or_without_channel():
    tdms = HERE / "ni_daq_trigger.tdms"
    for extra in ([], ["--channel", "Dev1/ai0"], ["--channel", "Measured Data/Dev1/ai0"],
                  ["--group", "Measured Data"]):
        res = _analyze(tdms, "--calibration", "20", *extra)
        assert res.exit_code == 0, res.output
        report = json.loads(res.stdout)
        assert [s["channel"] for s in report["shots"]] == ["Measured Data/Dev1/ai0"], extra
    res = _analyze(tdms, "--calibration", "20", "--channel", "Dev1/ai1")
    assert res.exit_code == 1 and not json.loads(res.stdout)["shots"]
    assert "not a sensor trace" in json.loads(res.stdout)["errors"][0]["error"]


def test_a_channel_that_does_not_exist_is_an_error_listing_those_that_do():
    res = _analyze(HERE / "ni_daq_trigger.tdms", "--calibration", "20", "--channel", "Dev2/ai0")
    assert res.exit_code == 1
    (error,) = json.loads(res.stdout)["errors"]
    assert "--channel" in error["error"] and "Dev2/ai0" in error["error"]
    assert "Measured Data/Dev1/ai0, Measured Data/Dev1/ai1" in error["error"]


def test_an_unknown_layout_is_an_error_naming_the_file_and_line(tmp_path):
    odd = tmp_path / "odd.csv"
    odd.write_text("Oscilloscope export v2\nsamples follow\n" + "".join(
        f"{i}; {i * 0.1:.3f}; x\n" for i in range(100)))
    res = _analyze(odd)
    assert res.exit_code == 1
    (error,) = json.loads(res.stdout)["errors"]
    assert "odd.csv" in error["error"] and "line 102" in error["error"]


def test_without_calibration_volts_are_refused_naming_the_flag():
    res = _analyze(HERE / "tek_mso5_save_waveform.csv")
    assert res.exit_code == 1
    (error,) = json.loads(res.stdout)["errors"]
    assert "--calibration" in error["error"] and "calibration=" not in error["error"]
