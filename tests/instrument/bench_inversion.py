"""Benchmarks: one inversion, table load, table build rate (serial and on a local Dask cluster).

Run with ``.venv/bin/python -m pytest -m bench -s tests/instrument/bench_inversion.py``. Each figure
is printed with a baseline measured in the same run: the inversion against one exp() over its fine
grid (the least any grid posterior costs) and against itself with the material's spread off, the
load against reading the raw datasets with h5py, the cluster build rate against the serial one.
Targets (printed, not asserted): inversion <= 2 ms, load <= 0.5 s. The inversion is also timed
with its likelihood pass on one thread (a Dask worker's limit), and while every core is kept
busy by another process (as by a table build beside the service), against the same inversion on
the idle machine.
"""

from __future__ import annotations

import multiprocessing
import os
import statistics
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from solitonde.instrument import parallel
from solitonde.instrument.cli.cmd_table import DEFAULT_TABLE_PATH
from solitonde.instrument.inference import grid_threads
from solitonde.instrument.inference.fine_grid import fine_grid
from solitonde.instrument.inference.inversion import invert
from solitonde.instrument.inference.inversion_inputs import FeatureSummary
from solitonde.instrument.parallel import default_workers
from solitonde.instrument.tables.table import ModelTable
from solitonde.instrument.tables.table_build import Sweep, build_table

pytestmark = pytest.mark.bench

FAST = {"sem": {"elements": [6, 6, 1], "order": [2, 2, 2]}}


def _sweep() -> Sweep:
    return Sweep([4.76e-3, 9.53e-3, 19.05e-3], [2.5e-3, 3.5e-3, 5e-3], [0.0, 0.02, 0.05, 0.3],
                 scene=FAST)


@pytest.fixture(scope="module")
def table_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    if DEFAULT_TABLE_PATH.is_file():
        return DEFAULT_TABLE_PATH
    out = tmp_path_factory.mktemp("bench") / "t.h5"
    build_table(_sweep(), out, workers=1)
    return out


def _best(fn, repeat: int) -> float:  # type: ignore[no-untyped-def]
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def _spin(seconds: float) -> None:
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        pass


def test_bench_inversion_and_load(table_path: Path) -> None:
    """One inversion (three sphere sizes) and one table load, with same-run baselines."""
    load = _best(lambda: ModelTable.load(table_path), 5)

    def raw() -> None:
        with h5py.File(table_path) as fh:
            for name in ("tof_s", "arr"):
                fh["features"][name][...]
            fh["status"][...]

    raw_t = _best(raw, 5)
    table = ModelTable.load(table_path)
    warm = time.perf_counter()
    for i in range(table.axes["diameter_m"].size):
        fine_grid(table, i)
    warm = time.perf_counter() - warm
    i_l = table.axes["distance_m"].size - 1
    # the middle-most thickness where every sphere size has a reflection (all sizes invert)
    ok = [i for i in range(table.axes["thickness_m"].size) if (table.status[:, i, i_l] == 0).all()]
    i_t = min(ok, key=lambda i: abs(i - table.axes["thickness_m"].size // 2)) if ok else 0
    inputs = []
    for i_d, d in enumerate(table.axes["diameter_m"]):
        tof, arr = table.features["tof_s"][i_d, i_t, i_l], table.features["arr"][i_d, i_t, i_l]
        if np.isfinite(tof) and np.isfinite(arr):
            inputs.append(FeatureSummary(float(d), float(tof), float(arr), 1e-6, 0.01, 5))
    invert(table, inputs)
    one = _best(lambda: invert(table, inputs), 300)
    grid = fine_grid(table, 0).tof_s
    exp_t = _best(lambda: np.exp(-grid), 300)
    print(f"\n[bench] table {table_path.name} shape {list(table.shape)}")
    print(f"[bench] load: {load * 1e3:.1f} ms (target <= 500 ms); raw h5py read "
          f"{raw_t * 1e3:.1f} ms, ratio {load / raw_t:.1f}; fine grids warmed once in "
          f"{warm * 1e3:.1f} ms")
    exact = dict.fromkeys(("youngs_modulus_rel_sd", "poisson_ratio_sd", "density_rel_sd"), 0.0)
    no_spread = _best(lambda: invert(table, inputs, material_spread=exact), 300)
    bands = grid_threads.threads()
    parallel.limit_threads(1)
    try:
        single = _best(lambda: invert(table, inputs), 300)
    finally:
        parallel.limit_threads(None)
    print(f"[bench] one inversion ({len(inputs)} sizes, grid {grid.shape}): "
          f"{one * 1e3:.3f} ms (target <= 2 ms); one exp() over the grid {exp_t * 1e3:.3f} ms, "
          f"ratio {one / exp_t:.1f}")
    print(f"[bench] the likelihood's pass on {bands} threads: {one * 1e3:.3f} ms; "
          f"on one thread {single * 1e3:.3f} ms, ratio {single / one:.2f}")
    print(f"[bench] the material spread's term: {one * 1e3:.3f} ms with it, "
          f"{no_spread * 1e3:.3f} ms with the properties exact, ratio {one / no_spread:.2f}")
    spinners = [multiprocessing.get_context("spawn").Process(target=_spin, args=(4.0,))
                for _ in range(os.cpu_count() or 1)]
    for p in spinners:
        p.start()
    time.sleep(0.5)  # the spinners running
    loaded = _best(lambda: invert(table, inputs), 100)
    for p in spinners:
        p.join()
    print(f"[bench] one inversion with every core busy ({len(spinners)} spinning processes): "
          f"{loaded * 1e3:.3f} ms, against {one * 1e3:.3f} ms idle: ratio {loaded / one:.2f}")


def test_bench_build_rate(tmp_path: Path) -> None:
    """Scenes per second for a small sweep (coarse plate mesh): serial, then on a local Dask
    cluster (one process per core, started beforehand so its start-up is not counted)."""
    from dask.distributed import LocalCluster

    from solitonde.instrument.parallel import WORKER_ENV

    sweep = _sweep()
    build_table(Sweep([4.76e-3], [3e-3], [0.01], scene=FAST), tmp_path / "warm.h5", workers=1)
    # each build computes its own plate responses (no store), so the ratio is the executor's
    serial = build_table(sweep, tmp_path / "serial.h5", workers=1, responses=False)
    n = default_workers()
    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                           env=dict(WORKER_ENV), dashboard_address=":0")
    try:
        # warm the workers (imports, numba cache) outside the timed build
        build_table(Sweep([4.76e-3], [3e-3], [0.01, 0.02], scene=FAST), tmp_path / "w2.h5",
                    scheduler=cluster.scheduler_address)
        parallel = build_table(sweep, tmp_path / "dask.h5", scheduler=cluster.scheduler_address,
                               responses=False)
    finally:
        cluster.close()
    print(f"\n[bench] build {serial.points_written} scenes on {serial.plates_written} plates: "
          f"serial {serial.scenes_per_s:.2f} scenes/s; local cluster ({n} processes) "
          f"{parallel.scenes_per_s:.2f} scenes/s; "
          f"ratio {parallel.scenes_per_s / serial.scenes_per_s:.2f}")
