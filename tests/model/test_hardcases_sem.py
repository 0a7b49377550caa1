"""Extreme scenes on the spectral-element plate tiers, long runs and float32 traces.

The chain-only extremes (D/t, v_imp, gravity, chain length, sensor position) live in
test_hardcases_chain.py; these cover where the plate is: on the clamped edge (L = 0), on a free
edge, meshes run at their stability limit, very long records, and float32 sensor data through the
signal package. Each asserts finite output, bounded energy and a stable step, or a clear error.
"""

from __future__ import annotations

import numpy as np
import pytest

from solitonde.model.errors import SimulationError
from solitonde.model.scene import STANDARD_GRAVITY, scene_from_dict
from solitonde.model.simulate import simulate
from solitonde.signal.errors import WaveformError
from solitonde.signal.features import extract
from solitonde.signal.waveform import Waveform

pytestmark = pytest.mark.hardcases

COARSE = {"preset": "paper", "elements": [8, 8, 1], "order": [3, 3, 2]}
"""Single-node load on a coarse mesh: cheap, and exact at L = 0 (the loaded node is clamped)."""


def _scene(plate_model="sem", sem=None, **sections):
    data = {"plate": {"thickness": 2.29e-3}, "effects": {"plate_model": plate_model},
            "sem": dict(COARSE if sem is None else sem)}
    for name, values in sections.items():
        data.setdefault(name, {}).update(values)
    return scene_from_dict(data)


def _sane(r, drift=1e-4):
    """Finite trace, no tension, forces below the all-energy-in-one-contact bound, energy kept."""
    s = r.scene
    assert np.isfinite(r.samples).all()
    assert r.samples.min() >= 0.0
    m = s.sphere_mass
    g = STANDARD_GRAVITY if s.effects.gravity else 0.0
    a = max(s.a_s, s.a_p)
    e_kin = 0.5 * m * s.impact_velocity**2
    bound = a * ((2.5 * e_kin / min(s.a_s, s.a_p)) ** 0.4
                 + (s.chain.n_particles * m * g / min(s.a_s, s.a_p)) ** (2 / 3)) ** 1.5
    assert r.samples.max() <= bound
    assert r.diagnostics["energy_drift"] < drift
    if "dt_stability_ratio" in r.diagnostics:
        assert 0.0 < r.diagnostics["dt_stability_ratio"] <= s.sem.step_factor * (1 + 1e-12)


def _features(r):
    return extract(Waveform(t0=r.t0, dt=r.dt, samples=r.samples))


@pytest.mark.parametrize("tier", ["sem", "greens"])
def test_chain_on_the_clamped_edge_is_the_halfspace(tier):
    """L = 0: the contact node is clamped, so the plate acts as a rigid half-space under Hertz."""
    r = simulate(_scene(tier, plate={"distance_to_support": 0.0}))
    _sane(r)
    half = simulate(_scene("halfspace", plate={"distance_to_support": 0.0}))
    assert r.truth["tof_s"] == pytest.approx(half.truth["tof_s"], rel=1e-5)
    assert r.truth["arr"] == pytest.approx(half.truth["arr"], rel=1e-5)


def test_chain_on_a_free_edge():
    """L = 0 with no support: the chain on a free edge, more mobile than the plate's interior.

    A free edge's point mobility exceeds the interior's, so the plate takes more of the energy and
    the reflection is weaker than at the centre of the same (unsupported) plate.
    """
    edge = simulate(_scene(plate={"distance_to_support": 0.0, "supports": "none"}))
    centre = simulate(_scene(plate={"distance_to_support": 0.457, "supports": "none"}))
    _sane(edge)
    _sane(centre)
    f_edge, f_centre = _features(edge), _features(centre)
    arr_edge = f_edge.arr if f_edge.arr is not None else f_edge.arr_upper_bound
    assert f_centre.arr is not None and arr_edge < f_centre.arr


