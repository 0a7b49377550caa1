"""Waveform files: every format round-trips; every bad input raises an error naming its field."""

from __future__ import annotations

import json

import numpy as np
import pytest

from solitonde.signal import io
from solitonde.signal.errors import WaveformError
from solitonde.signal.synth import pulse_train
from solitonde.signal.waveform import MIN_SAMPLES, Waveform

DT = 5e-7


def _shots(k: int = 2) -> list[Waveform]:
    out = []
    for i in range(k):
        x = pulse_train(400, DT, [(40e-6, 30.0, 80e-6), (150e-6, 15.0 + i, 85e-6)])
        out.append(Waveform(0.0, DT, x, "N", None,
                            {"plate_id": "P1", "position": 0.1, "sphere_diameter": 9.53e-3,
                             "scene": {"plate": {"thickness": 3.18e-3}}}))
    return out


@pytest.mark.parametrize("ext", ["csv", "npz", "h5", "tdms", "json", "npy"])
def test_round_trip(tmp_path, ext):
    """Written shots read back with the same samples, time axis and metadata."""
    shots = _shots()
    path = io.write(tmp_path / f"shots.{ext}", shots)
    back = io.read(path)
    assert len(back) == len(shots)
    for a, b in zip(shots, back, strict=True):
        assert b.n == a.n
        assert b.dt == pytest.approx(a.dt, rel=1e-9)
        assert b.t0 == pytest.approx(a.t0, abs=1e-12)
        np.testing.assert_allclose(b.samples, a.samples, rtol=1e-8, atol=1e-9)
        assert b.metadata["source"] == path.name
        if ext != "npy":
            assert b.metadata["plate_id"] == "P1"
            assert b.metadata["position"] == pytest.approx(0.1)
        if ext in ("csv", "npz", "json", "h5", "tdms"):
            assert b.metadata["scene"] == {"plate": {"thickness": 3.18e-3}}
    assert [w.metadata["shot"] for w in back] == [0, 1]


def test_csv_single_column_needs_sample_rate(tmp_path):
    """A bare column of samples is read only with an explicit sample rate."""
    path = tmp_path / "raw.csv"
    np.savetxt(path, np.arange(100.0))
    with pytest.raises(WaveformError) as err:
        io.read(path)
    assert err.value.field == "sample_rate"
    (w,) = io.read(path, sample_rate=1e6, t0=1e-3)
    assert w.dt == pytest.approx(1e-6) and w.t0 == pytest.approx(1e-3) and w.n == 100


def test_csv_comment_metadata(tmp_path):
    """`# key: value` lines become metadata; JSON values are decoded."""
    path = tmp_path / "m.csv"
    t = np.arange(64) * 1e-6
    body = "\n".join(f"{a:.9g},{b:.9g}" for a, b in zip(t, np.sin(t * 1e5), strict=True))
    path.write_text('# plate_id: A7\n# scene: {"chain": {"diameter": 0.00953}}\n'
                    f"time_s,force_N\n{body}\n")
    (w,) = io.read(path)
    assert w.metadata["plate_id"] == "A7"
    assert w.metadata["scene"] == {"chain": {"diameter": 0.00953}}


def test_voltage_needs_calibration(tmp_path):
    """Volts are converted with the calibration, and refused without one."""
    path = tmp_path / "v.csv"
    t = np.arange(64) * 1e-6
    path.write_text("time_s,voltage_V\n" + "\n".join(f"{a:.9g},0.5" for a in t) + "\n")
    with pytest.raises(WaveformError) as err:
        io.read(path)
    assert err.value.field == "calibration"
    (w,) = io.read(path, calibration=20.0)
    assert w.units == "V" and np.allclose(w.force, 10.0)


@pytest.mark.parametrize(
    ("text", "field"),
    [
        ("time_s,force_N\n", "samples"),
        ("time_s,force_N\n" + "".join(f"{i}e-6,{'nan' if i == 5 else 1.0}\n" for i in range(40)),
         "samples"),
        ("time_s,force_N\n" + "".join(f"{i}e-6,{'inf' if i == 5 else 1.0}\n" for i in range(40)),
         "samples"),
        ("time_s,force_N\n" + "".join(f"{i}e-6,1.0\n" for i in range(5)), "samples"),
        ("time_s,force_N\n" + "".join(f"{(i if i != 7 else 9)}e-6,1\n" for i in range(40)), "time"),
        ("time_s,force_N\n" + "".join(f"{i * i}e-6,1\n" for i in range(40)), "time"),
        ("time_s,force_kN\n" + "".join(f"{i}e-6,1\n" for i in range(40)), "units"),
        ("time_s\n" + "".join(f"{i}e-6\n" for i in range(40)), "channel"),
    ],
    ids=["empty", "nan", "inf", "too_few", "non_monotonic", "non_uniform", "unknown_units",
         "missing_channel"],
)
def test_bad_csv(tmp_path, text, field):
    """Each defect raises WaveformError naming the field at fault."""
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(WaveformError) as err:
        io.read(path)
    assert err.value.field == field, str(err.value)


