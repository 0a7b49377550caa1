"""The Mindlin-Reissner plate: its operator, its convergence to Mindlin's exact frequency, the
coupled run's energy balance, its Green's function, and its agreement with the 3-D plate."""

from __future__ import annotations

import math

import numpy as np
import pytest

from solitonde.model.materials import get_material
from solitonde.model.mesh import plate_mesh
from solitonde.model.mindlin import build_mindlin_plate, rigidities
from solitonde.model.plan import plan
from solitonde.model.scene import load_scene
from solitonde.model.sem_kernels import dense_operator, stiffness_product
from solitonde.model.simulate import simulate

AL = get_material("al_6061")


def _dense_matrix(plate) -> np.ndarray:
    """K column by column from the sum-factorised product (small plates only)."""
    n = plate.n_dofs
    k = np.empty((n, n))
    unit = np.zeros(n)
    for i in range(n):
        unit[i] = 1.0
        k[:, i] = plate.apply_stiffness(unit)
        unit[i] = 0.0
    return k


@pytest.mark.parametrize("order", [(4, 4), (3, 2)])
def test_sum_factorisation_is_the_element_matrices(order) -> None:
    """The kernel's K u equals the dense element matrices B^T C B assembled, to round-off, on a
    graded, locally refined mesh (several element shapes)."""
    mesh = plate_mesh((0.3, 0.2), 3e-3, (6, 4, 1), (*order, 1), 0.05, True, 3e-3, 1)
    plate = build_mindlin_plate(mesh, AL)
    conn = plate.operator[0]
    edofs = (3 * conn[:, :, None] + np.arange(3)).reshape(conn.shape[0], -1)
    by_shape = np.argsort(plate.shape_id, kind="stable")
    offsets = np.searchsorted(plate.shape_id[by_shape],
                              np.arange(len(plate.sizes) + 1)).astype(np.int64)
    dense = dense_operator(np.ascontiguousarray(edofs[by_shape]), offsets, plate.kes)
    u = np.random.default_rng(0).standard_normal(plate.n_dofs)
    fast, ref = np.empty(plate.n_dofs), np.empty(plate.n_dofs)
    stiffness_product(plate.operator, u, fast)
    stiffness_product(dense, u, ref)
    assert len(plate.sizes) > 2
    assert np.abs(fast - ref).max() <= 1e-12 * np.abs(ref).max()
    # symmetric and positive semi-definite with three rigid modes on the free plate
    free = build_mindlin_plate(mesh, AL, "none")
    k = _dense_matrix(free)
    assert np.abs(k - k.T).max() <= 1e-12 * np.abs(k).max()


def mindlin_exact_frequency(side: float, thickness: float, m: int = 1, n: int = 1) -> float:
    """Mindlin's flexural frequency (rad/s) of mode (m, n) of a simply supported square plate.

    With w = W sin sin and an irrotational rotation field theta = grad psi, the plate's two
    equations give det [[kGt k^2 - rho t w^2, kGt k^2], [kGt, D k^2 + kGt - rho t^3/12 w^2]] = 0,
    a quadratic in w^2 whose lower root is the flexural mode (Mindlin 1951).
    """
    bend, shear = rigidities(AL, thickness)
    k2 = (m * math.pi / side) ** 2 + (n * math.pi / side) ** 2
    rho, inertia = AL.density, thickness**3 / 12.0
    a = rho * thickness * rho * inertia
    b = -(shear * k2 * rho * inertia + rho * thickness * (bend * k2 + shear))
    c = shear * k2 * (bend * k2 + shear) - shear**2 * k2
    return math.sqrt((-b - math.sqrt(b * b - 4.0 * a * c)) / (2.0 * a))


