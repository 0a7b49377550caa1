"""Green's-function tier: the response, its cache key, memory and disk caches."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from solitonde.instrument.tables.greens_cache import DiskGreensCache, LayeredCache
from solitonde.model import greens
from solitonde.model.materials import MATERIALS
from solitonde.model.mesh import plate_mesh
from solitonde.model.mindlin import build_mindlin_plate
from solitonde.model.sem import build_plate

AL = MATERIALS["al_6061"]


def _plate(distance: float = 0.05, thickness: float = 3.18e-3, supports: str = "opposite_edges",
           elements: tuple[int, int, int] = (4, 4, 1), material=AL, radius: float = 3e-3,
           refinement: int = 1):
    mesh = plate_mesh((0.3, 0.3), thickness, elements, (3, 3, 2), distance, True, radius,
                      refinement)
    return build_plate(mesh, material, supports)


def test_response_is_the_plate_run_it_stands_for() -> None:
    """Convolving g with a force history gives the directly computed deflection."""
    plate = _plate()
    dt = 0.8 * 2 / np.sqrt(plate.element_bound)
    n = 400
    g = greens.compute_response(plate, dt, n)
    force = np.sin(np.linspace(0, 3, n)) ** 2
    direct = plate.run_contact_load(force, dt)[0]
    conv = np.array([np.dot(g[s - np.arange(s)], force[:s]) for s in range(n + 1)])
    assert np.allclose(conv, direct, rtol=0, atol=1e-10 * np.abs(direct).max())
    # after one step u = dt^2 M^-1 b, seen through the same weights: w = b . u / share
    b = plate.load_weights
    expected = dt**2 * np.sum(b * b * plate.inv_mass[plate.load_dofs]) / plate.force_share
    assert g[1] == pytest.approx(expected)


def test_key_depends_on_everything_the_response_depends_on() -> None:
    """Plate, mesh, position, patch, refinement, supports, material and step change the key;
    nothing else does."""
    base = _plate()
    key = greens.response_key(base, 1e-7)
    assert key == greens.response_key(_plate(), 1e-7)
    others = [
        greens.response_key(_plate(distance=0.06), 1e-7),
        greens.response_key(_plate(thickness=2.29e-3), 1e-7),
        greens.response_key(_plate(supports="all_edges"), 1e-7),
        greens.response_key(_plate(elements=(5, 4, 1)), 1e-7),
        greens.response_key(_plate(material=MATERIALS["al_6061_paper"]), 1e-7),
        greens.response_key(base, 1.1e-7),
        greens.response_key(_plate(radius=2e-3), 1e-7),
        greens.response_key(_plate(refinement=2), 1e-7),
        greens.response_key(_plate(radius=0.0, refinement=0), 1e-7),
        greens.response_key(build_mindlin_plate(base.mesh, AL), 1e-7),  # the plate theory
    ]
    assert len({key, *others}) == 11


def test_key_depends_on_the_model_code(monkeypatch: pytest.MonkeyPatch) -> None:
    """Another version or an edit of the model (its source digest) is another key: a stored
    response is only ever this code's."""
    key = greens.response_key(_plate(), 1e-7)
    monkeypatch.setattr(greens, "model_digest", lambda: "an-edited-model")
    assert greens.response_key(_plate(), 1e-7) != key


def test_cache_reuses_and_extends() -> None:
    """A stored response serves shorter requests; a longer request recomputes and replaces."""
    plate = _plate()
    dt = 0.8 * 2 / np.sqrt(plate.element_bound)
    cache = greens.MemoryCache()
    g1, hit1, _ = greens.contact_response(plate, dt, 100, cache)
    g2, hit2, _ = greens.contact_response(plate, dt, 50, cache)
    g3, hit3, _ = greens.contact_response(plate, dt, 200, cache)
    assert (hit1, hit2, hit3) == (False, True, False)
    assert np.array_equal(g2, g1[:51])
    assert np.allclose(g3[:101], g1)
    assert cache.load(greens.response_key(plate, dt)).size == 201


def test_disk_cache_round_trip_is_atomic(tmp_path) -> None:
    """npz files under the folder, written by rename (no temporary left), read back equal;
    a corrupt file counts as missing."""
    disk = DiskGreensCache(tmp_path)
    data = np.linspace(0, 1, 17)
    disk.store("abc123", data)
    assert [p.name for p in tmp_path.iterdir()] == ["abc123.npz"]
    assert np.array_equal(disk.load("abc123"), data)
    assert disk.load("missing") is None
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    assert disk.load("bad") is None
    with pytest.raises(ValueError, match="alphanumeric"):
        disk.path("../escape")
    layered = LayeredCache(DiskGreensCache(tmp_path))
    assert np.array_equal(layered.load("abc123"), data)


