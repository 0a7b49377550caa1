"""Slow studies of the spectral-element plate: the support effect against L, and convergence.

Run with ``pytest -m slow -s tests/test_sem_study.py``; both print their tables.
"""

from __future__ import annotations

import numpy as np
import pytest

from solitonde.model.scene import load_scene
from solitonde.model.simulate import simulate
from solitonde.model.zener import critical_distance

pytestmark = pytest.mark.slow

DISTANCES = [0.0, 0.01, 0.02, 0.04, 0.06, 0.08, 0.1, 0.125, 0.15, 0.2, 0.3, 0.457]
THICKNESSES = [2.29e-3, 3.18e-3, 4.83e-3]


def _truth(*overrides: str) -> tuple[float, float]:
    r = simulate(load_scene(None, list(overrides)))
    assert r.diagnostics["energy_drift"] < 1e-4
    return r.truth["arr"], r.truth["tof_s"]


def _settling_distance(distances: list[float], tof: np.ndarray, far: float, band: float) -> float:
    """Smallest L beyond which every TOF lies within ``band`` (relative) of the far value."""
    inside = np.abs(tof / far - 1.0) <= band
    for i in range(len(distances)):
        if inside[i:].all():
            return distances[i]
    return float("inf")


def test_support_effect_and_critical_distance() -> None:
    """D = 9.53 mm, the paper's mesh, greens tier: at L = 0 ARR is near 1 and TOF near 0.5 ms
    (paper Sec. 4); ARR falls and TOF rises with L and settle; the settling distance (TOF
    within 5 % of its value far from the support) grows as the plate gets thinner (paper
    Figs. 7, 8, 10)."""
    settle = {}
    for t in THICKNESSES:
        common = ["effects.plate_model=greens", f"plate.thickness={t}"]
        rows = [_truth(*common, f"plate.distance_to_support={d}") for d in DISTANCES]
        arr = np.array([r[0] for r in rows])
        tof = np.array([r[1] for r in rows])
        inf_arr, inf_tof = _truth("effects.plate_model=infinite", f"plate.thickness={t}")
        far = float(np.median(tof[np.array(DISTANCES) >= 0.15]))
        far_arr = float(np.median(arr[np.array(DISTANCES) >= 0.15]))
        settle[t] = _settling_distance(DISTANCES, tof, far, 0.05)
        scene = load_scene(None, [f"plate.thickness={t}"])
        print(f"\nt = {t * 1e3:.2f} mm (infinite plate: ARR {inf_arr:.3f}, "
              f"TOF {inf_tof * 1e3:.3f} ms; "
              f"L_c = {critical_distance(scene, 0.57) * 1e3:.0f} mm (k=0.57), "
              f"{critical_distance(scene, 0.2) * 1e3:.0f} mm (k=0.2))")
        for d, a, f in zip(DISTANCES, arr, tof, strict=True):
            print(f"  L = {d * 1e3:5.0f} mm  ARR {a:.3f}  TOF {f * 1e3:.3f} ms")
        print(f"  settles (TOF within 5 %) from L = {settle[t] * 1e3:.0f} mm")
        assert arr[0] > 0.9
        assert tof[0] == pytest.approx(0.5e-3, rel=0.05)
        assert arr[1] > far_arr + 0.2
        assert tof[0] < 0.95 * far
    assert settle[2.29e-3] >= settle[3.18e-3] >= settle[4.83e-3]
    assert settle[2.29e-3] > settle[4.83e-3]


def test_convergence_with_order_and_element_count() -> None:
    """Centre of a 0.3 m plate (t = 3.18 mm, D = 9.53 mm), greens tier. Thickness order: TOF
    and ARR converge (change below 0.1 % from order 2 to 4). In-plane element count: TOF
    converges (last change below 0.1 %); ARR keeps creeping up slowly (a point force on a
    shear-deformable plate has a logarithmic local deflection), bounded here by 5 % per
    refinement. Prints the observed orders p = ln(d_k / d_k+1) / ln(h_k / h_k+1)."""
    base = ["effects.plate_model=greens", "plate.size=[0.3,0.3]", "plate.distance_to_support=0.15"]
    counts = [6, 8, 12, 16, 24]
    h_rows = [_truth(*base, f"sem.elements=[{n},{n},1]") for n in counts]
    z_orders = [1, 2, 3, 4]
    z_rows = [_truth(*base, "sem.elements=[12,12,1]", f"sem.order=[4,4,{p}]") for p in z_orders]
    print("\nin-plane elements (order 4): n, ARR, TOF ms")
    for n, (a, f) in zip(counts, h_rows, strict=True):
        print(f"  {n:3d}  {a:.4f}  {f * 1e3:.5f}")
    print("thickness order (12 x 12 elements): pz, ARR, TOF ms")
    for p, (a, f) in zip(z_orders, z_rows, strict=True):
        print(f"  {p:3d}  {a:.5f}  {f * 1e3:.5f}")
    for name, k in (("ARR", 0), ("TOF", 1)):
        q = np.array([r[k] for r in h_rows])
        d = np.abs(np.diff(q))
        h = 1.0 / np.array(counts, dtype=float)
        orders = np.log(d[:-1] / d[1:]) / np.log(h[1:-1] / h[2:])
        print(f"observed order of {name} under h-refinement: {np.round(orders, 2)}")
        qz = np.array([r[k] for r in z_rows])
        dz = np.abs(np.diff(qz))
        print(f"{name} change per thickness order: {dz} (ratios {np.round(dz[:-1] / dz[1:], 1)})")
        assert dz[-1] < 1e-3 * abs(qz[-1])
    tof = np.array([r[1] for r in h_rows])
    arr = np.array([r[0] for r in h_rows])
    assert abs(tof[-1] / tof[-2] - 1) < 1e-3
    assert abs(tof[0] / tof[-1] - 1) > 3 * abs(tof[-1] / tof[-2] - 1)
    assert abs(arr[-1] / arr[-2] - 1) < 0.05
