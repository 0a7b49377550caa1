"""Spectral-element plate: mesh layout, elasticity, mass, stability, symmetry, point impedance."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.sparse.linalg import eigsh

from solitonde.model.contact import plate_impedance
from solitonde.model.materials import MATERIALS
from solitonde.model.mesh import plate_mesh
from solitonde.model.sem import build_plate

AL = MATERIALS["al_6061"]


def test_paper_preset_counts() -> None:
    """16 x 16 x 1 elements of order 4 x 4 x 2: 12,675 nodes and 38,025 dofs (paper, Sec. 3.2)."""
    mesh = plate_mesh((0.914, 0.914), 3.18e-3, (16, 16, 1), (4, 4, 2), contact_x=0.457)
    assert mesh.n_nodes == 12_675
    assert mesh.n_dofs == 38_025
    half = plate_mesh((0.914, 0.914), 3.18e-3, (16, 16, 1), (4, 4, 2), 0.457, symmetry=True)
    assert half.elements == (16, 8, 1)
    assert half.n_nodes == 65 * 33 * 3


@pytest.mark.parametrize("distance", [0.0, 0.001, 0.01, 0.0123, 0.05, 0.2, 0.3171, 0.457, 0.914])
@pytest.mark.parametrize("symmetry", [False, True])
def test_contact_node_lies_under_the_chain(distance: float, symmetry: bool) -> None:
    """For any L the top-surface node under the chain is at (L, Ly/2, t), with at most two
    element sizes per direction, none far from the uniform size unless L forces it."""
    mesh = plate_mesh((0.914, 0.914), 3.18e-3, (16, 16, 1), (4, 4, 2), distance, symmetry)
    x, y, z = mesh.nodes[mesh.contact_node]
    assert x == pytest.approx(distance, abs=1e-12)
    assert y == pytest.approx(0.457, abs=1e-12)
    assert z == pytest.approx(3.18e-3, abs=1e-15)
    hx = np.diff(mesh.x_edges)
    assert len(np.unique(np.round(hx / hx.max(), 9))) <= 2
    assert hx.sum() == pytest.approx(0.914)
    if distance >= 0.01:  # a node at L = 1 mm needs some element near 1 mm / 0.17 at least
        assert hx.min() > 0.5 * 0.914 / 16
    assert len(mesh.shapes[0]) <= 4


def test_stiffness_matches_assembled_and_is_symmetric() -> None:
    """Matrix-free K u equals the assembled CSR matvec on a graded mesh; K is symmetric."""
    mesh = plate_mesh((0.2, 0.15), 4e-3, (3, 3, 2), (3, 2, 2), contact_x=0.031)
    plate = build_plate(mesh, AL, "none")
    assert len(mesh.shapes[0]) >= 2
    k = plate.stiffness_csr()
    rng = np.random.default_rng(3)
    u = rng.standard_normal(plate.n_dofs)
    ku = plate.apply_stiffness(u)
    assert np.allclose(ku, k @ u, rtol=0, atol=1e-12 * np.abs(ku).max())
    assert abs(k - k.T).max() <= 1e-12 * abs(k).max()


def test_rigid_body_motions_carry_no_force() -> None:
    """Translations and infinitesimal rotations of a free plate lie in the kernel of K."""
    mesh = plate_mesh((0.2, 0.15), 4e-3, (3, 3, 1), (4, 3, 2), contact_x=0.05)
    plate = build_plate(mesh, AL, "none")
    x, y, z = mesh.nodes.T
    scale = np.abs(plate.apply_stiffness(np.random.default_rng(0).standard_normal(plate.n_dofs)))
    zero = np.zeros_like(x)
    modes = [
        (np.ones_like(x), zero, zero), (zero, np.ones_like(x), zero), (zero, zero, np.ones_like(x)),
        (-y, x, zero), (zero, -z, y), (z, zero, -x),
    ]
    for mode in modes:
        u = np.column_stack(mode).ravel()
        assert np.abs(plate.apply_stiffness(u)).max() < 1e-11 * scale.max()


def test_uniform_strain_gives_hookes_law_tractions() -> None:
    """u_x = eps x: the nodal forces on the face x = Lx add up to (lambda + 2 mu) eps A and
    those on y = Ly to lambda eps A_y; interior nodes carry nothing (a patch test)."""
    lx, ly, t = 0.12, 0.08, 5e-3
    mesh = plate_mesh((lx, ly), t, (3, 2, 1), (3, 4, 2), contact_x=0.05)
    plate = build_plate(mesh, AL, "none")
    eps = 1e-4
    x, y, _ = mesh.nodes.T
    u = np.column_stack((eps * x, 0 * x, 0 * x)).ravel()
    f = plate.apply_stiffness(u).reshape(-1, 3)
    lam, mu = AL.lame_lambda, AL.shear_modulus
    face_x = np.isclose(x, lx)
    face_y = np.isclose(y, ly)
    assert f[face_x, 0].sum() == pytest.approx((lam + 2 * mu) * eps * ly * t, rel=1e-10)
    assert f[face_y, 1].sum() == pytest.approx(lam * eps * lx * t, rel=1e-10)
    inside = ~(np.isclose(x, 0) | face_x | np.isclose(y, 0) | face_y
               | np.isclose(mesh.nodes[:, 2], 0) | np.isclose(mesh.nodes[:, 2], t))
    assert np.abs(f[inside]).max() < 1e-9 * np.abs(f).max()


@pytest.mark.parametrize("symmetry", [False, True])
def test_mass_is_the_plate_mass(symmetry: bool) -> None:
    """Nodal quadrature conserves mass: sum of the diagonal = rho V (half of it on a half model)."""
    mesh = plate_mesh((0.914, 0.914), 3.18e-3, (7, 6, 1), (4, 3, 2), 0.2, symmetry)
    plate = build_plate(mesh, AL)
    share = 0.5 if symmetry else 1.0
    assert plate.node_mass.sum() == pytest.approx(share * AL.density * 0.914**2 * 3.18e-3)
    assert np.all(plate.node_mass > 0)


def test_stable_step_bound_and_instability_beyond_it() -> None:
    """The element bound is above the global omega_max^2 and close to it; central differences
    stay bounded at 0.98 of the critical step and blow up at 1.03 of it."""
    mesh = plate_mesh((0.1, 0.1), 3e-3, (3, 3, 1), (3, 3, 2), contact_x=0.05)
    plate = build_plate(mesh, AL, "opposite_edges")
    lanczos = plate.max_eigenvalue
    assert plate.element_bound >= lanczos * (1 - 1e-9)
    assert plate.element_bound <= 1.3 * lanczos
    dt_crit = 2.0 / np.sqrt(lanczos)
    force = np.zeros(4000)
    force[0] = 1.0
    every = np.arange(plate.n_dofs)[~plate.fixed][::7]
    stable = np.abs(plate.run_point_force(force, 0.98 * dt_crit, every))
    unstable = np.abs(plate.run_point_force(force, 1.03 * dt_crit, every))
    assert stable[-500:].max() < 10 * stable[:500].max()
    assert not unstable[-500:].max() < 1e6 * unstable[:500].max()


@pytest.mark.parametrize("supports", ["opposite_edges", "all_edges", "none"])
@pytest.mark.parametrize(("radius", "refinement"), [(0.0, 0), (3.18e-3, 1)])
def test_half_model_reproduces_full_plate(supports: str, radius: float, refinement: int) -> None:
    """The mirror plane y = Ly/2 with half the force gives the full plate's contact response,
    for a single-node force and for the patch on a locally refined mesh."""
    args = ((0.3, 0.24), 3.18e-3, (6, 6, 1), (3, 3, 2), 0.07)
    full = build_plate(plate_mesh(*args, False, radius, refinement), AL, supports)
    half = build_plate(plate_mesh(*args, True, radius, refinement), AL, supports)
    assert half.mesh.n_nodes < 0.6 * full.mesh.n_nodes
    dt = 0.9 * 2 / np.sqrt(max(full.element_bound, half.element_bound))
    force = np.sin(np.pi * np.arange(600) / 150) ** 2 * (np.arange(600) < 150)
    w_full = full.run_contact_load(force, dt)[0]
    w_half = half.run_contact_load(force, dt)[0]
    assert np.abs(w_half - w_full).max() < 1e-9 * np.abs(w_full).max()


@pytest.mark.parametrize("thickness", [2.29e-3, 3.18e-3, 4.83e-3])
def test_point_impedance_of_the_infinite_plate(thickness: float) -> None:
    """After a short force pulse and before any edge reflection returns, the contact point has
    moved by impulse / Z with Z = 8 sqrt(rho t D_p) (Zener; the Kirchhoff plate's point
    mobility is real and frequency independent). Mean over 30-100 us, 20 us sin^2 pulse,
    through the contact patch (r_c = t) on the locally refined mesh."""
    size = 0.3
    mesh = plate_mesh((size, size), thickness, (12, 12, 1), (4, 4, 2), size / 2, symmetry=True,
                      contact_radius=thickness, contact_refinement=1)
    plate = build_plate(mesh, AL, "opposite_edges")
    dt = 0.9 * 2 / np.sqrt(plate.element_bound)
    n = int(110e-6 / dt)
    t = np.arange(n) * dt
    pulse = np.where(t < 20e-6, np.sin(np.pi * t / 20e-6) ** 2, 0.0)
    impulse = pulse.sum() * dt
    w = plate.run_contact_load(pulse, dt)[0]
    tw = np.arange(n + 1) * dt
    window = (tw > 30e-6) & (tw < 100e-6)
    ratio = w[window].mean() / impulse * plate_impedance(thickness, AL)
    assert ratio == pytest.approx(1.0, abs=0.02)


def test_lanczos_agrees_with_scipy_on_assembled_matrix() -> None:
    """omega_max^2 from the matrix-free Lanczos equals eigsh on the assembled M^-1/2 K M^-1/2."""
    mesh = plate_mesh((0.1, 0.08), 3e-3, (2, 2, 1), (3, 3, 2), contact_x=0.05)
    plate = build_plate(mesh, AL, "all_edges")
    k = plate.stiffness_csr().toarray()
    s = np.sqrt(plate.inv_mass)
    a = s[:, None] * k * s[None, :]
    ref = eigsh(a, k=1, which="LA", return_eigenvectors=False)[0]
    assert plate.max_eigenvalue == pytest.approx(ref, rel=1e-6)


@pytest.mark.parametrize("distance", [0.0, 0.002, 0.01, 0.0123, 0.2, 0.457, 0.914])
@pytest.mark.parametrize("symmetry", [False, True])
def test_refined_mesh_resolves_the_patch(distance: float, symmetry: bool) -> None:
    """Local refinement: elements of size 2 r_c / n within 2 r_c of the chain, sizes at most
    doubling outward, none smaller than the fine size (it sets the stable step), few shapes."""
    rc, n = 3.18e-3, 2
    mesh = plate_mesh((0.914, 0.914), 3.18e-3, (16, 16, 1), (4, 4, 2), distance, symmetry, rc, n)
    fine = 2 * rc / n
    for edges, centre in ((mesh.x_edges, distance), (mesh.y_edges, 0.457)):
        h = np.diff(edges)
        assert h.min() >= fine * (1 - 1e-9)
        assert np.all(np.maximum(h[1:] / h[:-1], h[:-1] / h[1:]) <= 2.5)
        mid = 0.5 * (edges[1:] + edges[:-1])
        near = np.abs(mid - centre) < 2 * rc
        assert np.all(h[near] <= 2 * fine * (1 + 1e-9))
        assert h.max() < 0.914 / 16 * 1.5
    assert mesh.x_edges[-1] == pytest.approx(0.914)
    assert mesh.y_edges[-1] == pytest.approx(0.457 if symmetry else 0.914)
    assert len(mesh.shapes[0]) <= 36


@pytest.mark.parametrize(("refinement", "distance"), [(0, 0.2), (1, 0.2), (3, 0.2), (2, 0.001)])
@pytest.mark.parametrize("symmetry", [False, True])
def test_contact_load_is_the_consistent_patch_load(
    refinement: int, distance: float, symmetry: bool
) -> None:
    """The nodal weights b_a = int N_a p dA integrate every polynomial the elements hold as the
    pressure bump does: sum b = share, the centroid is the chain's position and the second
    moment is r_c^2 / 4 (exact for p = (1 - r^2/r_c^2)^2), on a coarse mesh as on a fine one.
    Near the edge (L = 1 mm < r_c) the patch is cut by the plate's edge and renormalised."""
    rc = 3.18e-3
    mesh = plate_mesh((0.3, 0.3), 3.18e-3, (6, 6, 1), (4, 4, 2), distance, symmetry, rc,
                      refinement)
    nodes, b = mesh.contact_load
    share = 0.5 if symmetry else 1.0
    x, y, z = mesh.nodes[nodes].T
    assert np.all(z == pytest.approx(3.18e-3))
    assert b.sum() == pytest.approx(share, rel=1e-12)
    if distance > rc:
        assert (b * x).sum() / share == pytest.approx(distance, abs=1e-9 * rc)
        assert (b * ((x - distance) ** 2 + (y - 0.15) ** 2)).sum() / share == pytest.approx(
            rc**2 / 4, rel=1e-5)  # 24-point Gauss on a C1 rim: ~1e-6
        if not symmetry:
            assert (b * y).sum() == pytest.approx(0.15, abs=1e-9 * rc)
    else:
        assert np.all(x >= 0) and (b * x).sum() / share > distance
    if refinement:
        assert np.all(b > -0.1 * b.max())  # resolved: nearly a positive quadrature of p


