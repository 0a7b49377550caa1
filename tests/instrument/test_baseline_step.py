"""A level that jumps between the pulses is refused, not read as a weaker reflection.

Traces of scipy's DOP853 solve of the chain on Zener's dashpot (tests/support/independent_chain.py,
no model code): a 4.0 mm structural-steel plate, D 9.53 mm, gravity on, five shots at 40 dB,
measured as ``analyze`` measures a shot of a stated size (the drift fitted on the pre-trigger and
the gap against the chain's relaxation). A step of the sensor's level by 2 N (6 % of the 33.7 N
incident) 400 us after the impact, between the incident (137 us) and the reflection (630 us),
read ARR 0.63 for 0.67 and "3.60 mm, 95 % 1.62-3.88, constrained", exit 0: the quadratic drift
bent through the step. Its fit now misses its own stretches by 1.0 % of the incident (a smooth
drift, or any striker's relaxation, by under 0.04 %): ``unsteady_baseline``, rejected.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from independent_chain import recorded_for
from recordings import STEEL, analyze_inverted, edit_shots, steel_shots

from solitonde.instrument.inference import chain_geometry, shot_measure
from solitonde.instrument.tables.measured import detect_options
from solitonde.signal import io as signal_io
from solitonde.signal.batch import extract_batch
from solitonde.signal.features import extract, from_detection
from solitonde.signal.pulses import detect


def _recording(folder: Path, step_n: float, drift: float = 0.0) -> Path:
    """Five noisy shots, the level stepping by ``step_n`` at 400 us and drifting by a parabola
    of ``drift`` times the incident over the record."""
    t, force = recorded_for(STEEL, 4.0e-3, 1.0e-3)
    path = steel_shots(folder / f"step_{step_n:g}_{drift:g}.csv", t, force)
    peak = float(force.max() - force[0])
    return edit_shots(path, lambda time, _, v: v + (step_n if time > 4.0e-4 else 0.0)
                      + drift * peak * ((time + 2.5e-4) / 1.25e-3) ** 2)


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("steps")


def test_a_step_between_the_pulses_is_refused(folder: Path) -> None:
    path = _recording(folder, 2.0)
    features = [shot_measure.measure_shot(w, 9.53e-3) for w in signal_io.read(path)]
    assert all("unsteady_baseline" in f.flags for f in features)
    code, out = analyze_inverted(path)
    assert code == 1
    assert out["estimates"][0]["estimate"] is None
    assert "every shot is unsteady_baseline" in out["errors"][0]["error"]


@pytest.mark.parametrize(("step_n", "drift"), [(0.0, 0.0), (0.0, 0.05), (0.5, 0.0)])
def test_a_smooth_drift_or_a_small_step_is_read(folder: Path, step_n: float, drift: float
                                                ) -> None:
    """No step, a 5 % parabola, and a 0.5 N step (1.5 % of the incident, which moves the ARR
    by 1.7 %): not flagged, and the answer holds 4.0 mm."""
    code, out = analyze_inverted(_recording(folder, step_n, drift))
    assert code == 0, out["errors"]
    assert all("unsteady_baseline" not in s["flags"] for s in out["shots"])
    low, high = out["estimates"][0]["estimate"]["thickness_m"]["ci95"]
    assert low <= 4.0e-3 <= high


def test_the_batch_path_flags_the_same_shots(folder: Path) -> None:
    """extract_batch with the chain's options and relaxation flags what extract does."""
    waves = signal_io.read(_recording(folder, 2.0)) + signal_io.read(_recording(folder, 0.0))
    scene = chain_geometry.chain_scene(9.53e-3)
    first = extract(waves[0], **detect_options(scene))
    relax = chain_geometry.relaxation(scene, first.incident_peak_N, waves[0].dt)
    options = {**detect_options(scene), "relaxation_N": relax}
    expected = [extract(w, **options) for w in waves]
    table = extract_batch(np.stack([w.force for w in waves]), waves[0].dt, t0=waves[0].t0,
                          **options)
    assert table.to_features() == expected
    assert [("unsteady_baseline" in f.flags) for f in expected] == [True] * 5 + [False] * 5
    assert [from_detection(detect(w, **options)) for w in waves] == expected
