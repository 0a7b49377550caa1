"""Benchmarks: what the plate-response store saves a table build, on the tutorial's plate and
on a plate of another kind.

Run with ``.venv/bin/python -m pytest -m bench -s tests/instrument/bench_table_build.py``. The
baseline is the elastic sweep of the same run, warm (the kernels compiled by a small build
first) and with an empty store; printed against it, each figure's target (not asserted):

- the three dissipation layers of the bundled tables, together, at most 1.5x (their plate
  responses come from the store: only the chain runs);
- the same table built again (a rebuild after an extractor change, another id) at most 0.35x.

Every build runs on the usable cores, as ``table build`` does.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import pytest

from solitonde.instrument.parallel import default_workers, local_cluster
from solitonde.instrument.tables.dissipation import damped_scene
from solitonde.instrument.tables.sweep import Sweep
from solitonde.instrument.tables.table_build import build_table
from solitonde.model.scene import load_scene_file

pytestmark = pytest.mark.bench

LAYERS_S = (7e-8, 1.2e-7, 2e-7)
"""The bundled tables' dissipation layers."""

TUTORIAL_PLATE = """\
chain: {diameter: 9.53e-3, material: steel_440c, n_particles: 20, sensor_index: 7}
striker: {drop_height: 5.0e-3}
plate: {thickness: 3.0e-3, size: [0.914, 0.914], material: al_7075_t6,
        supports: opposite_edges, distance_to_support: 0.457}
effects: {gravity: true}
"""

OTHER_PLATE = """\
chain: {diameter: 19.05e-3, material: steel_440c, n_particles: 20, sensor_index: 7}
striker: {drop_height: 5.0e-3}
plate: {thickness: 6.0e-3, size: [0.6, 0.6], material: steel_structural,
        supports: opposite_edges, distance_to_support: 0.3}
"""


def _sweep(tmp_path: Path, text: str, thicknesses: list[float], distances: list[float]) -> Sweep:
    scene = tmp_path / "plate.yaml"
    scene.write_text(text)
    base = load_scene_file(scene)
    return Sweep([base["chain"]["diameter"]], thicknesses, distances, scene=base)


def _timed(sweep: Sweep, out: Path, store: Path, scheduler: str | None = None,
           slopes: bool = True) -> float:
    start = time.perf_counter()
    report = build_table(sweep, out, workers=default_workers(), scheduler=scheduler,
                         responses=store, slopes=slopes)
    assert report.complete
    return time.perf_counter() - start


def _layers(sweep: Sweep, stem: Path, store: Path) -> float:
    """The three layers as ``table build --dissipation-layer`` runs them: on one local cluster
    (its start counted)."""
    start = time.perf_counter()
    with local_cluster(default_workers()) as cluster:
        for tau in LAYERS_S:
            _timed(dataclasses.replace(sweep, scene=damped_scene(sweep.scene, tau)),
                   stem.with_name(f"{stem.name}-{tau:g}.h5"), store, cluster.scheduler_address,
                   slopes=False)  # as simulate_layer builds them
    return time.perf_counter() - start


def _ratios(name: str, sweep: Sweep, tmp_path: Path) -> None:
    store = tmp_path / f"{name}-store"
    small = Sweep(sweep.diameters_m, sweep.thicknesses_m[:1], [0.0, sweep.distances_m[-1]],
                  scene=sweep.scene)
    _timed(small, tmp_path / f"{name}-warm.h5", tmp_path / "warm-store")  # compile, not timed
    elastic = _timed(sweep, tmp_path / f"{name}.h5", store)
    layers = _layers(sweep, tmp_path / name, store)
    rebuild = _timed(sweep, tmp_path / f"{name}-again.h5", store)
    n = len(sweep.thicknesses_m) * len(sweep.distances_m) * len(sweep.diameters_m)
    print(f"\n[bench] {name} ({n} points, {default_workers()} workers): elastic sweep "
          f"{elastic:.1f} s (empty store); three layers {layers:.1f} s, ratio "
          f"{layers / elastic:.2f} (target <= 1.5); rebuild {rebuild:.1f} s, ratio "
          f"{rebuild / elastic:.2f} (target <= 0.35)")


def test_store_on_the_tutorial_plate(tmp_path: Path) -> None:
    from solitonde.instrument.tables.sweep import default_distances_m

    thicknesses = [2e-3 * (5e-3 / 2e-3) ** (k / 5) for k in range(6)]  # geom:2e-3:5e-3:6
    _ratios("tutorial plate", _sweep(tmp_path, TUTORIAL_PLATE, thicknesses,
                                     default_distances_m()), tmp_path)


def test_store_on_a_thick_steel_plate(tmp_path: Path) -> None:
    _ratios("6 mm steel, 19.05 mm spheres", _sweep(
        tmp_path, OTHER_PLATE, [4e-3, 5e-3, 6e-3, 7e-3, 8e-3],
        [0.0, 0.005, 0.01, 0.02, 0.04, 0.08, 0.15, 0.3]), tmp_path)
