"""The text-table reader on its own: units scaled from the file, delimiters and decimal commas,
the time column never a shot, and a layout it cannot read named by file, line and expectation.
The vendors' full files are in test_vendor_files.py."""

from __future__ import annotations

import numpy as np
import pytest

from solitonde.signal import io
from solitonde.signal.errors import WaveformError
from solitonde.signal.formats.csv_layouts import parse

T = -20e-6 + 0.5e-6 * np.arange(300)
PULSE = np.exp(-(((T - 60e-6) / 12e-6) ** 2))


def _rows(fmt: str, time_scale: float = 1.0, value_scale: float = 1.0, sep: str = ",",
          comma: bool = False) -> str:
    lines = []
    for t, v in zip(T * time_scale, PULSE * value_scale, strict=True):
        line = f"{fmt.format(t)}{sep}{v:.7g}"
        lines.append(line.replace(".", ",") if comma else line)
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(("header", "time_scale", "value_scale", "unit", "sep", "comma"), [
    ("Time (s),Voltage (V)", 1.0, 1.0, "V", ",", False),
    ("time [ms];Voltage [mV]", 1e3, 1e3, "V", ";", True),
    ("Time (us)\tForce (N)", 1e6, 1.0, "N", "\t", False),
    ("time_s,force_kN", 1.0, 1e-3, "N", ",", False),
    ("t [ns];Signal [uV]", 1e9, 1e6, "V", ";", False),
    ("Zeit (µs);Kraft (lbf)", 1e6, 1 / 4.4482216152605, "N", ";", True),
])
def test_units_in_column_names_are_scaled_to_seconds_volts_newtons(
        tmp_path, header, time_scale, value_scale, unit, sep, comma):
    path = tmp_path / "x.csv"
    path.write_text(header + "\n" + _rows("{:.9g}", time_scale, value_scale, sep, comma),
                    encoding="utf-8")
    (w,) = io.read(path, calibration=10.0) if unit == "V" else io.read(path)
    assert w.units == unit and w.n == T.size
    assert w.t0 == pytest.approx(T[0], rel=1e-6) and w.dt == pytest.approx(0.5e-6, rel=1e-6)
    np.testing.assert_allclose(w.samples, PULSE, rtol=2e-6, atol=1e-9)
    if not header.startswith("time_s"):  # this project's own layout: columns are shots
        assert w.metadata["channel"] == header.split(sep)[1]


def test_windows_1252_text_with_a_micro_sign_is_read(tmp_path):
    path = tmp_path / "w.csv"
    path.write_bytes(("Zeit (µs);Spannung (mV)\r\n" + _rows("{:.6f}", 1e6, 1e3, ";", True))
                     .encode("cp1252"))
    (w,) = io.read(path, calibration=1.0)
    assert w.dt == pytest.approx(0.5e-6, rel=1e-6) and w.samples.max() == pytest.approx(1.0)


def test_rounded_time_stamps_are_a_uniform_grid_but_a_gap_is_not(tmp_path):
    """Time printed with 4 decimals of microseconds is uniform within its printing; a missing
    sample is still refused, naming the time column."""
    path = tmp_path / "r.csv"
    path.write_text("Time (us),Voltage (V)\n" + _rows("{:.1f}", 1e6))
    (w,) = io.read(path, calibration=1.0)
    assert w.dt == pytest.approx(0.5e-6, rel=1e-9)
    lines = path.read_text().splitlines()
    path.write_text("\n".join(lines[:100] + lines[101:]) + "\n")
    with pytest.raises(WaveformError) as err:
        io.read(path, calibration=1.0)
    assert err.value.field == "time"


def test_several_value_columns_are_several_channels_with_their_own_units(tmp_path):
    path = tmp_path / "two.csv"
    body = "".join(f"{t:.9g},{v * 1e3:.6g},{v:.6g}\n" for t, v in zip(T, PULSE, strict=True))
    path.write_text("Time (s),Sensor (mV),Force (N)\n" + body)
    table = parse(path.read_text(), path.name)
    assert [c.label for c in table.columns] == ["Sensor (mV)", "Force (N)"]
    assert [c.unit for c in table.columns] == ["V", "N"]
    np.testing.assert_allclose(table.columns[0].values, table.columns[1].values, rtol=1e-5)


