"""Isotropic linear-elastic materials for spheres and plates: a library, or given by properties.

A scene names a material from :data:`MATERIALS` or gives its properties (``{name,
youngs_modulus, poisson_ratio, density}``, SI units), which :func:`properties_from` checks. The
library's values are room-temperature handbook values; each entry names its source. The source
paper's set-up is 440C spheres on an Al 6061 plate.

A material also states how well a user who names it knows its properties: the spread of a plate
bought as "structural steel" or "6061-T6" (:data:`SPREAD_KEYS`: the relative standard deviation
of E and of rho, the standard deviation of nu). The library's spreads are the handbooks' ranges
for the grade read as uniform, measured about the entry's own value, which a table built with the
entry assumes: the root-mean-square distance from it, ``sqrt(w^2 / 12 + (c - value)^2)`` for a
range of width w and centre c (:func:`spread_about`). Where the value is the range's centre that
is the uniform's standard deviation; where it is not (A36's nu: 0.26 in 0.25-0.30), a plate of
the grade lies further from the table's value than the range's width alone says (0.021, not
0.014). Each entry names the range it comes from. A property mapping may state its own
(``youngs_modulus_rel_sd`` ...); a material given by properties without them is taken as known
exactly. The inversion propagates the plate's spread into its intervals (instrument.inference).
"""

from __future__ import annotations

from collections.abc import Callable
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
    youngs_modulus_rel_sd, poisson_ratio_sd, density_rel_sd: the spread of the grade (relative
        for E and rho, absolute for nu); 0 when the properties are known exactly.
    """

    name: str
    youngs_modulus: float
    poisson_ratio: float
    density: float
    youngs_modulus_rel_sd: float = 0.0
    poisson_ratio_sd: float = 0.0
    density_rel_sd: float = 0.0

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


def spread_about(value: float, low: float, high: float, relative: bool = True) -> float:
    """The root-mean-square distance of a property uniform on [``low``, ``high``] from ``value``
    (relative to ``value`` when ``relative``): the spread a user who names the grade has about
    the library's value."""
    centre = 0.5 * (low + high)
    rms = sqrt((high - low) ** 2 / 12.0 + (centre - value) ** 2)
    return rms / value if relative else rms


def _graded(name: str, e: float, nu: float, rho: float, e_range: tuple[float, float],
            nu_range: tuple[float, float], rho_range: tuple[float, float] | float) -> Material:
    """A library entry whose spreads come from its grade's ranges (:func:`spread_about`); a
    number for ``rho_range`` is the density's relative spread where no range is stated."""
    rho_sd = (rho_range if isinstance(rho_range, float)
              else spread_about(rho, *rho_range))
    return Material(name, e, nu, rho, spread_about(e, *e_range),
                    spread_about(nu, *nu_range, relative=False), rho_sd)


