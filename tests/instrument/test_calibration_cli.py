"""`solitonde calibrate` writes only files `invert --calibration` reads back; a bad calibration
file or output path is one `error: <field>: ...` line, never a traceback or a stray temp file."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app
from solitonde.instrument.inference.calibration import Calibration, CalibrationError

TABLE = Path(__file__).resolve().parents[2] / "data_samples" / "default_table.h5"
REFERENCE = ["--thickness", "0.003312", "--distance", "0.05", "--diameter", "0.00953",
             "--tof", "5.6e-4", "--table", str(TABLE)]
INVERT = ["invert", "--table", str(TABLE), "--diameter", "0.00953", "--tof", "5.5e-4",
          "--arr", "0.3"]


def _run(*args: str):
    return CliRunner().invoke(build_app(), list(args))


def test_calibrate_then_invert_reads_it_back(tmp_path: Path) -> None:
    out = tmp_path / "cal.json"
    res = _run("calibrate", *REFERENCE, "--arr", "0.3", "--out", str(out))
    assert res.exit_code == 0, res.output
    res = _run(*INVERT, "--calibration", str(out))
    assert res.exit_code == 0, res.output
    assert [p.name for p in tmp_path.iterdir()] == ["cal.json"]


@pytest.mark.parametrize("arr", ["0", "0.0"])
def test_zero_reference_arr_is_refused_naming_arr(tmp_path: Path, arr: str) -> None:
    """ARR 0 gives a factor 0, which the loader (rightly) refuses: calibrate must not write it."""
    out = tmp_path / "cal.json"
    res = _run("calibrate", *REFERENCE, "--arr", arr, "--out", str(out))
    assert res.exit_code == 2
    assert res.output.startswith("error: arr:")
    assert "Traceback" not in res.output
    assert not out.exists()


def test_out_a_directory_is_a_clean_error_leaving_no_temp_file(tmp_path: Path) -> None:
    folder = tmp_path / "here"
    folder.mkdir()
    res = _run("calibrate", *REFERENCE, "--arr", "0.3", "--out", str(folder))
    assert res.exit_code == 2
    assert res.output.startswith("error: --out:") and "directory" in res.output
    assert list(tmp_path.iterdir()) == [folder] and list(folder.iterdir()) == []


def test_out_below_a_file_is_a_clean_error(tmp_path: Path) -> None:
    blocker = tmp_path / "afile"
    blocker.write_text("")
    res = _run("calibrate", *REFERENCE, "--arr", "0.3", "--out", str(blocker / "cal.json"))
    assert res.exit_code == 2
    assert res.output.startswith("error: --out:") and "not a folder" in res.output
    assert [p.name for p in tmp_path.iterdir()] == ["afile"]


def test_save_removes_its_temp_file_when_the_rename_fails(tmp_path: Path,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """A directory appearing at the target after the check (os.replace then fails): the
    temporary file is removed and the error names the path."""
    from solitonde.signal import atomic  # the one atomic write, which calibrations use

    def replace(src: Path, dst: Path) -> None:
        raise IsADirectoryError(21, "Is a directory")

    monkeypatch.setattr(atomic.os, "replace", replace)
    with pytest.raises(CalibrationError) as info:
        Calibration().save(tmp_path / "cal.json")
    assert info.value.field == "path" and "Is a directory" in str(info.value)
    assert list(tmp_path.iterdir()) == []


BAD_FILES = [
    ('{"per_diameter":[{"diameter_m":0.00953,"arr_factor":0.8,"note":"plate A"}]}',
     "per_diameter[0].note"),
    ('{"per_diameter":[{"diameter_m":0.00953,"arr_factor":0.8,"arr_factor_std":NaN}]}',
     "per_diameter[0].arr_factor_std"),
    ('{"per_diameter":[{"diameter_m":0.00953,"arr_factor":0.8,"tof_offset_std_s":-1e-6}]}',
     "per_diameter[0].tof_offset_std_s"),
    ('{"per_diameter":[{"diameter_m":0.00953,"arr_factor":0.8,"arr_factor_std":"big"}]}',
     "per_diameter[0].arr_factor_std"),
    ('{"per_diameter":[{"diameter_m":0.00953,"arr_factor":0.8,"n_references":1.5}]}',
     "per_diameter[0].n_references"),
    ('{"per_diameter":[{"diameter_m":0.00953},{"diameter_m":0.009531}]}',
     "per_diameter[1].diameter_m"),
    ('{"per_diameter": 5}', "per_diameter"),
    ('{"arr_factor": 0.0}', "arr_factor"),
    ("[1]", "calibration"),
]


@pytest.mark.parametrize(("text", "field"), BAD_FILES, ids=[b[1] + f":{i}"
                                                            for i, b in enumerate(BAD_FILES)])
def test_bad_calibration_file_names_the_field(tmp_path: Path, text: str, field: str) -> None:
    path = tmp_path / "cal.json"
    path.write_text(text)
    with pytest.raises(CalibrationError) as info:
        Calibration.load(path)
    assert info.value.field == field
    res = _run(*INVERT, "--calibration", str(path))
    assert res.exit_code == 2, res.output
    assert res.output.startswith(f"error: {field}:")


def test_every_key_calibrate_writes_is_read_back(tmp_path: Path) -> None:
    out = tmp_path / "cal.json"
    assert _run("calibrate", *REFERENCE, "--arr", "0.3", "--out", str(out)).exit_code == 0
    written = json.loads(out.read_text())["per_diameter"][0]
    back = Calibration.load(out).to_dict()["per_diameter"][0]
    assert back == written


SAMPLE = TABLE.parent / "waveforms" / "synthetic_D9.53_t4.83_snr40.csv"


def test_calibrate_from_waveform_files_fits_and_writes(tmp_path: Path) -> None:
    """The files path analyses the shots itself (it crashed with a TypeError on every file)."""
    out = tmp_path / "cal.json"
    res = _run("calibrate", str(SAMPLE), "--thickness", "4.83e-3", "--distance", "0.457",
               "--table", str(TABLE), "--out", str(out))
    assert res.exit_code == 0, res.output
    cal = Calibration.load(out)
    (entry,) = cal.to_dict()["per_diameter"]
    assert entry["diameter_m"] == pytest.approx(9.53e-3)
    assert entry["n_references"] == 1
    assert cal.to_dict()["reference"]["references"][0]["n_shots"] == 2


def test_calibrate_from_an_unreadable_file_is_one_error_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"not hdf5 at all")
    res = _run("calibrate", str(bad), "--thickness", "4.83e-3", "--distance", "0.457",
               "--diameter", "0.00953", "--table", str(TABLE), "--out", str(tmp_path / "c.json"))
    assert res.exit_code == 2
    assert res.exception is None or isinstance(res.exception, SystemExit)
    assert "error: files: " in res.output and "bad.h5" in res.output
    assert not (tmp_path / "c.json").exists()
