"""The paper's 3 x 3 grid on the infinite plate: simulated ARR and TOF beside Zener's theory.

Run with ``-s`` to see the table (paper Fig. 5 and 6). ARR and TOF come from the sampled sensor
trace through the signal extractor, with the model's own step-resolution peaks beside them.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from solitonde.model.batch import scene_grid, simulate_many
from solitonde.model.zener import predict
from solitonde.signal.errors import WaveformError
from solitonde.signal.features import extract
from solitonde.signal.waveform import Waveform

DIAMETERS = [4.76e-3, 9.53e-3, 19.05e-3]
THICKNESSES = [2.29e-3, 3.18e-3, 4.83e-3]
FIGURES = Path(__file__).resolve().parents[2] / "docs" / "figures" / "theory-grid.json"


def _features(result):
    try:
        f = extract(Waveform(result.t0, result.dt, result.samples, "N"))
    except WaveformError:
        return math.nan, math.nan
    return (math.nan if f.arr is None else f.arr), (math.nan if f.tof_s is None else f.tof_s)


def _rows() -> list[tuple[float, ...]]:
    """Per scene, sorted by D/t: (D/t, D, t, lambda, e, ARR theory, ARR of the model's peaks, ARR
    read by the extractor, TOF theory, TOF of the model's peaks, TOF read by the extractor)."""
    scenes = scene_grid({"effects": {"plate_model": "infinite"}},
                        {"chain.diameter": DIAMETERS, "plate.thickness": THICKNESSES})
    results = simulate_many(scenes, workers=2)
    rows = []
    for scene, r in zip(scenes, results, strict=True):
        p = predict(scene)
        arr_sig, tof_sig = _features(r)
        rows.append((scene.d_over_t, scene.chain.diameter, scene.plate.thickness, p.lambda_, p.e,
                     p.arr, r.truth["arr"], arr_sig, p.tof_s, r.truth["tof_s"], tof_sig))
    rows.sort()
    return rows


def test_grid_against_theory():
    """Simulated ARR falls with D/t like e^(6/5); TOF follows Eq. 15 where the reflection exists."""
    rows = _rows()
    print("\n D/t   D mm   t mm  lambda     e   ARR th  ARR sim ARR sig  TOF th ms TOF sim TOF sig"
          "  dTOF %")
    for row in rows:
        dt_, d, t, lam, e, arr_th, arr_sim, arr_sig, tof_th, tof_sim, tof_sig = row
        print(f"{dt_:5.2f} {d * 1e3:6.2f} {t * 1e3:6.2f} {lam:6.3f} {e:6.3f} {arr_th:7.4f} "
              f"{arr_sim:8.4f} {arr_sig:7.4f} {tof_th * 1e3:9.4f} {tof_sim * 1e3:7.4f} "
              f"{tof_sig * 1e3:7.4f} {100 * (tof_sim / tof_th - 1):7.1f}")
    with_reflection = [row for row in rows if row[4] > 0.1]
    arr_sim = np.array([row[6] for row in with_reflection])
    # ARR falls with D/t in the simulation as in the theory (Fig. 5) ...
    assert np.all(np.diff(arr_sim) < 0.0)
    # ... lies below e^(6/5) (the wave's last particle is pushed on by the ones behind it) ...
    assert all(row[6] < row[5] for row in with_reflection)
    # ... and TOF agrees with Eq. 15 to 15 % where a reflected pulse exists.
    for row in with_reflection:
        assert abs(row[9] / row[8] - 1) < 0.15


@pytest.mark.slow
def test_the_docs_table_of_the_grid() -> None:
    """docs/explanation/physics.md's table: docs/figures/theory-grid.json."""
    keys = ("d_over_t", "diameter_m", "thickness_m", "lambda", "e", "arr_theory", "arr_model",
            "arr_read", "tof_theory_s", "tof_model_s", "tof_read_s")
    rows = [{k: (None if isinstance(v, float) and math.isnan(v) else v)
             for k, v in zip(keys, row, strict=True)} for row in _rows()]
    FIGURES.write_text(json.dumps({
        "command": "pytest -m slow tests/model/test_chain_theory_grid.py --timeout 0",
        "figures": {"rows": rows}}, indent=1) + "\n")