def test_simulate_uses_the_cache_it_is_given_and_no_other() -> None:
    """A greens run stores its response in the cache passed to simulate(), the next run with that
    cache reads it back with the same trace, and the process's own cache is never touched."""
    from solitonde.model.scene import scene_from_dict
    from solitonde.model.simulate import simulate

    scene = scene_from_dict({"effects": {"plate_model": "greens"},
                             "sem": {"elements": [2, 2, 1], "order": [2, 2, 1],
                                     "contact_refinement": 0},
                             "plate": {"distance_to_support": 0.05},
                             "output": {"duration": 5e-4}})
    before = len(greens.PROCESS_CACHE)
    mine = greens.MemoryCache()
    first = simulate(scene, greens_cache=mine)
    again = simulate(scene, greens_cache=mine)
    assert len(mine) == 1 and len(greens.PROCESS_CACHE) == before
    assert not first.diagnostics["greens_cached"] and again.diagnostics["greens_cached"]
    np.testing.assert_array_equal(first.samples, again.samples)
    assert not hasattr(greens, "set_default_cache")  # no process-wide swap to reach for


def test_a_3d_plates_key_is_unchanged_by_the_mindlin_tier() -> None:
    """A 3-D plate's key is the hash of its description with no plate-theory field (the Mindlin
    plate's names itself), the model's code among it."""
    import hashlib
    import json

    plate = _plate()
    mesh = plate.mesh
    edges = hashlib.sha256(np.concatenate((mesh.x_edges, mesh.y_edges, mesh.z_edges))
                           .astype("<f8").tobytes()).hexdigest()[:16]
    desc = {"contact_radius_m": float(mesh.contact_radius), "edges": edges, "version": 3,
            "thickness_m": float(mesh.z_edges[-1]), "size_m": [0.3, 0.3],
            "distance_to_support_m": 0.05, "elements": list(mesh.elements),
            "order": list(mesh.order), "symmetry": True, "supports": "opposite_edges",
            "material": [AL.youngs_modulus, AL.poisson_ratio, AL.density], "dt_s": 1e-7,
            "code": greens.model_digest()}
    text = json.dumps(desc, sort_keys=True, separators=(",", ":"), default=repr)
    assert greens.response_key(plate, 1e-7) == hashlib.sha256(text.encode()).hexdigest()[:32]


def test_a_run_reads_the_response_only_after_the_chain_loads_the_plate(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The plate is at rest until the pulse reaches it, so a run computes its response only from
    the chain's first load on (a sixth to a third of a run is the pulse's way down the chain),
    and a quarter of that lead longer. Any response that long gives the run to the bit, run on at
    once (the run finds the first load itself: no chain-only probe); one step shorter stops
    that run, which then starts again from the chain's first state, probes and computes the
    response again, to the same trace."""
    import solitonde.model.tiers.meshed as meshed
    from solitonde.model.scene import load_scene
    from solitonde.model.simulate import simulate

    scene = load_scene(None, ["plate.size=[0.3,0.3]", "plate.distance_to_support=0.05",
                              "plate.thickness=3.18e-3", "sem.elements=[8,8,1]",
                              "sem.elements_per_wavelength=0",
                              "effects.plate_model=mindlin_greens"])
    firsts = []

    def spy(*args: object) -> int:
        firsts.append(greens.first_load_step(*args))  # type: ignore[arg-type]
        return firsts[-1]

    monkeypatch.setattr(meshed, "first_load_step", spy)
    cache = greens.MemoryCache()
    first_run = simulate(scene, greens_cache=cache)
    steps, first = first_run.diagnostics["plate_steps"], firsts[0]
    assert 0.15 * steps < first < 0.35 * steps
    (key, stored), = cache._items.items()
    assert stored.size == steps - first + first // 4 + 1
    for length, reused in ((stored.size, True), (steps - first + 1, True),
                           (steps - first, False)):
        trimmed = greens.MemoryCache()
        trimmed.store(key, stored[:length])
        probes = len(firsts)
        again = simulate(scene, greens_cache=trimmed)
        assert again.diagnostics["greens_cached"] is reused, length
        assert len(firsts) == probes + (not reused)
        assert (again.diagnostics["greens_probe_s"] == 0.0) is reused
        assert again.samples.tobytes() == first_run.samples.tobytes()
        assert again.truth == first_run.truth


def test_a_run_the_pulse_never_reaches_stores_no_response() -> None:
    """A record that ends before the pulse reaches the plate needs no response: none is computed
    or stored, and the trace is the chain's alone."""
    from solitonde.model.scene import scene_from_dict
    from solitonde.model.simulate import simulate

    scene = scene_from_dict({"effects": {"plate_model": "greens"},
                             "sem": {"elements": [2, 2, 1], "order": [2, 2, 1],
                                     "contact_refinement": 0},
                             "plate": {"distance_to_support": 0.05},
                             "output": {"duration": 2e-4}})
    mine = greens.MemoryCache()
    run = simulate(scene, greens_cache=mine)
    assert len(mine) == 0 and run.diagnostics["greens_compute_s"] == 0.0
    assert np.isfinite(run.samples).all()


@pytest.mark.parametrize("make", [greens.MemoryCache, DiskGreensCache], ids=["memory", "disk"])
def test_a_store_keeps_the_longer_of_two_responses(make: type, tmp_path: Path) -> None:
    """Runs of one plate need responses of different lengths (each from its chain's first
    load on): a shorter one stored after a longer one (another process, another layer) must not
    replace it, a longer one does."""
    cache = make(tmp_path) if make is DiskGreensCache else make()
    long, short = np.arange(10.0), np.arange(6.0)
    cache.store("k", long)
    cache.store("k", short)
    np.testing.assert_array_equal(cache.load("k"), long)
    cache.store("k", np.arange(12.0))
    assert cache.load("k").size == 12