MATERIALS: dict[str, Material] = {
    m.name: m
    for m in (
        # --- spheres -------------------------------------------------------------------------
        # 440C stainless steel spheres: the paper's values (Sec. 2).
        # Spread: 440C balls, E 200-204 GPa, nu 0.28-0.30 (ASM; AISI 440C datasheets).
        _graded("steel_440c", 200e9, 0.28, 7800.0, (200e9, 204e9), (0.28, 0.30), 0.002),
        # AISI 52100 chrome steel (bearing balls): ASM Handbook Vol. 1; MatWeb "AISI 52100".
        # Spread: E 201-210 GPa, nu 0.27-0.30 (ASM; MatWeb).
        _graded("steel_52100", 210e9, 0.30, 7810.0, (201e9, 210e9), (0.27, 0.30), 0.002),
        # Tungsten carbide, WC with 6 % Co (carbide balls): MatWeb "Tungsten Carbide, 6% Co".
        # Spread: 6 % Co grades, E 600-650 GPa, nu 0.21-0.24, rho 14,800-15,000 (MatWeb).
        _graded("tungsten_carbide", 614e9, 0.22, 14900.0, (600e9, 650e9), (0.21, 0.24),
                (14800.0, 15000.0)),
        # Soda-lime glass (glass balls and plates): MatWeb "Soda-Lime Glass".
        # Spread: soda-lime, E 69-74 GPa, nu 0.21-0.25, rho 2,440-2,520 (MatWeb).
        _graded("glass", 72e9, 0.23, 2500.0, (69e9, 74e9), (0.21, 0.25), (2440.0, 2520.0)),
        # --- plates (and brass spheres) ---------------------------------------------------------
        # Al 6061-T6 with the handbook density; the paper's own wave speeds need it (ASM
        # Aerospace Specification Metals, "Aluminum 6061-T6").
        # Spread: E 68.0-70.0 GPa (MMPDS: 68.3 tension, 69.6 compression), nu 0.32-0.35,
        # rho 2,690-2,720 (ASM; MatWeb "6061-T6").
        _graded("al_6061", 68.9e9, 0.33, 2700.0, (68e9, 70e9), (0.32, 0.35), (2690.0, 2720.0)),
        # Al 6061 with the density the paper prints, to reproduce its printed numbers.
        # Its spreads are al_6061's (the printed density lies outside 6061's range).
        Material("al_6061_paper", 68.9e9, 0.33, 2360.0,
                 spread_about(68.9e9, 68e9, 70e9), spread_about(0.33, 0.32, 0.35, relative=False),
                 spread_about(2700.0, 2690.0, 2720.0)),
        # Al 2024-T3: ASM Aerospace Specification Metals, "Aluminum 2024-T3".
        # Spread: E 72.4-73.8 GPa, nu 0.33 +- 0.015, rho 2,770-2,790 (ASM; MMPDS).
        _graded("al_2024_t3", 73.1e9, 0.33, 2780.0, (72.4e9, 73.8e9), (0.315, 0.345),
                (2770.0, 2790.0)),
        # Al 7075-T6: ASM Aerospace Specification Metals, "Aluminum 7075-T6".
        # Spread: E 71.0-72.4 GPa, nu 0.32-0.35, rho 2,800-2,810 (ASM; MMPDS).
        _graded("al_7075_t6", 71.7e9, 0.33, 2810.0, (71.0e9, 72.4e9), (0.32, 0.35),
                (2800.0, 2810.0)),
        # Structural carbon steel ASTM A36: MatWeb "ASTM A36 Steel, plate".
        # Spread: structural carbon steels, E 190-210 GPa (ASM; EN 1993-1-1 takes 210 GPa, AISC
        # 200 GPa), nu 0.25-0.30 (MatWeb A36 0.26; EN 1993-1-1 0.30), rho 7,800-7,870.
        _graded("steel_structural", 200e9, 0.26, 7850.0, (190e9, 210e9), (0.25, 0.30),
                (7800.0, 7870.0)),
        # Stainless steel AISI 304: ASM Aerospace Specification Metals, "AISI Type 304".
        # Spread: E 190-203 GPa, nu 0.27-0.30, rho 7,900-8,030 (ASM; MatWeb "AISI 304").
        _graded("steel_304", 193e9, 0.29, 8000.0, (190e9, 203e9), (0.27, 0.30), (7900.0, 8030.0)),
        # Titanium Ti-6Al-4V (grade 5), annealed: ASM Aerospace Specification Metals.
        # Spread: E 110-119 GPa, nu 0.31-0.37, rho 4,420-4,430 (ASM; MatWeb "Ti-6Al-4V").
        _graded("ti_6al_4v", 113.8e9, 0.342, 4430.0, (110e9, 119e9), (0.31, 0.37),
                (4420.0, 4430.0)),
        # Copper C11000 (electrolytic tough pitch): MatWeb "Copper, Cu; Annealed" / ASM.
        # Spread: E 110-128 GPa, nu 0.31-0.34, rho 8,890-8,940 (ASM; MatWeb "C11000").
        _graded("copper", 115e9, 0.31, 8890.0, (110e9, 128e9), (0.31, 0.34), (8890.0, 8940.0)),
        # Cartridge brass C26000: MatWeb "Brass, UNS C26000".
        # Spread: E 100-110 GPa, nu 0.33-0.38, rho 8,470-8,550 (MatWeb "C26000").
        _graded("brass", 110e9, 0.375, 8530.0, (100e9, 110e9), (0.33, 0.38), (8470.0, 8550.0)),
        # PMMA (cast acrylic sheet): MatWeb "Polymethyl Methacrylate (PMMA), cast".
        # Spread: cast sheet, E 2.4-3.4 GPa, nu 0.35-0.40, rho 1,170-1,200 (MatWeb).
        _graded("pmma", 3.1e9, 0.37, 1190.0, (2.4e9, 3.4e9), (0.35, 0.40), (1170.0, 1200.0)),
    )
}
"""The bundled library: spheres (440C, 52100, tungsten carbide, glass, brass) and plates."""
PROPERTY_KEYS = ("name", "youngs_modulus", "poisson_ratio", "density")
SPREAD_KEYS = ("youngs_modulus_rel_sd", "poisson_ratio_sd", "density_rel_sd")
"""The optional spread of a material given by properties (relative sd of E and rho, sd of nu)."""
SPREAD_MAX = {"youngs_modulus_rel_sd": 0.5, "poisson_ratio_sd": 0.2, "density_rel_sd": 0.5}
"""Largest spread a mapping may state: beyond it the linearised propagation means nothing."""
PROPERTY_RANGES = {"youngs_modulus": (1e6, 1e13, "Pa"), "density": (1.0, 1e5, "kg/m^3")}
"""Physical bounds of a material given by its properties: from soft rubber (1 MPa) past diamond
(1.05 TPa), from foams to beyond osmium (22,590 kg/m^3). Outside them no solid is meant, and the
contact laws under- or overflow (a modulus of 1e-300 Pa)."""


