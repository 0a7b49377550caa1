"""Write the vendor-layout fixtures of test_vendor_files.py: one noisy simulated sensor trace,
in volts, saved the way each instrument's software saves a waveform.

Run from the repository root: ``.venv/bin/python tests/data/vendor/make_fixtures.py``. The
trace is the project's chain model (D = 9.53 mm on a 3.18 mm plate, infinite-plate tier), with
a static pre-trigger, converted to volts by a 20 N/V sensor, 0.3 % noise and a 12 mV offset.
``reference.npz`` keeps the exact samples every file holds (to the digits each layout prints).
The layouts follow the vendors' manuals and files seen in the wild; each writer names its own.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

from solitonde.instrument.tables.measured import as_measured
from solitonde.model.scene import load_scene
from solitonde.model.simulate import simulate

HERE = Path(__file__).resolve().parent
CAL = 20.0  # N/V
CRLF = "\r\n"


def trace() -> tuple[float, float, np.ndarray]:
    scene = load_scene(None, ["chain.diameter=9.53e-3", "plate.thickness=3.18e-3",
                              "striker.drop_height=5e-3", "effects.plate_model=infinite",
                              "output.duration=auto"])
    wave = as_measured(simulate(scene))
    volts = wave.samples / CAL
    rng = np.random.default_rng(14)
    volts = volts + 0.003 * volts.max() * rng.standard_normal(volts.size) + 0.012
    return wave.t0, wave.dt, volts


def trigger(t: np.ndarray) -> np.ndarray:
    """A 5 V TTL trigger that steps high 20 us before the chain's pulse reaches the sensor."""
    rng = np.random.default_rng(15)
    return np.where(t >= t[0] + 60e-6, 5.0, 0.0) + 0.002 * rng.standard_normal(t.size)


def write(name: str, text: str) -> None:
    (HERE / name).write_bytes(text.encode("utf-8"))


def tektronix_mso(t: np.ndarray, v: np.ndarray, dt: float) -> None:
    # Tektronix MSO 4/5/6 series, "Save As > Waveform (.csv)": Key,Value header lines, then
    # TIME,CH1 and one row per sample (CRLF).
    head = ["Model,MSO54", "Firmware Version,1.30.3.115", ",", "Waveform Type,ANALOG",
            "Point Format,Y", "Horizontal Units,s", f"Horizontal Scale,{dt * t.size / 10:.6e}",
            "Horizontal Delay,0.0", f"Sample Interval,{dt:.6e}", f"Record Length,{t.size}",
            "Gating,0.0% to 100.0%", "Probe Attenuation,1", "Vertical Units,V",
            "Vertical Offset,0.0", "Vertical Scale,0.5", "Vertical Position,0.0", ",", ",",
            ",", "Label,", "TIME,CH1"]
    rows = [f"{a:.10e},{b:.6f}" for a, b in zip(t, v, strict=True)]
    write("tek_mso5_save_waveform.csv", CRLF.join(head + rows) + CRLF)


def tektronix_legacy(t: np.ndarray, v: np.ndarray, dt: float) -> None:
    # Tektronix TDS/TBS/DPO (older firmware): six cells a row, metadata key and value in the
    # first two columns of the first rows, time and value in columns 4 and 5 beside them.
    meta = [("Record Length", f"{t.size:.6e}"), ("Sample Interval", f"{dt:.6e}"),
            ("Trigger Point", "2.000000000000e+02"), ("", ""), ("", ""), ("Source", "CH1"),
            ("Vertical Units", "V"), ("Vertical Scale", "5.000000e-01"),
            ("Vertical Offset", "0.000000e+00"), ("Horizontal Units", "s"),
            ("Horizontal Scale", f"{dt * t.size / 10:.6e}"), ("Pt Fmt", "Y"),
            ("Yzero", "0.000000e+00"), ("Probe Atten", "1.000000e+00"),
            ("Model Number", "TBS1052B"), ("Serial Number", "C010427"),
            ("Firmware Version", "FV:v4.00")]
    rows = []
    for i, (a, b) in enumerate(zip(t, v, strict=True)):
        key, value = meta[i] if i < len(meta) else ("", "")
        rows.append(f"{key},{value},,{a:.12f},{b:.6f},")
    write("tek_tbs_legacy.csv", CRLF.join(rows) + CRLF)


def keysight(t: np.ndarray, v: np.ndarray) -> None:
    # Keysight/Agilent InfiniiVision "Save > CSV": the channel numbers, a units row, then
    # time and one column per channel. Channel 2 is the trigger output.
    trig = trigger(t)
    rows = [f"{a:.8E},{b:.8E},{c:.8E}" for a, b, c in zip(t, v, trig, strict=True)]
    write("keysight_infiniivision_2ch.csv", CRLF.join(["x-axis,1,2", "second,Volt,Volt", *rows])
          + CRLF)