@pytest.mark.parametrize(
    ("mesh", "plate"),
    [
        # coarse: 4 x 4 elements of order 2 on the paper's plate
        ({"preset": "paper", "elements": [4, 4, 1], "order": [2, 2, 1]},
         {"distance_to_support": 0.1}),
        # fine: 2 elements through the thickness of order 3 (nodes 0.38 mm apart) on a small plate
        ({"preset": "paper", "elements": [6, 6, 2], "order": [4, 4, 3]},
         {"size": [0.05, 0.05], "distance_to_support": 0.025}),
    ],
    ids=["coarse", "fine"],
)
def test_meshes_at_the_stability_limit(mesh, plate):
    """step_factor = 1 (the largest allowed) stays stable and agrees with half the step."""
    chain = {"n_particles": 3, "sensor_index": 1}  # the wave reaches the plate at once
    out = {"duration": 1.2e-4}
    at_limit = simulate(_scene(sem={**mesh, "step_factor": 1.0}, plate=plate, chain=chain,
                               output=out))
    half = simulate(_scene(sem={**mesh, "step_factor": 0.5}, plate=plate, chain=chain,
                           output=out))
    _sane(at_limit)
    _sane(half)
    assert at_limit.diagnostics["dt_stability_ratio"] > 0.5
    # central differences are second order: the two steps agree on the plate contact peak
    assert at_limit.truth["bottom_peak_N"] == pytest.approx(half.truth["bottom_peak_N"], rel=1e-3)


@pytest.mark.parametrize(("tier", "duration"), [("sem", 3e-3), ("infinite", 0.05)])
def test_very_long_records(tier, duration):
    """Records far past the reflection (many edge echoes; up to 100,000 samples) stay bounded.

    Velocity Verlet and central differences are symplectic: the energy error oscillates, it does
    not grow with the record length. The start of a long record is the short record itself.
    """
    sem = {"preset": "paper", "elements": [6, 6, 1], "order": [2, 2, 2]}
    r = simulate(_scene(tier, sem=sem, output={"duration": duration}))
    _sane(r)
    assert r.samples.size >= int(duration * 2e6)
    short = simulate(_scene(tier, sem=sem))
    n = short.samples.size
    assert np.allclose(r.samples[:n], short.samples, rtol=1e-9, atol=1e-9 * short.samples.max())


@pytest.mark.parametrize("tier", ["sem", "greens"])
def test_impossible_plate_requests_are_clear_errors(tier):
    """A record the step budget cannot cover fails with a clear error, not hours of running."""
    with pytest.raises(SimulationError, match="step_budget_exceeded"):
        simulate(_scene(tier, output={"duration": 100.0}))


@pytest.fixture(scope="module")
def trace():
    return simulate(_scene("infinite", plate={"thickness": 3.18e-3}))


@pytest.mark.parametrize("scale", [1.0, 1e-6, 1e6])
def test_float32_traces(trace, scale):
    """float32 sensor data (as digitisers write it) gives float64's features to float32 precision.

    At any scale (volts, millivolts, raw counts): detection is scale-free, and float32 keeps 24
    bits, so TOF moves by far less than a sample and ARR by about 1e-6 relative.
    """
    ref = extract(Waveform(t0=trace.t0, dt=trace.dt, samples=trace.samples * scale))
    single = (trace.samples * scale).astype(np.float32)
    f = extract(Waveform(t0=trace.t0, dt=trace.dt, samples=single))
    assert f.tof_s == pytest.approx(ref.tof_s, abs=0.01 * trace.dt)
    assert f.arr == pytest.approx(ref.arr, rel=1e-4)
    assert not f.flags


def test_float32_with_offset_and_bad_values(trace):
    """A large float32 offset costs resolution, not correctness; NaN in float32 is refused."""
    offset = np.float32(1e4)  # 1e4 N offset: float32 resolves about 1e-3 N there
    f = extract(Waveform(t0=trace.t0, dt=trace.dt,
                         samples=trace.samples.astype(np.float32) + offset))
    ref = extract(Waveform(t0=trace.t0, dt=trace.dt, samples=trace.samples))
    assert f.tof_s == pytest.approx(ref.tof_s, abs=0.05 * trace.dt)
    assert f.arr == pytest.approx(ref.arr, rel=1e-3)
    bad = trace.samples.astype(np.float32)
    bad[100] = np.nan
    with pytest.raises(WaveformError) as err:
        Waveform(t0=trace.t0, dt=trace.dt, samples=bad)
    assert err.value.field == "samples"
