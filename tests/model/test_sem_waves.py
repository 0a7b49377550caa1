"""Guided waves in the spectral-element plate travel at the Lamb group velocities."""

from __future__ import annotations

import numpy as np
import pytest

from solitonde.model.contact import plate_bending_stiffness
from solitonde.model.lamb import lamb_dispersion
from solitonde.model.materials import MATERIALS
from solitonde.model.mesh import plate_mesh
from solitonde.model.sem import build_plate

AL = MATERIALS["al_6061"]
THICKNESS = 3.18e-3


def _group_velocity(s1: np.ndarray, s2: np.ndarray, dx: float, f0: float, dt: float) -> float:
    """dx over the group delay d(phase)/d(omega) of the cross spectrum, fitted within f0 +- 15 %."""
    n = 1 << 16
    spec1, spec2 = np.fft.rfft(s1, n), np.fft.rfft(s2, n)
    f = np.fft.rfftfreq(n, dt)
    band = (f > 0.85 * f0) & (f < 1.15 * f0)
    phase = np.unwrap(np.angle(spec1[band] * np.conj(spec2[band])))
    delay = np.polyfit(2 * np.pi * f[band], phase, 1)[0]
    return dx / delay


@pytest.fixture(scope="module")
def plate():
    """Free 0.56 x 0.5 m plate (half model), 12.4 mm elements of order 4: >= 8 nodes per A0
    wavelength at 40 kHz. Source 0.25 m from the near edge: no reflection reaches the probes
    before the bursts have passed (paths >= 0.5 m)."""
    mesh = plate_mesh((0.56, 0.5), THICKNESS, (45, 40, 1), (4, 4, 2), 0.25, symmetry=True)
    return build_plate(mesh, AL, "none")


@pytest.mark.parametrize(("mode", "f0", "duration", "component"),
                         [("A0", 30e3, 260e-6, 2), ("S0", 100e3, 90e-6, 0)])
def test_arrivals_follow_lamb_group_velocity(plate, mode, f0, duration, component) -> None:
    """A 5-cycle tone burst of vertical force at the top surface; probes 60 and 120 mm away on
    the centre line. The plate-symmetric part (mean of top and bottom in-plane displacement) is
    S0 only, the antisymmetric part (mean vertical displacement) A0 only. Their group velocity
    at f0 matches the Rayleigh-Lamb value within 3 %; for A0 the Kirchhoff value, 2 c_phase,
    is 10 % off, so the check tells the 3D plate from thin-plate theory."""
    mesh = plate.mesh
    dt = 0.9 * 2 / np.sqrt(plate.element_bound)
    n = int(duration / dt)
    t = np.arange(n) * dt
    cycles = 5 / f0
    force = np.where(t < cycles, np.sin(2 * np.pi * f0 * t) * np.sin(np.pi * t / cycles) ** 2, 0)
    ax, ay, az = mesh.axes
    dofs, where = [], []
    for d in (0.06, 0.12):
        i = int(np.argmin(np.abs(ax - (0.25 + d))))
        where.append(ax[i])
        for k in (az.size - 1, 0):
            dofs.append(3 * int(mesh.node_index(i, ay.size - 1, k)) + component)
    rec = plate.run_point_force(force, dt, np.array(dofs))
    s1 = 0.5 * (rec[:, 0] + rec[:, 1])
    s2 = 0.5 * (rec[:, 2] + rec[:, 3])
    measured = _group_velocity(s1, s2, where[1] - where[0], f0, dt)
    lamb = float(lamb_dispersion(THICKNESS, AL, np.array([f0])).group_velocity[mode][0])
    assert measured == pytest.approx(lamb, rel=0.03)
    if mode == "A0":
        d_p = plate_bending_stiffness(THICKNESS, AL)
        kirchhoff = 2 * np.sqrt(2 * np.pi * f0) * (d_p / (AL.density * THICKNESS)) ** 0.25
        assert abs(measured / kirchhoff - 1) > 0.05