def test_point_load_keeps_the_single_node() -> None:
    """r_c = 0 is the single node under the chain, with the mesh's share of the force."""
    mesh = plate_mesh((0.3, 0.3), 3.18e-3, (6, 6, 1), (4, 4, 2), 0.1, True)
    nodes, b = mesh.contact_load
    assert nodes.tolist() == [mesh.contact_node]
    assert b.tolist() == [0.5]


def test_patch_deflection_converges_where_a_point_force_does_not() -> None:
    """Refining the elements around the chain (2 r_c / n, n = 1, 2, 3): the deflection under a
    single-node force keeps growing (3D point load: ~1/r under it, unbounded as h -> 0), the
    patch-weighted deflection under the patch load stays put (within 0.5 %). Mean deflection
    over 10-25 us under a 20 us sin^2 force pulse."""
    rc = 3.18e-3
    means: dict[str, list[float]] = {"patch": [], "point": []}
    for n in (1, 2, 3):
        mesh = plate_mesh((0.12, 0.12), 3.18e-3, (4, 4, 1), (4, 4, 2), 0.06, True, rc, n)
        for name, m in (("patch", mesh), ("point", replace(mesh, contact_radius=0.0))):
            plate = build_plate(m, AL, "opposite_edges")
            dt = 0.9 * 2 / np.sqrt(plate.element_bound)
            t = np.arange(int(25e-6 / dt) + 1) * dt
            pulse = np.where(t < 20e-6, np.sin(np.pi * t / 20e-6) ** 2, 0.0)
            w = plate.run_contact_load(pulse[:-1], dt)[0]
            means[name].append(float(w[t >= 10e-6].mean()))
    point, patch = np.array(means["point"]), np.array(means["patch"])
    assert np.all(point[1:] / point[:-1] > 1.03)  # measured +10 %, +4.7 % (h / 2, h / 1.5)
    assert point[-1] / point[0] > 1.1
    assert np.ptp(patch) < 5e-3 * patch.mean()


def test_single_threaded_blas_limits_every_blas_pool_and_restores_them() -> None:
    """Inside, every BLAS pool of the process (numpy's and scipy's, which compiled code calls)
    runs one thread; after, each has its count back (two here, whatever the machine's cores)."""
    import scipy.linalg.cython_blas  # noqa: F401  (scipy's BLAS loaded, as compiled code has it)
    from threadpoolctl import threadpool_info, threadpool_limits

    from solitonde.model.sem import single_threaded_blas

    def counts() -> list[int]:
        return [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]

    with threadpool_limits(limits=2, user_api="blas"):
        assert len(counts()) >= 2 and set(counts()) == {2}  # numpy's and scipy's
        for _ in range(2):  # the pools found once serve every entry
            with single_threaded_blas():
                assert set(counts()) == {1}
            assert set(counts()) == {2}
