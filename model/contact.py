"""Hertz contact constants and sphere properties (the paper's Sec. 3.1).

``F = A [delta]_+^(3/2)`` with delta the approach of the two bodies.
"""

from __future__ import annotations

from math import pi, sqrt

from .materials import Material


def sphere_mass(diameter: float, material: Material) -> float:
    """Mass of a solid sphere, kg."""
    return material.density * pi * diameter**3 / 6.0


def hertz_sphere_sphere(diameter: float, material: Material) -> float:
    """A_s for two identical spheres: E sqrt(D) / (3 (1 - nu^2)), N/m^(3/2)."""
    return material.youngs_modulus * sqrt(diameter) / (3.0 * (1.0 - material.poisson_ratio**2))


def hertz_two_spheres(diameter: float, a: Material, b: Material) -> float:
    """A for two spheres of one diameter and two materials: (4/3) E* sqrt(D/4) = (2/3) E* sqrt(D),
    N/m^(3/2) (effective radius D/4); :func:`hertz_sphere_sphere` when a and b are alike."""
    return 2.0 / 3.0 * effective_modulus(a, b) * sqrt(diameter)


def effective_modulus(a: Material, b: Material) -> float:
    """E* with 1/E* = (1 - nu_a^2)/E_a + (1 - nu_b^2)/E_b."""
    return 1.0 / (1.0 / a.plane_stress_modulus + 1.0 / b.plane_stress_modulus)


def hertz_sphere_flat(diameter: float, sphere: Material, flat: Material) -> float:
    """A_p for a sphere on a flat: (4/3) E* sqrt(D/2), N/m^(3/2)."""
    return 4.0 / 3.0 * effective_modulus(sphere, flat) * sqrt(diameter / 2.0)


def plate_bending_stiffness(thickness: float, plate: Material) -> float:
    """Kirchhoff bending stiffness D_p = E t^3 / (12 (1 - nu^2)), N m."""
    return plate.plane_stress_modulus * thickness**3 / 12.0


def plate_impedance(thickness: float, plate: Material) -> float:
    """Point impedance of an infinite thin plate, Z = 8 sqrt(rho t D_p), N s/m (Zener)."""
    return 8.0 * sqrt(plate.density * thickness * plate_bending_stiffness(thickness, plate))
