"""Benchmarks of the spectral-element plate (run with ``pytest -m bench -s
tests/model/bench_sem.py``).

Each prints its figure, the issue's target and a ratio against a baseline timed in the same run;
nothing here asserts a time. Compilation is kept out of the figures by a warm-up run.
"""

from __future__ import annotations

import os
import time
from functools import partial

import numpy as np
import pytest

from solitonde.instrument.tables.sweep import default_sweep
from solitonde.model import greens
from solitonde.model.mindlin_kernels import _mindlin_any
from solitonde.model.scene import load_scene
from solitonde.model.sem import single_threaded_blas
from solitonde.model.sem_kernels import run_plate_load, stiffness_product
from solitonde.model.simulate import simulate
from solitonde.model.tiers.meshed import plate_for

pytestmark = pytest.mark.bench

PAPER = ["sem.elements=[16,16,1]", "sem.order=[4,4,2]", "sem.symmetry=true"]
#: The meshes timed: the paper's model (single-node force, uniform 16 x 16 x 1) and the default
#: (same nominal mesh, contact patch r_c = t resolved by local refinement).
PRESETS = {"paper": [*PAPER, "sem.preset=paper"], "resolved": [*PAPER, "sem.preset=resolved"]}


def _timed(fn, repeat: int = 1):
    best, out = float("inf"), None
    for _ in range(repeat):
        start = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - start)
    return best, out


@pytest.mark.parametrize("preset", ["paper", "resolved"])
def test_bench_stiffness_vs_csr(preset: str) -> None:
    """K u matrix-free (sum factorisation) vs assembled CSR, full plate."""
    scene = load_scene(None, [*PRESETS[preset], "sem.symmetry=false"])
    plate = plate_for(scene)
    k = plate.stiffness_csr()
    u = np.random.default_rng(0).standard_normal(plate.n_dofs)
    out = np.empty_like(u)
    with single_threaded_blas():
        plate.apply_stiffness(u, out)
        t_mf, _ = _timed(lambda: [plate.apply_stiffness(u, out) for _ in range(50)], 3)
    t_csr, ref = _timed(lambda: [k @ u for _ in range(50)], 3)
    assert np.allclose(out, ref[-1], atol=1e-12 * np.abs(ref[-1]).max())
    print(f"\n[bench] stiffness, {preset} mesh full plate ({plate.n_dofs} dofs, "
          f"{len(plate.mesh.shapes[0])} element shapes, {k.nnz:,} nonzeros): "
          f"matrix-free {t_mf / 50 * 1e3:.3f} ms, CSR {t_csr / 50 * 1e3:.3f} ms, "
          f"ratio {t_csr / t_mf:.1f}x (target >= 10x)")


def test_bench_green_function_and_runs() -> None:
    """Paper mesh (half model), paper preset and resolved patch: coupled sem run, one Green's
    function, one greens chain run; the resolved one against the paper's in the same run."""
    figures = {}
    for preset, overrides in PRESETS.items():
        scene = load_scene(None, [*overrides, "effects.plate_model=sem"])
        simulate(scene.with_overrides(["output.duration=2e-5"]))  # compile, build the plate
        t_sem, sem = _timed(lambda scene=scene: simulate(scene))
        d = sem.diagnostics
        g_scene = scene.with_overrides(["effects.plate_model=greens"])
        run_greens = partial(simulate, g_scene, greens_cache=greens.MemoryCache())
        _, first = _timed(run_greens)
        t_green = first.diagnostics["greens_compute_s"]
        t_chain, again = _timed(run_greens, 3)
        inf = scene.with_overrides(["effects.plate_model=infinite"])
        t_inf, _ = _timed(lambda inf=inf: simulate(inf), 3)
        peak = np.abs(sem.samples).max()
        mismatch = np.abs(again.samples - sem.samples).max() / peak
        figures[preset] = (t_sem, t_green, d["plate_steps"])
        print(f"\n[bench] {preset} mesh {d['mesh']}, plate step {d['dt_s']:.3g} s "
              f"(ratio {d['dt_stability_ratio']:.2f} of the limit), chain sub-step "
              f"{d['chain_dt_s']:.3g} s, {d['plate_steps']} plate steps to "
              f"{d['duration_s'] * 1e3:.2f} ms (reflection passed); ARR {sem.truth['arr']:.4f}, "
              f"TOF {sem.truth['tof_s'] * 1e3:.4f} ms")
        print(f"[bench] {preset}: coupled sem run: {t_sem:.2f} s (target <= 20 s); "
              f"{t_sem / t_inf:.0f}x the infinite-plate run ({t_inf * 1e3:.1f} ms)")
        print(f"[bench] {preset}: one Green's function: {t_green:.2f} s (target <= 15 s); "
              f"{t_green / t_sem:.2f} of the coupled run")
        print(f"[bench] {preset}: greens chain run (cached response): {t_chain * 1e3:.1f} ms "
              f"(target <= 50 ms); {t_sem / t_chain:.0f}x faster than sem; "
              f"|greens - sem| = {mismatch:.1e} of peak")
        print(f"[bench] {preset}: energy drift sem {d['energy_drift']:.2e}, greens "
              f"{again.diagnostics['energy_drift']:.2e}")
        assert mismatch < 1e-6
    (ps, pg, pn), (rs, rg, rn) = figures["paper"], figures["resolved"]
    print(f"[bench] resolved / paper: sem run {rs / ps:.2f}x, Green's function {rg / pg:.2f}x, "
          f"plate steps {rn / pn:.2f}x")