def _within(low: float, high: float) -> Callable[[float], bool]:
    """The check ``low <= v <= high``."""
    return lambda v: low <= v <= high


def properties_from(value: object) -> dict[str, object]:
    """A material given by name or by ``{name, youngs_modulus, poisson_ratio, density}``, as its
    property mapping; raises ValueError naming the key at fault (``[density] ...``)."""
    from collections.abc import Mapping
    from math import isfinite

    if isinstance(value, Material):
        return {k: getattr(value, k) for k in PROPERTY_KEYS}
    # (a library material's spread is looked up by :func:`material_spread`, not copied here: a
    # table's family compares properties only)
    if isinstance(value, str):
        if value not in MATERIALS:
            raise ValueError(f"unknown material {value!r}; known: {', '.join(sorted(MATERIALS))}, "
                             "or a mapping {name, youngs_modulus, poisson_ratio, density}")
        return properties_from(MATERIALS[value])
    if not isinstance(value, Mapping):
        raise ValueError(f"expected a material name or a mapping {{{', '.join(PROPERTY_KEYS)}}}, "
                         f"got {type(value).__name__}")
    unknown = [str(k) for k in value if k not in PROPERTY_KEYS + SPREAD_KEYS]
    if unknown:
        raise ValueError(f"[{unknown[0]}] unknown key (allowed: "
                         f"{', '.join(PROPERTY_KEYS + SPREAD_KEYS)})")
    out: dict[str, object] = {"name": str(value.get("name") or "custom")[:80]}
    rules: dict[str, tuple[str, Callable[[float], bool]]] = {
        key: (f"{low:g} <= {key} <= {high:g} {unit}", _within(low, high))
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
    for key in SPREAD_KEYS:
        if value.get(key) is None:
            continue
        raw = value[key]
        try:
            number = float(raw) if not isinstance(raw, bool) else float("nan")
        except (TypeError, ValueError):
            number = float("nan")
        if not (isfinite(number) and 0.0 <= number <= SPREAD_MAX[key]):
            raise ValueError(f"[{key}] {raw!r} is out of range (allowed: 0 <= {key} <= "
                             f"{SPREAD_MAX[key]:g})")
        out[key] = number
    return out


DEFAULT_PROPERTY_SPREAD = {"youngs_modulus_rel_sd": 0.03, "poisson_ratio_sd": 0.02,
                           "density_rel_sd": 0.01}
"""The spread of a material given by its properties without one (1 sd): a wide grade's. The
library's widest metal plate grade, structural steel, has E +- 2.9 % and nu +- 0.021 about its
value; densities are known to a percent. A user states the spread (0 where the properties are
measured) to replace it; every answer carrying it says so."""


def is_default_spread(spread: object) -> bool:
    """Whether ``spread`` is :data:`DEFAULT_PROPERTY_SPREAD` (by value: the spread a material
    given by its properties alone gets)."""
    from collections.abc import Mapping

    return isinstance(spread, Mapping) and all(
        spread.get(k) == v for k, v in DEFAULT_PROPERTY_SPREAD.items())


def material_spread(props: object) -> dict[str, float]:
    """The spread of a material (:data:`SPREAD_KEYS`): the one a property mapping states, else
    the library's for a library name whose properties it has (a table's family records the
    properties it was built with), else, for properties alone, the stated default
    (:data:`DEFAULT_PROPERTY_SPREAD`); none (0) where there is no material at all."""
    from collections.abc import Mapping
    from math import isclose

    if isinstance(props, str):
        props = properties_from(props)
    if isinstance(props, Material):
        return {k: float(getattr(props, k)) for k in SPREAD_KEYS}
    if not isinstance(props, Mapping):
        return dict.fromkeys(SPREAD_KEYS, 0.0)
    if any(props.get(k) is not None for k in SPREAD_KEYS):
        return {k: float(props.get(k) or 0.0) for k in SPREAD_KEYS}
    known = MATERIALS.get(str(props.get("name")))
    if known is not None and all(
            isclose(float(props.get(k, float("nan"))), getattr(known, k), rel_tol=1e-6)
            for k in ("youngs_modulus", "poisson_ratio", "density")):
        return {k: float(getattr(known, k)) for k in SPREAD_KEYS}
    if props.get("youngs_modulus") is None:  # not a material's properties
        return dict.fromkeys(SPREAD_KEYS, 0.0)
    return dict(DEFAULT_PROPERTY_SPREAD)


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