def test_waveform_validation():
    """The constructor names the field: dt, units, samples, calibration."""
    x = np.ones(MIN_SAMPLES)
    cases = [
        (dict(t0=0, dt=0.0, samples=x), "dt"),
        (dict(t0=0, dt=-1e-6, samples=x), "dt"),
        (dict(t0=0, dt=1e-6, samples=x, units="kN"), "units"),
        (dict(t0=0, dt=1e-6, samples=np.ones((4, 40))), "samples"),
        (dict(t0=0, dt=1e-6, samples=[]), "samples"),
        (dict(t0=float("nan"), dt=1e-6, samples=x), "t0"),
        (dict(t0=0, dt=1e-6, samples=x, units="V"), "calibration"),
    ]
    for kwargs, field in cases:
        with pytest.raises(WaveformError) as err:
            Waveform(**kwargs)
        assert err.value.field == field


def test_format_choice(tmp_path):
    """Unknown or ambiguous extensions are refused; an explicit format= is honoured."""
    shots = _shots(1)
    for name in ("a.txt", "a.xyz", "a"):
        with pytest.raises(WaveformError) as err:
            io.write(tmp_path / name, shots)
        assert err.value.field == "format"
    path = io.write(tmp_path / "a.txt", shots, format="csv")
    assert io.read(path, format="csv")[0].n == shots[0].n
    with pytest.raises(WaveformError) as err:
        io.read(path)
    assert err.value.field == "format"
    with pytest.raises(WaveformError) as err:
        io.read(path, format="wav")
    assert err.value.field == "format"


def test_tdms_group_and_channel(tmp_path):
    """TDMS channels are selected by group and name; a missing one is named in the error."""
    path = io.write(tmp_path / "s.tdms", _shots(3))
    assert len(io.read(path)) == 3
    (w,) = io.read(path, group="shots", channel="shot_001")
    assert w.metadata["channel"] == "shot_001"
    with pytest.raises(WaveformError) as err:
        io.read(path, group="shots", channel="shot_009")
    assert err.value.field == "channel" and "shot_001" in str(err.value)
    with pytest.raises(WaveformError) as err:
        io.read(path, group="nope")
    assert err.value.field == "group"


def test_hdf5_dataset_selection(tmp_path):
    """An HDF5 dataset path selects one shot; missing dt/sample_rate attributes are an error."""
    import h5py

    path = io.write(tmp_path / "s.h5", _shots(2))
    (w,) = io.read(path, dataset="shots/shot_001")
    assert w.metadata["dataset"] == "/shots/shot_001"
    bare = tmp_path / "bare.h5"
    with h5py.File(bare, "w") as fh:
        fh["x"] = np.ones(100)
    with pytest.raises(WaveformError) as err:
        io.read(bare)
    assert err.value.field == "sample_rate"
    assert io.read(bare, sample_rate=1e6)[0].dt == pytest.approx(1e-6)
    with pytest.raises(WaveformError) as err:
        io.read(path, dataset="nope")
    assert err.value.field == "dataset"


def test_json_shapes():
    """Single object, list and {"shots": [...]} bodies; errors carry the shot's path."""
    one = _shots(1)[0].to_dict()
    assert len(io.from_json(one)) == 1
    assert len(io.from_json([one, one])) == 2
    assert len(io.from_json({"shots": [one, one]})) == 2
    bad = dict(one, samples=[1.0] * 10)
    with pytest.raises(WaveformError) as err:
        io.from_json({"shots": [one, bad]})
    assert err.value.field == "shots[1].samples"
    with pytest.raises(WaveformError) as err:
        io.from_json({"shots": [dict(one, units="mV")]})
    assert err.value.field == "shots[0].units"
    json.dumps(io.to_json(_shots(2)))


def test_npy_layouts(tmp_path):
    """NPY: time in column 0, or samples only with sample_rate."""
    path = tmp_path / "a.npy"
    np.save(path, np.ones(100))
    with pytest.raises(WaveformError) as err:
        io.read(path)
    assert err.value.field == "sample_rate"
    assert io.read(path, sample_rate=2e6)[0].dt == pytest.approx(5e-7)
    np.save(path, np.ones((3, 100)))
    assert len(io.read(path, sample_rate=2e6)) == 3
