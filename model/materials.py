"""Isotropic linear-elastic materials for spheres and plates: a library, or given by properties.

A scene names a material from :data:`MATERIALS` or gives its properties (``{name,
youngs_modulus, poisson_ratio, density}``, SI units), which :func:`properties_from` checks. The
library's values are room-temperature handbook values; each entry names its source. The source
paper's set-up is 440C spheres on an Al 6061 plate.
"""

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
        # --- spheres -------------------------------------------------------------------------
        # 440C stainless steel spheres: the paper's values (Sec. 2).
        Material("steel_440c", 200e9, 0.28, 7800.0),
        # AISI 52100 chrome steel (bearing balls): ASM Handbook Vol. 1; MatWeb "AISI 52100".
        Material("steel_52100", 210e9, 0.30, 7810.0),
        # Tungsten carbide, WC with 6 % Co (carbide balls): MatWeb "Tungsten Carbide, 6% Co".
        Material("tungsten_carbide", 614e9, 0.22, 14900.0),
        # Soda-lime glass (glass balls and plates): MatWeb "Soda-Lime Glass".
        Material("glass", 72e9, 0.23, 2500.0),
        # --- plates (and brass spheres) ---------------------------------------------------------
        # Al 6061-T6 with the handbook density; the paper's own wave speeds need it (ASM
        # Aerospace Specification Metals, "Aluminum 6061-T6").
        Material("al_6061", 68.9e9, 0.33, 2700.0),
        # Al 6061 with the density the paper prints, to reproduce its printed numbers.
        Material("al_6061_paper", 68.9e9, 0.33, 2360.0),
        # Al 2024-T3: ASM Aerospace Specification Metals, "Aluminum 2024-T3".
        Material("al_2024_t3", 73.1e9, 0.33, 2780.0),
        # Al 7075-T6: ASM Aerospace Specification Metals, "Aluminum 7075-T6".
        Material("al_7075_t6", 71.7e9, 0.33, 2810.0),
        # Structural carbon steel ASTM A36: MatWeb "ASTM A36 Steel, plate".
        Material("steel_structural", 200e9, 0.26, 7850.0),
        # Stainless steel AISI 304: ASM Aerospace Specification Metals, "AISI Type 304".
        Material("steel_304", 193e9, 0.29, 8000.0),
        # Titanium Ti-6Al-4V (grade 5), annealed: ASM Aerospace Specification Metals.
        Material("ti_6al_4v", 113.8e9, 0.342, 4430.0),
        # Copper C11000 (electrolytic tough pitch): MatWeb "Copper, Cu; Annealed" / ASM.
        Material("copper", 115e9, 0.31, 8890.0),
        # Cartridge brass C26000: MatWeb "Brass, UNS C26000".
        Material("brass", 110e9, 0.375, 8530.0),
        # PMMA (cast acrylic sheet): MatWeb "Polymethyl Methacrylate (PMMA), cast".
        Material("pmma", 3.1e9, 0.37, 1190.0),
    )
}
"""The bundled library: spheres (440C, 52100, tungsten carbide, glass, brass) and plates."""
PROPERTY_KEYS = ("name", "youngs_modulus", "poisson_ratio", "density")
PROPERTY_RANGES = {"youngs_modulus": (1e6, 1e13, "Pa"), "density": (1.0, 1e5, "kg/m^3")}
"""Physical bounds of a material given by its properties: from soft rubber (1 MPa) past diamond
(1.05 TPa), from foams to beyond osmium (22,590 kg/m^3). Outside them no solid is meant, and the
contact laws under- or overflow (a modulus of 1e-300 Pa)."""


def properties_from(value: object) -> dict[str, object]:
    """A material given by name or by ``{name, youngs_modulus, poisson_ratio, density}``, as its
    property mapping; raises ValueError naming the key at fault (``[density] ...``)."""
    from collections.abc import Mapping
    from math import isfinite

    if isinstance(value, Material):
        return {k: getattr(value, k) for k in PROPERTY_KEYS}
    if isinstance(value, str):
        if value not in MATERIALS:
            raise ValueError(f"unknown material {value!r}; known: {', '.join(sorted(MATERIALS))}, "
                             "or a mapping {name, youngs_modulus, poisson_ratio, density}")
        return properties_from(MATERIALS[value])
    if not isinstance(value, Mapping):
        raise ValueError(f"expected a material name or a mapping {{{', '.join(PROPERTY_KEYS)}}}, "
                         f"got {type(value).__name__}")
    unknown = [str(k) for k in value if k not in PROPERTY_KEYS]
    if unknown:
        raise ValueError(f"[{unknown[0]}] unknown key (allowed: {', '.join(PROPERTY_KEYS)})")
    out: dict[str, object] = {"name": str(value.get("name") or "custom")[:80]}
    rules = {key: (f"{low:g} <= {key} <= {high:g} {unit}", lambda v, lo=low, hi=high: lo <= v <= hi)
             for key, (low, high, unit) in PROPERTY_RANGES.items()}
    rules["poisson_ratio"] = ("-1 < nu < 0.5", lambda v: -1.0 < v < 0.5)
    for key, (allowed, ok) in rules.items():
        if key not in value:
            raise ValueError(f"[{key}] missing (allowed: {allowed})")
        raw = value[key]
        try:
            number = float(raw) if not isinstance(raw, bool) else float("nan")
        except (TypeError, ValueError):
            number = float("nan")
        if not (isfinite(number) and ok(number)):
            raise ValueError(f"[{key}] {raw!r} is out of range (allowed: {allowed})")
        out[key] = number
    return out


def material_of(spec: object, field: str = "material") -> Material:
    """The Material a scene's ``material`` entry means: a library name or a property mapping."""
    if isinstance(spec, str):
        return get_material(spec, field)
    try:
        props = properties_from(spec)
    except ValueError as exc:
        raise SceneError(field, str(exc)) from None
    return Material(str(props["name"]), float(props["youngs_modulus"]),  # type: ignore[arg-type]
                    float(props["poisson_ratio"]), float(props["density"]))  # type: ignore[arg-type]


def get_material(name: str, field: str = "material") -> Material:
    """Look up a material by key; unknown keys raise a SceneError listing the known ones."""
    try:
        return MATERIALS[name]
    except KeyError:
        raise SceneError(
            field, f"unknown material {name!r}", allowed=", ".join(sorted(MATERIALS))
        ) from None
