"""Waveform files: every format round-trips; every bad input raises an error naming its field."""

from __future__ import annotations

import json
from pathlib import Path

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
            assert b.metadata["position"] == "0.1"  # an identifier: text in every format
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
        ("time_s,force_psi\n" + "".join(f"{i}e-6,1\n" for i in range(40)), "units"),
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


# --- review fixes: malformed files, options, units, identifiers, the service's JSON shape -------

def _csv_rows(n: int = 400) -> str:
    t = DT * np.arange(n)
    x = pulse_train(n, DT, [(50e-6, 100.0, 15e-6), (120e-6, 50.0, 15e-6)])
    return "\n".join(f"{a:.9g},{b:.9g}" for a, b in zip(t, x, strict=True)) + "\n"


def test_malformed_files_raise_waveform_error_naming_the_field(tmp_path):
    """Parser failures (BOM + comment, Latin-1, bad JSON, JSON lists as metadata, array-valued
    attributes, object arrays) are WaveformErrors naming the field, never TypeError & co."""
    import h5py

    x = pulse_train(400, DT, [(50e-6, 100.0, 15e-6)])
    (tmp_path / "bom.csv").write_text("\ufeff# plate_id: P1\ntime_s,force_N\n" + _csv_rows(),
                                      encoding="utf-8")
    (w,) = io.read(tmp_path / "bom.csv")  # a byte-order mark is read, not a parse error
    assert w.metadata["plate_id"] == "P1"
    (tmp_path / "lat.csv").write_bytes(b"# operator: J\xfcrgen\ntime_s,force_N\n"
                                       + _csv_rows().encode())
    (tmp_path / "bad.json").write_text("{not json")
    np.savez(tmp_path / "list.npz", samples=x, dt=DT, metadata=json.dumps([1]))
    np.save(tmp_path / "obj.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with h5py.File(tmp_path / "attr.h5", "w") as fh:
        fh["x"] = x
        fh["x"].attrs["dt"] = [DT, DT]
    (w,) = io.read(tmp_path / "lat.csv")  # Windows-1252, as Windows spreadsheets save it
    assert w.metadata["operator"] == "J\u00fcrgen"
    (tmp_path / "bin.csv").write_bytes(b"time_s,force_N\n\x81\x8d\x90" + _csv_rows().encode())
    cases = {"bin.csv": "file", "bad.json": "file", "list.npz": "metadata", "obj.npy": "file",
             "attr.h5": "dt"}
    for name, field in cases.items():
        with pytest.raises(WaveformError) as err:
            io.read(tmp_path / name)
        assert err.value.field == field, (name, str(err.value))


def test_options_apply_only_where_they_fit(tmp_path):
    """sample_rate must agree with a file's own time axis; a 2-D NPY with a time column keeps
    its layout when sample_rate is given; calibration for data in N is an error; TDMS and JSON
    accept the common options; an unknown option is named with the allowed ones."""
    shots = _shots(2)
    npy = io.write(tmp_path / "s.npy", shots)
    back = io.read(npy, sample_rate=1 / DT)
    assert len(back) == 2 and back[0].n == shots[0].n
    with pytest.raises(WaveformError) as err:
        io.read(npy, sample_rate=1e6)
    assert err.value.field == "sample_rate"
    for ext in ("tdms", "json", "csv", "h5", "npz"):
        path = io.write(tmp_path / f"s.{ext}", shots)
        assert len(io.read(path, sample_rate=1 / DT, units="N")) == 2
        with pytest.raises(WaveformError) as err:
            io.read(path, calibration=100.0)
        assert err.value.field == "calibration", ext
    with pytest.raises(WaveformError) as err:
        io.read(tmp_path / "s.npz", sample_rte=1e6)
    assert err.value.field == "sample_rte" and "sample_rate" in err.value.allowed
    with pytest.raises(WaveformError) as err:
        io.read(tmp_path / "s.h5", chanel="x")
    assert err.value.field == "chanel" and "dataset" in err.value.allowed


def test_units_option_and_tdms_unit_names(tmp_path):
    """units= says what unlabelled data are in; a file's own units win and a contradiction is
    an error; TDMS 'Volts' / 'Newtons' map to V / N."""
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    x = pulse_train(400, DT, [(50e-6, 1.0, 15e-6)])
    np.save(tmp_path / "v.npy", x)
    (w,) = io.read(tmp_path / "v.npy", sample_rate=1 / DT, units="V", calibration=200.0)
    assert w.units == "V" and np.allclose(w.force, 200.0 * x)
    with pytest.raises(WaveformError) as err:
        io.read(tmp_path / "v.npy", sample_rate=1 / DT, units="V")
    assert err.value.field == "calibration"
    path = tmp_path / "u.tdms"
    with TdmsWriter(str(path)) as writer:
        props = {"wf_increment": DT, "wf_start_offset": 0.0}
        writer.write_segment([RootObject(), GroupObject("g"),
                              ChannelObject("g", "a", x, {**props, "unit_string": "Volts"}),
                              ChannelObject("g", "b", x, {**props, "unit_string": "Newtons"})])
    a, b = io.read(path, calibration=50.0)
    assert (a.units, a.calibration, b.units) == ("V", 50.0, "N")
    with pytest.raises(WaveformError) as err:
        io.read(path, channel="b", units="V")
    assert err.value.field == "units"


def test_identifiers_stay_text_and_numbers_stay_numbers(tmp_path):
    """`# plate_id: 007` and `# position: 1.50` keep their digits; sphere_diameter is a number;
    a non-numeric one is kept as given and to_dict (the service's shape) names it."""
    path = tmp_path / "id.csv"
    path.write_text("# plate_id: 007\n# position: 1.50\n# sphere_diameter: 0.00953\n"
                    "# synthetic: true\ntime_s,force_N\n" + _csv_rows())
    (w,) = io.read(path)
    assert w.metadata["plate_id"] == "007" and w.metadata["position"] == "1.50"
    assert w.metadata["sphere_diameter"] == pytest.approx(0.00953)
    assert w.metadata["synthetic"] is True
    path.write_text("# sphere_diameter: big\ntime_s,force_N\n" + _csv_rows())
    (w,) = io.read(path)
    assert w.metadata["sphere_diameter"] == "big"
    with pytest.raises(WaveformError) as err:
        w.to_dict()
    assert err.value.field == "metadata.sphere_diameter"


def test_csv_comments_and_headerless_time_column(tmp_path):
    """An explicit t0 beats `# t0:`; `# sample_rate:` serves a file without a time column; a
    header-less (time, force) table is one shot with that time axis, not two shots."""
    x = pulse_train(400, DT, [(50e-6, 100.0, 15e-6)])
    path = tmp_path / "c.csv"
    path.write_text("# sample_rate: 2e6\n# t0: 1e-3\nforce_N\n"
                    + "\n".join(f"{v:.9g}" for v in x) + "\n")
    (w,) = io.read(path)
    assert w.dt == pytest.approx(5e-7) and w.t0 == pytest.approx(1e-3)
    assert io.read(path, t0=5.0)[0].t0 == 5.0
    path.write_text(_csv_rows())
    (w,) = io.read(path)
    assert w.dt == pytest.approx(DT) and w.samples.max() > 50.0


def test_to_json_is_what_the_service_accepts(tmp_path):
    """read -> to_json -> POST /v1/measurements is a 201; the stored metadata keeps the
    identifiers as text and the extras; from_json reads the shape back."""
    from fastapi.testclient import TestClient

    from solitonde.instrument.service.app import build_app
    from solitonde.instrument.service.settings import Settings

    data = (Path(__file__).resolve().parents[2] / "data_samples" / "waveforms"
            / "synthetic_D9.53_t4.83_snr40.csv")
    shots = io.read(data)
    body = io.to_json(shots)
    meta = body["shots"][0]["metadata"]
    assert meta["position"] == "0.457" and meta["extra"]["source_file"] == data.name
    back = io.from_json(json.loads(json.dumps(body)))
    assert back[0].metadata["position"] == "0.457"
    assert back[0].metadata["snr_db"] == shots[0].metadata["snr_db"]
    settings = Settings(store_path=tmp_path / "store.sqlite", table_path=None)
    with TestClient(build_app(settings)) as client:
        r = client.post("/v1/measurements", json=body)
        assert r.status_code == 201, r.text
        stored = r.json()
        assert stored["position"] == "0.457" and stored["n_shots"] == len(shots)
        assert stored["shots"][0]["metadata"]["channel"] == "force_N"


def test_written_files_follow_the_umask_not_the_temporary_files_0600(tmp_path):
    import os

    old = os.umask(0o022)
    try:
        path = io.write(tmp_path / "w.csv", Waveform(0.0, DT, np.ones(64), "N"))
    finally:
        os.umask(old)
    assert path.stat().st_mode & 0o777 == 0o644