def _lowest_frequency(elements: int, order: int, side: float, thickness: float) -> float:
    """Lowest eigenfrequency of the meshed plate, simply supported ("hard": w and the tangential
    rotation fixed on every edge), from the assembled K and the diagonal mass."""
    mesh = plate_mesh((side, side), thickness, (elements, elements, 1), (order, order, 1),
                      side / 2.0, False)
    plate = build_mindlin_plate(mesh, AL, "none")
    ax, ay, _ = mesh.axes
    x, y = np.tile(ax, ay.size), np.repeat(ay, ax.size)
    tol = 1e-9 * side
    fixed = np.zeros((x.size, 3), dtype=bool)
    on_x = (np.abs(x) < tol) | (np.abs(x - side) < tol)
    on_y = (np.abs(y) < tol) | (np.abs(y - side) < tol)
    fixed[on_x, 0] = fixed[on_x, 2] = True
    fixed[on_y, 0] = fixed[on_y, 1] = True
    free = ~fixed.ravel()
    k = _dense_matrix(plate)[np.ix_(free, free)]
    d = 1.0 / np.sqrt(plate.dof_mass[free])
    return math.sqrt(np.linalg.eigvalsh(k * d[:, None] * d[None, :])[0])


@pytest.mark.parametrize("order, meshes, min_rate", [(2, (2, 4, 8), 3.0), (4, (1, 2, 4), 6.5)])
def test_eigenfrequency_converges_to_mindlins_exact_value(order, meshes, min_rate) -> None:
    """A thick square plate (t/a = 0.1, where shear and rotary inertia lower the frequency by
    several per cent from Kirchhoff's): the (1, 1) frequency converges to Mindlin's exact value
    at the spectral element's rate O(h^2p) (observed: 3.4 at p = 2, 7.4 at p = 4 on these
    meshes), ending within 1e-6 of it at p = 4."""
    side, thickness = 0.1, 0.01
    exact = mindlin_exact_frequency(side, thickness)
    kirchhoff = 2.0 * (math.pi / side) ** 2 * math.sqrt(rigidities(AL, thickness)[0]
                                                         / (AL.density * thickness))
    assert exact < 0.97 * kirchhoff  # the test plate is thick enough for Mindlin to matter
    errors = [abs(_lowest_frequency(n, order, side, thickness) / exact - 1.0) for n in meshes]
    rates = [math.log2(errors[i] / errors[i + 1]) for i in range(len(errors) - 1)]
    assert rates[-1] >= min_rate, (errors, rates)
    if order == 4:
        assert errors[-1] < 1e-6


#: The paper's 9.53 mm chain on a small plate near its support: cheap, and the reflection comes
#: back from the support during the run.
SMALL = ["plate.size=[0.3,0.3]", "plate.distance_to_support=0.05", "plate.thickness=3.18e-3",
         "sem.elements=[8,8,1]", "sem.elements_per_wavelength=0"]


@pytest.fixture(scope="module")
def small_runs():
    return {tier: simulate(load_scene(None, [*SMALL, f"effects.plate_model={tier}"]))
            for tier in ("mindlin", "mindlin_greens", "sem")}


def test_coupled_run_balances_energy(small_runs) -> None:
    """Chain + contacts + gravity + the plate's kinetic and strain energy (w and rotations) stay
    constant to 1e-4 of the striker's energy, while the plate takes more than a tenth of it."""
    d = small_runs["mindlin"].diagnostics
    assert d["status"] == "reflection_passed"
    assert d["energy_drift"] < 1e-4
    assert d["plate_work_J"] > 0.1 * d["energy_scale_J"]


def test_energy_error_falls_as_the_step_squared() -> None:
    """Halving the plate step cuts the balance's drift about four times (the coupling is second
    order; a missing or misweighted energy term would not shrink)."""
    drifts = [simulate(load_scene(None, [*SMALL, "effects.plate_model=mindlin",
                                         f"sem.step_factor={f}"])).diagnostics["energy_drift"]
              for f in (0.8, 0.4)]
    assert 2.5 < drifts[0] / drifts[1] < 6.0, drifts


