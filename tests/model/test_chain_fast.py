"""The chain's fast paths agree with the reference forms they replace.

* the fused leapfrog driver (no dissipation) against the step-by-step driver built from the
  :mod:`~solitonde.model.chain` kernels, on every wall/dashpot tier, gravity on and off, traces on;
* the scalar Zener table lookup used to size a run against the vectorised one;
* the batch backends (threads, processes) against serial runs;
* the coarse-resolution knob: the dashpot step limit follows ``steps_per_period``.
"""

from __future__ import annotations

import numpy as np
import pytest

from solitonde.model.batch import scene_grid, simulate_many
from solitonde.model.chain import new_peak_tracker
from solitonde.model.plan import (
    DASHPOT_STEP_FRACTION,
    DASHPOT_STEP_FRACTION_MAX,
    STEPS_PER_PERIOD,
    choose_time_step,
)
from solitonde.model.record import chain_record
from solitonde.model.scene import STANDARD_GRAVITY, scene_from_dict
from solitonde.model.simulate import initial_state, simulate
from solitonde.model.tiers import make_boundary
from solitonde.model.tiers.dashpot import dashpot_run, dashpot_steps_run
from solitonde.model.zener import (
    restitution_and_contact_time_many,
    restitution_and_contact_time_one,
)


def _run(driver, scene, dt, n_sub, n_samples, traces):
    b = make_boundary(scene)
    n, m = scene.chain.n_particles, scene.sphere_mass
    g = STANDARD_GRAVITY if scene.effects.gravity else 0.0
    u, v = initial_state(n, m, g, scene.a_s, b.a_bottom, scene.impact_velocity)
    inv_z = 1.0 / b.impedance if b.name == "infinite" else 0.0
    rows = n_samples if traces else 0
    out = {k: np.empty((rows, n + 1)) for k in ("u", "v", "f")}
    out["w"] = np.empty(rows)
    samples, energy, pk = np.empty(n_samples), np.empty(n_samples), new_peak_tracker()
    record = chain_record(u, v, u.copy(), m, g, scene.a_s, b.a_bottom, n * m * g, 0.0,
                          scene.chain.sensor_index, samples, energy, out["u"], out["v"],
                          out["f"], out["w"], pk)
    status, done, w, work, _dissipated = driver(record, 0.0, inv_z, dt, n_sub, n_samples)
    assert status == 0 and done == n_samples
    return samples, energy, pk, w, work, out


@pytest.mark.parametrize("plate_model", ["rigid", "halfspace", "infinite"])
@pytest.mark.parametrize("gravity", [False, True])
def test_fused_driver_matches_step_by_step(plate_model, gravity):
    """Same scheme, rearranged: traces, energies, peaks and plate work agree to rounding."""
    scene = scene_from_dict({"effects": {"plate_model": plate_model, "gravity": gravity}})
    dt, n_sub = choose_time_step(scene, make_boundary(scene), 400)
    args = (scene, dt, n_sub, 700, True)
    fast = _run(dashpot_run, *args)
    ref = _run(dashpot_steps_run, *args)
    scale = np.abs(ref[0]).max()
    assert scale > 0.0
    np.testing.assert_allclose(fast[0], ref[0], rtol=0, atol=1e-11 * scale)
    e_scale = np.abs(ref[1]).max()
    np.testing.assert_allclose(fast[1], ref[1], rtol=0, atol=1e-11 * e_scale)
    np.testing.assert_allclose(fast[2], ref[2], rtol=1e-9)
    assert fast[3] == pytest.approx(ref[3], rel=1e-9, abs=1e-18)
    assert fast[4] == pytest.approx(ref[4], rel=1e-9, abs=1e-18)
    for key in ("u", "v", "f"):
        np.testing.assert_allclose(fast[5][key], ref[5][key], rtol=0,
                                   atol=1e-10 * np.abs(ref[5][key]).max())


def test_scalar_zener_lookup_matches_table():
    """restitution_and_contact_time_one is the vectorised table to rounding, and falls back
    to the ODE beyond the table."""
    lams = np.concatenate([[0.0, 1e-9, 1.0, 19.999, 20.0],
                           np.random.default_rng(3).uniform(0.0, 20.0, 50)])
    e, tau = restitution_and_contact_time_many(lams)
    one = np.array([restitution_and_contact_time_one(x) for x in lams])
    np.testing.assert_allclose(one[:, 0], e, rtol=1e-13)
    np.testing.assert_allclose(one[:, 1], tau, rtol=1e-13)
    e_far, tau_far = restitution_and_contact_time_many([25.0])
    assert restitution_and_contact_time_one(25.0) == pytest.approx((e_far[0], tau_far[0]))


@pytest.mark.parametrize("backend", ["threads", "processes"])
def test_batch_backends_match_serial(backend):
    """Both parallel backends return the serial results, in order, with their scenes."""
    scenes = scene_grid({"effects": {"plate_model": "infinite"}},
                        {"chain.diameter": [4.76e-3, 9.53e-3],
                         "plate.thickness": [2.29e-3, 4.83e-3]})
    many = simulate_many(scenes, workers=2, backend=backend, steps_per_period=200)
    for scene, result in zip(scenes, many, strict=True):
        one = simulate(scene, steps_per_period=200)
        assert result.scene == scene
        np.testing.assert_array_equal(result.samples, one.samples)
        assert result.truth == one.truth


def test_dashpot_limit_follows_steps_per_period():
    """Coarser steps per period loosen the dashpot limit in proportion, up to its ceiling.

    D/t = 12, where the dashpot limit is the binding one; a slow sample rate so that the step
    is not rounded much to fit the sample interval.
    """
    scene = scene_from_dict({"effects": {"plate_model": "infinite"},
                             "plate": {"thickness": 0.794e-3}, "output": {"sample_rate": 1e5}})
    b = make_boundary(scene)
    dt_default, _ = choose_time_step(scene, b)
    dt_coarse, _ = choose_time_step(scene, b, STEPS_PER_PERIOD // 4)
    assert dt_coarse == pytest.approx(4 * dt_default, rel=1e-2)
    # One step per period would allow 1600 x the default; the ceiling allows 40 x.
    ceiling = DASHPOT_STEP_FRACTION_MAX / DASHPOT_STEP_FRACTION
    dt_floor, n_sub = choose_time_step(scene, b, 1)
    assert ceiling * (1 - 1.0 / n_sub) < dt_floor / dt_default <= ceiling * (1 + 1e-3)