def rigol(t: np.ndarray, v: np.ndarray, dt: float) -> None:
    # Rigol DS1000Z "Save > CSV": X counts samples; the second row holds the start time and
    # the increment; each row ends with a comma.
    rows = [f"{i},{b:.5e}," for i, b in enumerate(v)]
    head = ["X,CH1,Start,Increment,", f"Sequence,Volt,{t[0]:.6e},{dt:.6e}"]
    write("rigol_ds1000z.csv", CRLF.join(head + rows) + CRLF)


def picoscope6(t: np.ndarray, v: np.ndarray) -> None:
    # PicoScope 6 "Save As > CSV": names, units in brackets, a blank line, time in ms and the
    # channel in mV.
    rows = [f"{a * 1e3:.8f},{b * 1e3:.5f}" for a, b in zip(t, v, strict=True)]
    write("picoscope6_ms_mv.csv", CRLF.join(["Time,Channel A", "(ms),(mV)", "", *rows]) + CRLF)


def picoscope7(t: np.ndarray, v: np.ndarray) -> None:
    # PicoScope 7: the same layout in us and V; channel B is an unconnected input (noise).
    rng = np.random.default_rng(16)
    b = 0.001 * rng.standard_normal(t.size)
    rows = [f"{a * 1e6:.5f},{x:.7f},{y:.7f}" for a, x, y in zip(t, v, b, strict=True)]
    write("picoscope7_us_v_2ch.csv",
          CRLF.join(["Time,Channel A,Channel B", "(us),(V),(V)", "", *rows]) + CRLF)


def lecroy(t: np.ndarray, v: np.ndarray) -> None:
    # Teledyne LeCroy "File > Save Waveform > ASCII (Excel)": instrument line, segment lines,
    # then Time,Ampl.
    head = ["LECROYWR104MXi-A,45236,Waveform", f"Segments,1,SegmentSize,{t.size}",
            "Segment,TrigTime,TimeSinceSegment1", "#1,25-Nov-2026 09:14:03,0", "Time,Ampl"]
    rows = [f"{a:.6e},{b:.6e}" for a, b in zip(t, v, strict=True)]
    write("lecroy_waverunner.csv", CRLF.join(head + rows) + CRLF)


def generic(t: np.ndarray, v: np.ndarray) -> None:
    # Spreadsheet exports: units in the column names.
    rows = [f"{a:.9g},{b * 1e3:.6f}" for a, b in zip(t, v, strict=True)]
    write("generic_time_s_voltage_mv.csv", "\n".join(["Time (s),Voltage (mV)", *rows]) + "\n")
    # Excel in a German locale: semicolons and decimal commas.
    rows = [f"{a * 1e3:.7f};{b:.7f}".replace(".", ",") for a, b in zip(t, v, strict=True)]
    write("generic_semicolon_decimal_comma.csv",
          CRLF.join(["time [ms];Voltage [V]", *rows]) + CRLF)
    # A DAQ program's tab-separated export, already in force (kN).
    rows = [f"{a * 1e6:.4f}\t{b * CAL / 1e3:.9f}" for a, b in zip(t, v, strict=True)]
    write("generic_tab_force_kN.csv", "\n".join(["time [us]\tforce_kN", *rows]) + "\n")
    rows = [f"{a:.9g},{b * CAL:.6f}" for a, b in zip(t, v, strict=True)]
    write("generic_force_N.csv", "\n".join(["Time (s),Force (N)", *rows]) + "\n")


def ni_daq(t0: float, dt: float, t: np.ndarray, v: np.ndarray) -> None:
    # NI DAQmx logging (LabVIEW "TDMS Streaming"): group "Measured Data", one channel per
    # physical input named after it, the waveform properties DAQmx writes.
    props = {"wf_start_offset": t0, "wf_increment": dt, "wf_samples": t.size,
             "wf_start_time": np.datetime64("2026-11-25T09:14:03.250000"),
             "unit_string": "V", "NI_UnitDescription": "Volts"}
    with TdmsWriter(str(HERE / "ni_daq_trigger.tdms")) as tdms:
        tdms.write_segment([
            RootObject({"name": "run 7", "author": "NDE lab"}), GroupObject("Measured Data"),
            ChannelObject("Measured Data", "Dev1/ai0", v,
                          properties={**props, "NI_ChannelName": "Dev1/ai0"}),
            ChannelObject("Measured Data", "Dev1/ai1", trigger(t),
                          properties={**props, "NI_ChannelName": "Dev1/ai1"})])


def main() -> None:
    t0, dt, v = trace()
    t = t0 + dt * np.arange(v.size)
    np.savez_compressed(HERE / "reference.npz", t0=t0, dt=dt, volts=v, calibration=CAL)
    tektronix_mso(t, v, dt)
    tektronix_legacy(t, v, dt)
    keysight(t, v)
    rigol(t, v, dt)
    picoscope6(t, v)
    picoscope7(t, v)
    lecroy(t, v)
    generic(t, v)
    ni_daq(t0, dt, t, v)


if __name__ == "__main__":
    main()