def test_bench_plate_step_sumfact_vs_dense() -> None:
    """Plate steps of a Green's-function run on the t = 1.5 mm default-table mesh: the time loop
    with the sum-factorised operator vs the same loop with the dense element matrices (one GEMM
    per element shape), both with one BLAS thread, timed alternately in the same run."""
    scene = default_sweep().scene_at(2, 0, 4)
    plate = plate_for(scene)
    dt = 0.9 * 2.0 / np.sqrt(plate.element_bound)
    n = 400
    force = np.sin(np.linspace(0.0, np.pi, n)) ** 2
    rec = np.array([plate.contact_dof], dtype=np.int64)
    ops = {"dense": plate.dense_operator(), "sumfact": plate.operator}
    u = np.random.default_rng(0).standard_normal(plate.n_dofs)
    out = np.empty_like(u)
    best = {name: float("inf") for name in ops}
    apply = dict(best)
    runs = {}
    with single_threaded_blas():
        for op in ops.values():  # compile (or load from the cache) outside the figures
            run_plate_load(force[:2], plate.load_dofs, plate.load_weights, dt, plate.inv_mass,
                           op, rec)
        for _ in range(3):
            for name, op in ops.items():
                t, runs[name] = _timed(lambda op=op: run_plate_load(
                    force, plate.load_dofs, plate.load_weights, dt, plate.inv_mass, op, rec))
                best[name] = min(best[name], t / n)
                t, _ = _timed(lambda op=op: [stiffness_product(op, u, out) for _ in range(50)])
                apply[name] = min(apply[name], t / 50)
    w_sf, w_dense = runs["sumfact"][0], runs["dense"][0]
    assert np.abs(w_sf - w_dense).max() <= 1e-10 * np.abs(w_dense).max()
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    print(f"\n[bench] plate step, t = {scene.plate.thickness * 1e3:g} mm table mesh "
          f"{plate.mesh.elements} order {list(plate.mesh.order)}, {plate.n_dofs} dofs, "
          f"{len(plate.mesh.shapes[0])} element shapes, {n} steps (load average {load}):")
    print(f"[bench]   dense (GEMM per shape) {best['dense'] * 1e3:.3f} ms/step, sum-factorised "
          f"{best['sumfact'] * 1e3:.3f} ms/step, ratio {best['dense'] / best['sumfact']:.2f}x")
    print(f"[bench]   K u alone: dense {apply['dense'] * 1e3:.3f} ms, sum-factorised "
          f"{apply['sumfact'] * 1e3:.3f} ms, ratio {apply['dense'] / apply['sumfact']:.2f}x")
    print(f"[bench]   160,000 steps: dense {best['dense'] * 160_000:.0f} s, sum-factorised "
          f"{best['sumfact'] * 160_000:.0f} s")


def test_bench_mindlin_plate_load() -> None:
    """A Mindlin response as a table build computes it (t = 1.98 mm, the 9.53 mm sphere, 10 mm
    from the clamp): ns per dof and step of run_plate_load, and its stiffness product against
    the scalar general-order kernel (``_mindlin_any``, one element at a time) on the same plate,
    timed alternately in the same run."""
    sweep = default_sweep()
    scene = sweep.scene_at(1, 3, 4).with_overrides(["effects.plate_model=mindlin_greens"])
    plate = plate_for(scene, "mindlin")
    dt = 0.9 * 2.0 / np.sqrt(plate.element_bound)
    n = 1000
    force = np.zeros(n)
    force[0] = 1.0
    rec = np.array([plate.load_dofs[0]], dtype=np.int64)
    op = plate.operator
    conn, geom, dx, dy, w2, (bend, nu, shear) = op
    u = np.random.default_rng(0).standard_normal(plate.n_dofs)
    out = np.empty_like(u)

    def scalar() -> None:
        out[:] = 0.0
        _mindlin_any(u, conn, geom, dx, dy, w2, bend, nu, shear, out)

    def run() -> None:
        run_plate_load(force, plate.load_dofs, plate.load_weights, dt, plate.inv_mass, op, rec)

    run_plate_load(force[:2], plate.load_dofs, plate.load_weights, dt, plate.inv_mass, op, rec)
    scalar()  # compile (or load from the cache) outside the figures
    best = {"run": float("inf"), "product": float("inf"), "scalar": float("inf")}
    for _ in range(3):
        best["run"] = min(best["run"], _timed(run)[0] / n)
        best["product"] = min(best["product"], _timed(
            lambda: [stiffness_product(op, u, out) for _ in range(100)])[0] / 100)
        best["scalar"] = min(best["scalar"], _timed(
            lambda: [scalar() for _ in range(100)])[0] / 100)
    ns = {name: t / plate.n_dofs * 1e9 for name, t in best.items()}
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    print(f"\n[bench] Mindlin response, t = {scene.plate.thickness * 1e3:g} mm table mesh, "
          f"{plate.n_dofs} dofs, {conn.shape[0]} elements, {n} steps (load average {load}):")
    print(f"[bench]   run_plate_load {ns['run']:.2f} ns per dof-step; the product alone "
          f"{ns['product']:.2f} ns per dof, {ns['product'] / ns['run']:.0%} of the step")
    print(f"[bench]   product: blocked order-[4, 4] kernel {ns['product']:.2f} ns per dof, scalar "
          f"general-order kernel {ns['scalar']:.2f} ns, ratio {ns['scalar'] / ns['product']:.2f}x")