def test_over_range_samples_are_refused_naming_the_channel(tmp_path):
    path = tmp_path / "pico.csv"
    values = [f"{v * 1e3:.4f}" if i != 120 else "∞" for i, v in enumerate(PULSE)]
    rows = "".join(f"{t * 1e3:.8f},{v}\r\n" for t, v in zip(T, values, strict=True))
    path.write_text("Time,Channel A\r\n(ms),(mV)\r\n\r\n" + rows, encoding="utf-8")
    with pytest.raises(WaveformError) as err:
        io.read(path, calibration=1.0)
    assert err.value.field == "samples" and "Channel A" in str(err.value)
    assert "over range" in str(err.value) and "sample 120" in str(err.value)


@pytest.mark.parametrize(("text", "field", "says"), [
    ("Time (s),Voltage (V)\n" + _rows("{:.9g}").replace("\n", "\n", 40)[:2000] + "0.1,abc\n"
     + _rows("{:.9g}")[2000:], "samples", "line"),
    ("Time (s),Voltage (V)\n1e-6,1,2\n" + _rows("{:.9g}"), "file", "line 2"),
    ("Time (fortnights),Voltage (V)\n" + _rows("{:.9g}"), "units", "fortnights"),
    ("Time (s),Pressure (psi)\n" + _rows("{:.9g}"), "units", "psi"),
    ("Model,XYZ\nfoo,bar,baz\n", "samples", "no data rows"),
    ("a header\n" + "".join(f"{i} {i} x\n" for i in range(50)), "file", "line 51"),
])
def test_a_layout_it_cannot_read_names_the_file_line_and_what_was_expected(
        tmp_path, text, field, says):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(WaveformError) as err:
        io.read(path, calibration=1.0)
    assert err.value.field == field, str(err.value)
    assert "bad.csv" in str(err.value) and says in str(err.value), str(err.value)
    assert err.value.allowed, "the error says what was expected"


def test_a_bad_cell_in_the_middle_of_the_data_is_named_by_its_line(tmp_path):
    path = tmp_path / "mid.csv"
    lines = ["Time (s),Voltage (V)", *_rows("{:.9g}").splitlines()]
    lines[150] = lines[150].split(",")[0] + ",1.2.3"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(WaveformError) as err:
        io.read(path, calibration=1.0)
    assert "line 151, column 2" in str(err.value) and "'1.2.3'" in str(err.value)


VENDOR = __import__("pathlib").Path(__file__).resolve().parents[1] / "data" / "vendor"


@pytest.mark.parametrize("name", ["tek_mso5_save_waveform.csv", "tek_tbs_legacy.csv",
                                  "lecroy_waverunner.csv"])
def test_a_scope_file_cut_at_a_line_end_is_refused_by_its_declared_record_length(tmp_path,
                                                                                   name):
    """Cut exactly between two rows, a file still parses; its header's record length tells."""
    lines = (VENDOR / name).read_text().splitlines(keepends=True)
    whole = io.read(VENDOR / name, calibration=1.0)
    assert whole[0].n > 1000
    path = tmp_path / name
    path.write_text("".join(lines[:-300]))
    with pytest.raises(WaveformError) as err:
        io.read(path, calibration=1.0)
    assert "cut short" in str(err.value) and name in str(err.value), str(err.value)


def test_the_projects_own_csv_declares_its_length_and_a_cut_one_is_refused(tmp_path):
    from solitonde.signal.waveform import Waveform

    path = io.write(tmp_path / "own.csv", Waveform(samples=PULSE, t0=float(T[0]), dt=0.5e-6,
                                                   units="V", calibration=1.0))
    assert io.read(path)[0].n == PULSE.size and "n_samples" not in io.read(path)[0].metadata
    text = path.read_text()
    path.write_text(text[:text.rfind("\n", 0, len(text) - 2000) + 1])
    with pytest.raises(WaveformError, match=r"own\.csv: \d+ data rows, its header declares 300"):
        io.read(path)


def test_a_row_cut_short_at_the_end_is_named_as_the_odd_one(tmp_path):
    path = tmp_path / "end.csv"
    path.write_text("Time (s),V1 (V),V2 (V)\n" + "".join(
        f"{t:.9g},{v:.7g},{v:.7g}\n" for t, v in zip(T, PULSE, strict=True)) + "1e-4,0.5\n")
    with pytest.raises(WaveformError, match=r"line 302: 2 values, the other rows have 3"):
        io.read(path, calibration=1.0)
