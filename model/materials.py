"""Isotropic linear-elastic materials used for spheres and plates (PHYSICS.md section 1)."""

from __future__ import annotations

from dataclasses import dataclass
from math import sqrt

from .errors import SceneError


@dataclass(frozen=True)
class Material:
    """An isotropic elastic solid.

    Parameters
    ----------
    name: library key.
    youngs_modulus: E in Pa.
    poisson_ratio: nu, dimensionless, in (-1, 0.5).
    density: rho in kg/m^3.
    """

    name: str
    youngs_modulus: float
    poisson_ratio: float
    density: float

    @property
    def plane_stress_modulus(self) -> float:
        """E / (1 - nu^2), the stiffness that enters Hertz contact and plate bending."""
        return self.youngs_modulus / (1.0 - self.poisson_ratio**2)

    @property
    def bar_velocity(self) -> float:
        """sqrt(E / rho), the reference speed of Eq. 17 (c = k sqrt(E/rho))."""
        return sqrt(self.youngs_modulus / self.density)

    @property
    def plate_velocity(self) -> float:
        """sqrt(E / (rho (1 - nu^2))): low-frequency limit of the S0 Lamb mode."""
        return sqrt(self.plane_stress_modulus / self.density)

    @property
    def shear_modulus(self) -> float:
        """G = E / (2 (1 + nu))."""
        return self.youngs_modulus / (2.0 * (1.0 + self.poisson_ratio))

    @property
    def lame_lambda(self) -> float:
        """First Lamé parameter."""
        e, nu = self.youngs_modulus, self.poisson_ratio
        return e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))

    @property
    def longitudinal_velocity(self) -> float:
        """Bulk P-wave speed c_L = sqrt((lambda + 2 G) / rho)."""
        return sqrt((self.lame_lambda + 2.0 * self.shear_modulus) / self.density)

    @property
    def shear_velocity(self) -> float:
        """Bulk S-wave speed c_T = sqrt(G / rho)."""
        return sqrt(self.shear_modulus / self.density)


MATERIALS: dict[str, Material] = {
    m.name: m
    for m in (
        # 440C stainless steel spheres (paper Sec. 2).
        Material("steel_440c", 200e9, 0.28, 7800.0),
        # Al 6061 with the handbook density; the paper's own wave speeds need it (PHYSICS.md 1).
        Material("al_6061", 68.9e9, 0.33, 2700.0),
        # Al 6061 with the density the paper prints, to reproduce its printed numbers.
        Material("al_6061_paper", 68.9e9, 0.33, 2360.0),
    )
}


def get_material(name: str, field: str = "material") -> Material:
    """Look up a material by key; unknown keys raise a SceneError listing the known ones."""
    try:
        return MATERIALS[name]
    except KeyError:
        raise SceneError(
            field, f"unknown material {name!r}", allowed=", ".join(sorted(MATERIALS))
        ) from None
