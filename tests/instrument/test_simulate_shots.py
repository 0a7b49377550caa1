"""`solitonde simulate --shots N --snr-db S`: N noisy shots of one trace, validate's noise model."""

from __future__ import annotations

import json

import numpy as np
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app
from solitonde.signal import io as signal_io


def _run(*args: object):
    return CliRunner().invoke(build_app(), ["simulate", *map(str, args)])


def test_shots_are_columns_with_the_stated_noise_and_the_seed_repeats_them(tmp_path):
    """Five shots read back as five; the noise sigma is the incident peak over 10^(S/20); the
    same seed gives the same file, another seed other shots."""
    clean_csv, a, b, c = (tmp_path / n for n in ("clean.csv", "a.csv", "b.csv", "c.csv"))
    assert _run("--out", clean_csv).exit_code == 0
    run = _run("--shots", 5, "--snr-db", 30, "--seed", 7, "--out", a, "--json")
    assert run.exit_code == 0, run.output
    data = json.loads(run.stdout)
    assert [s["shot"] for s in data["shots"]] == [0, 1, 2, 3, 4]
    assert data["acquisition"]["snr_db"] == 30.0 and data["acquisition"]["seed"] == 7
    assert _run("--shots", 5, "--snr-db", 30, "--seed", 7, "--out", b).exit_code == 0
    assert _run("--shots", 5, "--snr-db", 30, "--seed", 8, "--out", c).exit_code == 0
    assert a.read_bytes() == b.read_bytes() and a.read_bytes() != c.read_bytes()

    clean = signal_io.read(clean_csv)[0]
    shots = signal_io.read(a)
    assert len(shots) == 5 and all(s.n == clean.n for s in shots)
    reference = data["acquisition"]["reference_N"]
    residual = np.concatenate([s.samples - clean.samples for s in shots])
    sigma = reference / 10 ** (30 / 20)
    # 5 x ~2700 samples: the sample sigma is within 3 % of the true one (9 sigma of its error)
    assert abs(residual.std() / sigma - 1) < 0.03, residual.std() / sigma
    # every shot measured, TOF spread far below the TOF itself, mean ARR near the clean one
    tof = np.array([s["tof_s"] for s in data["shots"]])
    arr = np.array([s["arr"] for s in data["shots"]])
    assert np.isfinite(tof).all() and tof.std() < 0.01 * data["tof_s"]
    assert abs(arr.mean() - data["arr"]) < 5 * arr.std(ddof=1) / np.sqrt(5) + 1e-3


def test_drift_moves_the_baseline_by_the_fraction_asked(tmp_path):
    clean_csv, drifted = tmp_path / "clean.csv", tmp_path / "drift.csv"
    assert _run("--out", clean_csv).exit_code == 0
    run = _run("--shots", 2, "--snr-db", 120, "--drift", 0.1, "--out", drifted)
    assert run.exit_code == 0, run.output
    clean = signal_io.read(clean_csv)[0]
    reference = signal_io.read(drifted)[0].metadata["acquisition"]["reference_N"]
    for shot in signal_io.read(drifted):
        offset = shot.samples - clean.samples
        # ramp of +-0.1 ref plus a quarter sine of +-0.05 ref: the end sits 0.05 or 0.15 ref off
        assert min(abs(abs(offset[-1]) / reference - v) for v in (0.05, 0.15)) < 1e-3
        assert abs(offset[0]) < 1e-3 * reference


def test_shots_need_a_noise_level():
    run = _run("--shots", 3)
    assert run.exit_code == 2 and "--snr-db: needed with --shots" in run.output
