"""A recording of a chain unlike the stated one is refused, not read as a thin plate.

Traces of scipy's DOP853 solve of the chain on Zener's dashpot (tests/support/independent_chain.py,
no model code), a 4.0 mm structural-steel plate, D 9.53 mm, gravity on, five shots at 40 dB,
analysed as the paper's chain (20 spheres, the sensor 7th from the top) against the bundled steel
table. With the sensor 10th, the reflection comes back 384 us after the incident, before the
stated chain's travel gate opens (0.75 of its 541 us round trip): it was taken for the incident's
train, the gate held nothing, and the shots' "no reflection" bounded the plate at "at most 2.41
mm", exit 0. A train pulse that strong (0.67 of the incident) follows within a fifth of the trip;
one arriving between half the trip and the gate is flagged ``early_reflection`` and the shot is
rejected. The other chains unlike the table's (the sensor 4th, 25 spheres, a 20 mm drop) were and
are flagged ``inconsistent``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from independent_chain import recorded_for, sensor_trace
from recordings import STEEL, analyze_inverted, steel_shots

from solitonde.instrument.inference import chain_geometry
from solitonde.instrument.tables.measured import detect_options
from solitonde.signal import io as signal_io
from solitonde.signal.batch import extract_batch
from solitonde.signal.features import extract


def _recording(folder: Path, sensor_index: int) -> Path:
    if sensor_index == 7:  # the paper's chain: the solve other tests share
        t, force = recorded_for(STEEL, 4.0e-3, 8.0e-4)
    else:
        t, force = sensor_trace(STEEL, 4.0e-3, duration_s=8.0e-4, sensor_index=sensor_index)
    name = f"sensor{sensor_index}"
    return steel_shots(folder / f"{name}.csv", t, force)


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("chains")


def test_a_sensor_lower_than_stated_is_refused(folder: Path) -> None:
    path = _recording(folder, sensor_index=10)
    options = detect_options(chain_geometry.chain_scene(9.53e-3))
    waves = signal_io.read(path)
    features = [extract(w, **options) for w in waves]
    assert all(f.tof_s is None and "early_reflection" in f.flags for f in features)
    # the batch path flags the same shots
    table = extract_batch(np.stack([w.force for w in waves]), waves[0].dt, t0=waves[0].t0,
                          **options)
    assert [table.flag_names(i) for i in range(len(waves))] == [f.flags for f in features]
    code, out = analyze_inverted(path)
    assert code == 1
    assert out["estimates"][0]["estimate"] is None
    assert "every shot is early_reflection" in out["errors"][0]["error"]
    assert "table build --scene" in out["errors"][0]["error"]


def test_the_stated_chain_is_not_flagged(folder: Path) -> None:
    """The same plate under the stated chain: the reflection where the gate puts it, no flag,
    4.0 mm within reach."""
    code, out = analyze_inverted(_recording(folder, sensor_index=7))
    assert code == 0, out["errors"]
    assert all(s["flags"] == [] for s in out["shots"])
    est = out["estimates"][0]["estimate"]
    assert abs(est["thickness_m"]["median"] - 4.0e-3) < 0.1e-3
