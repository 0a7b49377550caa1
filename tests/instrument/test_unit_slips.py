"""Unit slips caught by the chain's physics (issue 27).

A solitary wave ties its width to its force and the sphere size (Nesterenko: it is about five
diameters long and travels at a speed that grows as F^(1/6)), so a recording whose force or time
axis is in other units than its file says cannot be the chain's. The traces come from the
independent SciPy solve of ``tests/support/independent_chain.py`` (D 9.53 mm on a 4.83 mm plate,
gravity on, 2 MHz, 40 dB), written as PicoScope and spreadsheet CSVs the way those programs write
them, in volts through a 20 N/V sensor.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy_chain import ChainTrace, solve
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app

CAL = 20.0  # N/V
RATE = 2e6


@pytest.fixture(scope="module")
def trace() -> tuple[np.ndarray, np.ndarray]:
    """Times (s) and the sensor in volts: the solve at 2 MHz with noise at 40 dB."""
    tr: ChainTrace = solve(9.53e-3, 4.83e-3, True, 0.9e-3, rate=RATE)
    rng = np.random.default_rng(7)
    sigma = tr.truth.incident_peak_N / 100.0
    volts = (tr.samples + rng.normal(0.0, sigma, tr.samples.size)) / CAL
    return tr.t0 + tr.dt * np.arange(tr.samples.size), volts


def _picoscope(path: Path, t_us: np.ndarray, values: np.ndarray, unit: str) -> Path:
    rows = "".join(f"{a:.5f},{b:.7f}\n" for a, b in zip(t_us, values, strict=True))
    path.write_text(f"Time,Channel A\n(us),({unit})\n\n{rows}")
    return path


def _analyze(*args: str):
    return CliRunner().invoke(build_app(), ["analyze", *args, "--json"])


def test_a_file_in_its_stated_units_is_accepted(tmp_path: Path, trace) -> None:
    """The control: volts labelled (V), the right calibration; with and without a sphere size."""
    t, v = trace
    path = _picoscope(tmp_path / "ok.csv", t * 1e6, v, "V")
    for extra in (["--sphere-diameter", "9.53e-3"], []):
        out = _analyze(str(path), "--calibration", str(CAL), *extra)
        assert out.exit_code == 0, out.output
        assert "implausible_units" not in out.stdout


def test_volts_labelled_millivolts_are_flagged(tmp_path: Path, trace) -> None:
    """A PicoScope CSV in volts whose unit row says (mV): the force reads 1000 times too small
    (34 mN), and a solitary wave that weak would be 3.2 times as wide. Exit 1, the shot not
    inverted, the message giving both widths and naming --calibration and the unit row."""
    t, v = trace
    path = _picoscope(tmp_path / "mv.csv", t * 1e6, v, "mV")
    out = _analyze(str(path), "--calibration", str(CAL), "--sphere-diameter", "9.53e-3",
                   "--invert")
    assert out.exit_code == 1, out.output
    text = out.output
    assert "implausible_units" in text and "--calibration" in text and "unit row" in text
    assert "us wide at half height" in text and "not inverted" in text


def test_milliseconds_labelled_microseconds_are_flagged(tmp_path: Path, trace) -> None:
    """A ``Time (us)`` column holding milliseconds: every duration reads 1000 times too short
    (TOF 0.5 us). Flagged with the sphere size stated, and without it (no chain of the table's
    sizes makes a pulse that short)."""
    t, v = trace
    rows = "".join(f"{a:.8f},{b * CAL:.6f}\n" for a, b in zip(t * 1e3, v, strict=True))
    path = tmp_path / "ms.csv"
    path.write_text("Time (us),Force (N)\n" + rows)
    for extra in (["--sphere-diameter", "9.53e-3"], []):
        out = _analyze(str(path), *extra)
        assert out.exit_code == 1, out.output
        assert "implausible_units" in out.output and "--units" in out.output


def test_a_calibration_off_by_ten_is_flagged(tmp_path: Path, trace) -> None:
    """200 N/V for a 20 N/V sensor: ten times the force, a width 1.47 times too long for it."""
    t, v = trace
    path = _picoscope(tmp_path / "cal.csv", t * 1e6, v, "V")
    out = _analyze(str(path), "--calibration", str(10 * CAL), "--sphere-diameter", "9.53e-3")
    assert out.exit_code == 1, out.output
    assert "implausible_units" in out.output


def test_the_service_keeps_an_implausible_shot_out_of_the_estimate(tmp_path: Path, trace) -> None:
    """Over REST the shot is stored with its flag (201), rejected from the aggregate with the
    reason, and the estimate says why it has none."""
    from fastapi.testclient import TestClient

    from solitonde.instrument.service.app import build_app
    from solitonde.instrument.service.settings import Settings
    from solitonde.instrument.tables.bundled import default_table

    t, v = trace
    shot = {"t0": float(t[0]), "dt": float(t[1] - t[0]), "samples": (v * 1e-3).tolist(),
            "units": "V", "calibration": CAL,
            "metadata": {"plate_id": "P", "position": "A", "sphere_diameter": 9.53e-3}}
    settings = Settings(store_path=tmp_path / "s.sqlite", table_paths=(default_table(),))
    with TestClient(build_app(settings)) as client:
        r = client.post("/v1/measurements", json={"shots": [shot]})
    assert r.status_code == 201, r.text
    body = r.json()
    assert "implausible_units" in body["shots"][0]["features"]["flags"]
    (agg,) = body["aggregates"]
    assert agg["rejected"][0]["reason"].startswith("implausible_units")
    assert body["estimate"] is None and "implausible_units" in body["estimate_reason"]