def test_greens_function_reproduces_the_coupled_run(small_runs) -> None:
    """The Mindlin plate's cached contact response, convolved, is the coupled run (round-off)."""
    a, b = small_runs["mindlin"], small_runs["mindlin_greens"]
    assert np.abs(a.samples - b.samples).max() < 1e-6 * np.abs(a.samples).max()


def test_agrees_with_the_3d_plate_on_the_same_mesh(small_runs) -> None:
    """Same in-plane mesh, same patch: the 2-D plate's TOF and ARR within the table budget
    (1 %, 5 %) of the 3-D plate's on a thin plate (D/t = 3), at a fraction of its dofs."""
    m, s = small_runs["mindlin"], small_runs["sem"]
    assert m.truth["tof_s"] == pytest.approx(s.truth["tof_s"], rel=0.01)
    assert m.truth["arr"] == pytest.approx(s.truth["arr"], rel=0.05)
    assert m.diagnostics["mesh"]["dofs"] < 0.4 * s.diagnostics["mesh"]["dofs"]
    assert m.diagnostics["mesh"]["plate_theory"] == "mindlin"


def test_plan_prices_the_mindlin_plate_as_it_runs(small_runs) -> None:
    """plan() gives the steps and dofs the run took; its floor never exceeds them."""
    scene = load_scene(None, [*SMALL, "effects.plate_model=mindlin"])
    p = plan(scene)
    d = small_runs["mindlin"].diagnostics
    assert p.plate_steps == d["plate_steps"]
    assert p.plate_dofs == d["mesh"]["dofs"]
    floor = plan(scene, budget=0.0)
    assert floor.estimate.startswith("floor")
    assert floor.chain_steps <= p.plate_steps


@pytest.mark.slow
def test_the_docs_coupled_comparison() -> None:
    """docs/explanation/accuracy-cost.md's coupled table: D 9.53 mm on the paper's two thinnest
    plates, 20 mm from the support and at the centre, ``sem`` against ``mindlin`` on the same
    16 x 16 mesh (``bench plates --kind coupled --set sem.elements_per_wavelength=0``); writes
    docs/figures/mindlin-coupled.json. Minutes: the 3-D runs."""
    import json
    from pathlib import Path

    from solitonde.instrument.studies.plate_theory import Point, compare

    points = [Point(9.53e-3, t, d) for t in (3.18e-3, 2.29e-3) for d in (0.02, 0.457)]
    result = compare(points, "coupled", overrides=["sem.elements_per_wavelength=0"])
    figures = Path(__file__).resolve().parents[2] / "docs" / "figures" / "mindlin-coupled.json"
    figures.write_text(json.dumps({
        "command": "pytest -m slow tests/model/test_mindlin.py::test_the_docs_coupled_comparison"
                   " --timeout 0",
        "figures": result}, indent=1, default=str) + "\n")


@pytest.mark.slow
def test_the_docs_mid_distance_convergence() -> None:
    """docs/explanation/accuracy-cost.md's thin plate at a mid distance (D 9.53 mm, t 1.5 mm,
    L 50 mm): both plates coupled on 16 x 16 and on 32 x 32 in-plane elements; writes
    docs/figures/mindlin-mid-distance.json. Minutes: the 3-D runs."""
    import json
    from pathlib import Path

    from solitonde.instrument.studies.plate_theory import Point, compare

    runs = {n: compare([Point(9.53e-3, 1.5e-3, 0.05)], "coupled",
                       overrides=["sem.elements_per_wavelength=0", f"sem.elements=[{n},{n},1]"])
            for n in (16, 32)}
    name = "mindlin-mid-distance.json"
    figures = Path(__file__).resolve().parents[2] / "docs" / "figures" / name
    figures.write_text(json.dumps({
        "command": "pytest -m slow tests/model/test_mindlin.py"
                   "::test_the_docs_mid_distance_convergence --timeout 0",
        "figures": {str(n): run["rows"][0] for n, run in runs.items()}}, indent=1, default=str)
        + "\n")
