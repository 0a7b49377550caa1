"""Zener's impact model for very inelastic impacts (large lambda) and vanishing plates."""

from __future__ import annotations

import numpy as np
import pytest

from solitonde.model import zener as z
from solitonde.model.errors import SceneError
from solitonde.model.scene import scene_from_dict


def test_large_lambda_law_matches_integration():
    """Beyond ASYMPTOTIC_LAMBDA, e = C lambda^-5 and tau_c = lambda (5 ln lambda + C') agree with
    the compiled DOP853 (rtol 1e-12) to 1e-6, the accuracy the fast path promises."""
    lams = np.array([2000.0, 5000.0])
    e, tau = z.restitution_and_contact_time_many(lams)
    e_int, tau_int = z._integrate_compiled(lams)
    np.testing.assert_allclose(e, e_int, rtol=1e-6)
    np.testing.assert_allclose(tau, tau_int, rtol=1e-6)


def test_very_inelastic_impacts_end():
    """lambda = 3e4 (a 10 um plate under the default sphere) exhausted the integrator's 1e7 steps;
    it and larger lambdas follow the scaling law: e lambda^5 and tau_c / lambda - 5 ln lambda are
    the same constants as at the anchor, and the reference path gives the same numbers."""
    lams = np.array([3e4, 1e6, 1e30])
    e, tau = z.restitution_and_contact_time_many(lams)
    e0, tau0 = z._integrate_compiled(np.array([z.ASYMPTOTIC_LAMBDA]))
    np.testing.assert_allclose(e * lams**5, e0[0] * z.ASYMPTOTIC_LAMBDA**5, rtol=1e-12)
    np.testing.assert_allclose(tau / lams - 5.0 * np.log(lams),
                               tau0[0] / z.ASYMPTOTIC_LAMBDA - 5.0 * np.log(z.ASYMPTOTIC_LAMBDA),
                               rtol=1e-10)
    assert z.restitution_and_contact_time(3e4) == (float(e[0]), float(tau[0]))


def test_thin_plate_theory_is_finite():
    """theory on a 10 um plate (lambda ~ 6e4) answers: no reflection (ARR ~ 0), a long contact."""
    p = z.predict(scene_from_dict({"plate": {"thickness": 1e-5}}))
    assert p.lambda_ > 5e4
    assert 0.0 <= p.arr < 1e-20
    assert np.isfinite(p.tof_s) and p.tof_s > p.contact_time_s > 1.0


def test_vanishing_thickness_is_a_scene_error():
    """A thickness whose impedance underflows to 0 was a ZeroDivisionError (HTTP 500); now a
    SceneError naming plate.thickness (the scene's floor of 10 um refuses it first)."""
    with pytest.raises(SceneError) as info:
        z.predict(scene_from_dict({"plate": {"thickness": 1e-100}}))
    assert info.value.field == "plate.thickness"
