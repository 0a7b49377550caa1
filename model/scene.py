"""The scene: one validated description of an experiment (the paper's Sec. 2 set-up as defaults).

A scene has the sections ``chain``, ``striker``, ``plate``, ``effects``, ``output`` (and the
optional ``sem`` and ``solver``). It is loaded from YAML or JSON, overridden with dotted keys
(``plate.thickness=3.18e-3``) and validated in one place; every bad input raises
:class:`SceneError` naming the field and what is allowed.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from math import isfinite, sqrt
from pathlib import Path
from typing import Annotated, Any, Literal, NamedTuple, TypedDict, cast

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    StrictBool,
    ValidationError,
    model_validator,
)

from .contact import (
    hertz_sphere_flat,
    hertz_sphere_sphere,
    hertz_two_spheres,
    plate_impedance,
    sphere_mass,
)
from .errors import SceneError
from .materials import Material, material_of, properties_from

STANDARD_GRAVITY = 9.80665  # m/s^2

PLATE_MODELS = ("rigid", "halfspace", "infinite", "sem", "greens", "mindlin", "mindlin_greens",
                "auto")
"""What ``effects.plate_model`` accepts (its schema's Literal spells them again, as pydantic and
the type checker need; tests/model/test_tiers.py holds the two and the tier registry together)."""
SUPPORTS = ("opposite_edges", "all_edges", "none")
MAX_PLATE_SIZE = 100.0  # m, per in-plane side; beyond it no mesh or Green's function is sane


class SceneDict(TypedDict, total=False):
    """A scene as files and tables hold it: a mapping of its sections, each ``{key: value}``
    with the keys of the section's spec below. Not validated: :func:`scene_from_dict` checks
    the values and names the first bad one."""

    chain: dict[str, Any]
    striker: dict[str, Any]
    plate: dict[str, Any]
    effects: dict[str, Any]
    output: dict[str, Any]
    sem: dict[str, Any]
    solver: dict[str, Any]


def _finite(value: float) -> float:
    """Refuse NaN and infinity: no scene quantity is meaningful there, and a NaN passes every
    ``gt``/``le`` bound unnoticed while an infinity reaches the solvers (huge meshes, endless
    loops). The one check every float field of the scene goes through."""
    if not isfinite(value):
        raise ValueError(f"must be a finite number, got {value!r}")
    return value


def _number(value: Any) -> Any:
    """Accept finite ints, floats and numeric strings; refuse booleans (pydantic would read True
    as 1), NaN and infinity."""
    if isinstance(value, bool):
        raise ValueError("expected a number, got a boolean")
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            raise ValueError(f"expected a number, got {value!r}") from None
    if isinstance(value, int | float):
        try:
            _finite(float(value))
        except OverflowError:
            raise ValueError(f"must be a finite number, got {value!r}") from None
    return value


def _integer(value: Any) -> Any:
    """Accept whole numbers only; refuse booleans and fractional values."""
    if isinstance(value, bool):
        raise ValueError("expected an integer, got a boolean")
    if isinstance(value, float) and not value.is_integer():
        raise ValueError(f"expected an integer, got {value}")
    return value


def _material(value: Any) -> Any:
    """A library name stays a name; a mapping of properties is checked and kept as a mapping."""
    if isinstance(value, str):
        properties_from(value)  # raises for an unknown name, listing the known ones
        return value
    return properties_from(value)


def _duration(value: Any) -> Any:
    if value == "auto":
        return value
    if isinstance(value, bool) or not isinstance(value, int | float | str):
        raise ValueError(f"must be 'auto' or a positive number of seconds, got {value!r}")
    try:
        seconds = float(value)
    except (ValueError, OverflowError):
        raise ValueError(f"must be 'auto' or a positive number of seconds, got {value!r}") from None
    if not (isfinite(seconds) and seconds > 0):
        raise ValueError(f"must be 'auto' or a positive finite number of seconds, got {value!r}")
    return seconds


def _contact_radius(value: Any) -> Any:
    message = f"must be 'auto' or a radius in metres, 0 <= r <= 0.05, got {value!r}"
    if value == "auto":
        return value
    if isinstance(value, bool) or not isinstance(value, int | float | str):
        raise ValueError(message)
    try:
        radius = float(value)
    except (ValueError, OverflowError):
        raise ValueError(message) from None
    if not (isfinite(radius) and 0.0 <= radius <= 0.05):
        raise ValueError(message)
    return radius


def _plate_side(value: Any) -> Any:
    """A plate side: a finite number (the range is checked with the whole plate)."""
    try:
        return _number(value)
    except ValueError as exc:
        raise ValueError(f"{exc} (allowed: 0 < size <= {MAX_PLATE_SIZE:g} m per side)") from None


Number = Annotated[float, BeforeValidator(_number)]
PlateSide = Annotated[float, BeforeValidator(_plate_side)]
Integer = Annotated[int, BeforeValidator(_integer)]
MaterialName = Annotated[str | dict[str, str | float], BeforeValidator(_material)]
"""A material: a name from the library, or ``{name, youngs_modulus, poisson_ratio, density}``."""


def _fail(field: str, message: str) -> ValueError:
    """An error from a cross-field check that still names the one field at fault."""
    return ValueError(f"[{field}] {message}")


class _Section(BaseModel):
    """Base for scene sections: unknown keys are errors, assignments are validated."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class ChainSpec(_Section):
    """The granular chain: N identical spheres standing on the plate."""

    n_particles: Integer = Field(
        20, ge=1, le=100_000, description="spheres in the chain (striker not counted)"
    )
    diameter: Number = Field(9.53e-3, ge=1e-4, le=1.0, description="sphere diameter D, m")
    material: MaterialName = Field("steel_440c", description="sphere material: a library name "
                                   "or {name, youngs_modulus, poisson_ratio, density} (SI)")
    sensor_index: Integer = Field(
        7, ge=1, description="sensor particle, counted from the top, 1-based"
    )

    @model_validator(mode="after")
    def _sensor_inside(self) -> ChainSpec:
        if self.sensor_index > self.n_particles:
            raise _fail(
                "sensor_index",
                f"sensor_index {self.sensor_index} is outside the chain of {self.n_particles} "
                f"particles (allowed: 1..{self.n_particles})"
            )
        return self


class StrikerSpec(_Section):
    """The striker: a sphere of the chain's diameter, of the chain's material unless ``material``
    says otherwise, dropped from a height or given an impact velocity."""

    drop_height: Number = Field(5e-3, ge=1e-6, le=100.0, description="free-fall height, m")
    material: MaterialName | None = Field(
        None, description="striker material when it differs from the chain's: a library name or "
        "{name, youngs_modulus, poisson_ratio, density} (SI); omitted: the chain's")
    velocity: Annotated[Number, Field(ge=1e-4, le=100.0)] | None = Field(
        None, description="impact velocity, m/s")

    @model_validator(mode="after")
    def _one_of(self) -> StrikerSpec:
        if self.velocity is not None and "drop_height" in self.model_fields_set:
            raise _fail("velocity", "give either drop_height or velocity, not both")
        return self

    @property
    def impact_velocity(self) -> float:
        """v_imp: the given velocity, else free fall sqrt(2 g h) (no air drag, as in the paper)."""
        if self.velocity is not None:
            return self.velocity
        return sqrt(2.0 * STANDARD_GRAVITY * self.drop_height)


class PlateSpec(_Section):
    """The plate: thickness, in-plane size, material, clamped supports, chain position."""

    thickness: Number = Field(3.18e-3, ge=1e-5, le=1.0, description="plate thickness t, m")
    size: tuple[PlateSide, PlateSide] = Field(
        (0.914, 0.914), description="in-plane size (along the centre line, across), m"
    )
    material: MaterialName = Field("al_6061", description="plate material: a library name or "
                                   "{name, youngs_modulus, poisson_ratio, density} (SI)")
    supports: Literal["opposite_edges", "all_edges", "none"] = Field(
        "opposite_edges", description="which edges are clamped"
    )
    distance_to_support: Number = Field(
        0.457, ge=0.0, description="distance L from the chain to the clamped edge at x = 0, m"
    )

    @model_validator(mode="after")
    def _geometry(self) -> PlateSpec:
        lx = self.size[0]
        if not all(0.0 < s <= MAX_PLATE_SIZE for s in self.size):
            raise _fail("size", f"each side must be positive and finite, 0 < size <= "
                        f"{MAX_PLATE_SIZE:g} m, got {list(self.size)}")
        if self.distance_to_support > lx:
            raise _fail(
                "distance_to_support",
                f"{self.distance_to_support} m lies outside the plate "
                f"(allowed: 0..{lx} m, the plate length along the centre line)"
            )
        return self


class EffectsSpec(_Section):
    """Which physical effects to simulate; each costs nothing when off."""

    gravity: StrictBool = Field(True, description="static preload m g per particle (paper Eq. 1)")
    dissipation: StrictBool = Field(False, description="contact damping (off in the paper's model)")
    plate_model: Literal["rigid", "halfspace", "infinite", "sem", "greens", "mindlin",
                         "mindlin_greens", "auto"] = Field(
        "auto", description="bottom boundary; auto picks the cheapest model that is right"
    )
    damping: Number = Field(
        0.0, ge=0.0, le=1e-3,
        description="Kuwabara-Kono dissipative time constant tau of the sphere contacts, s; "
        "used when dissipation is on (F = A d^1.5 + 1.5 A tau d^0.5 d')",
    )

    @model_validator(mode="after")
    def _damping_given(self) -> EffectsSpec:
        if self.dissipation and self.damping <= 0.0:
            raise _fail("damping", "dissipation is on but damping is 0; give the Kuwabara-Kono "
                        "time constant tau in seconds (allowed: 0 < damping <= 1e-3)")
        return self


class OutputSpec(_Section):
    """What to record."""

    sample_rate: Number = Field(2e6, ge=1e3, le=1e10,
                                description="sensor sampling rate, Hz (at least 1 kHz)")
    duration: Annotated[Literal["auto"] | float, BeforeValidator(_duration)] = Field(
        "auto", description="'auto' (until the reflection has passed the sensor) or seconds"
    )
    traces: StrictBool = Field(False,
                               description="also record particle positions, velocities, forces")


class SemSpec(_Section):
    """Meshed plate discretisation (plate models ``sem``, ``greens``, ``mindlin``,
    ``mindlin_greens``, ``auto``)."""

    preset: Literal["resolved", "paper"] = Field(
        "resolved", description="'resolved': the contact patch below, resolved by local "
        "refinement; 'paper': the paper's model, a single-node force on the uniform mesh "
        "(contact_radius 0, contact_refinement 0; under-resolved, kept for comparison)",
    )
    elements: tuple[Integer, Integer, Integer] = Field(
        (16, 16, 1), description="elements along x (centre line), y (across), z (thickness)"
    )
    order: tuple[Integer, Integer, Integer] = Field(
        (4, 4, 2), description="GLL polynomial order along x, y, z"
    )
    symmetry: StrictBool = Field(True, description="mesh half the plate, mirror plane y = Ly/2")
    step_factor: Number = Field(
        0.9, ge=1e-3, le=1.0, description="time step as a fraction of the stable limit"
    )
    auto_margin: Number = Field(
        2.0, gt=0.0, le=100.0,
        description="auto uses 'infinite' when L > auto_margin * L_c (Eq. 18, k = 0.57)",
    )
    contact_radius: Annotated[Literal["auto"] | float, BeforeValidator(_contact_radius)] = Field(
        "auto", description="radius r_c of the contact patch the chain loads the plate through, "
        "m; 'auto' = the plate thickness; 0 = a single node (mesh-dependent, for comparison)",
    )
    contact_refinement: Integer = Field(
        1, ge=0, le=8, description="elements of size 2 r_c / n around the chain (0: none, the "
        "paper's uniform layout)",
    )
    plate_theory: Literal["auto", "3d", "mindlin"] = Field(
        "auto", description="the meshed plate effects.plate_model 'auto' uses near a support: "
        "'3d' (greens), 'mindlin' (mindlin_greens), or 'auto': Mindlin from D/t = 0.5 up, where "
        "it was measured within the table budget of the 3-D plate, 3-D below (README, 'Where a "
        "2-D plate suffices')",
    )
    elements_per_wavelength: Number = Field(
        1.0, ge=0.0, le=8.0, description="plate models 'mindlin' and 'mindlin_greens': at least "
        "this many in-plane elements per flexural (Kirchhoff A0) wavelength at the top of the "
        "incident pulse's band, f = V_s / (2.5 D); thin plates get more elements than "
        "sem.elements, never fewer (0: sem.elements as given)",
    )
    mindlin_element_size: Number = Field(
        6.0, ge=0.5, le=50.0, description="plate models 'mindlin' and 'mindlin_greens': size of "
        "the elements around the chain in contact radii r_c (the patch itself is integrated "
        "exactly on any element; a 2-D plate has no field to resolve across the thickness, so "
        "it needs no element as fine as the 3-D plate's 2 r_c / contact_refinement)",
    )

    @model_validator(mode="after")
    def _ranges(self) -> SemSpec:
        if self.preset == "paper":
            clash = [name for name in ("contact_radius", "contact_refinement")
                     if name in self.model_fields_set and getattr(self, name) != 0]
            if clash:
                raise _fail("preset", f"'paper' loads a single node; it cannot be combined with "
                            f"{', '.join(clash)} (allowed: preset 'resolved' with a patch, or "
                            "'paper' alone)")
        if any(not 1 <= n <= 1024 for n in self.elements):
            raise _fail("elements", f"each count must be in 1..1024, got {list(self.elements)}")
        if any(not 1 <= p <= 16 for p in self.order):
            raise _fail("order", f"each order must be in 1..16, got {list(self.order)}")
        return self


class SolverSpec(_Section):
    """How the chain is integrated (plate models ``rigid``, ``halfspace``, ``infinite``)."""

    integrator: Literal["verlet", "dopri5"] = Field(
        "verlet", description="'verlet': velocity Verlet on a fixed step (the default); "
        "'dopri5': adaptive Dormand-Prince 5(4) with dense output, to the tolerance rtol",
    )
    rtol: Number = Field(
        1e-8, ge=1e-12, le=1e-2,
        description="relative tolerance of dopri5 (absolute: rtol x each component's typical "
        "magnitude); ignored by verlet",
    )


class Scene(_Section):
    """A complete experiment. Defaults are the paper's setup (D = 9.53 mm, t = 3.18 mm, centre)."""

    chain: ChainSpec = Field(default_factory=ChainSpec)
    striker: StrikerSpec = Field(default_factory=StrikerSpec)
    plate: PlateSpec = Field(default_factory=PlateSpec)
    effects: EffectsSpec = Field(default_factory=EffectsSpec)
    output: OutputSpec = Field(default_factory=OutputSpec)
    sem: SemSpec = Field(default_factory=SemSpec)
    solver: SolverSpec = Field(default_factory=SolverSpec)

    # Derived physical quantities -------------------------------------------------------------
    @property
    def sphere_material(self) -> Material:
        return material_of(self.chain.material, "chain.material")

    @property
    def plate_material(self) -> Material:
        return material_of(self.plate.material, "plate.material")

    @property
    def sphere_mass(self) -> float:
        """m, kg."""
        return sphere_mass(self.chain.diameter, self.sphere_material)

    @property
    def a_s(self) -> float:
        """Hertz constant between two chain spheres, N/m^1.5."""
        return hertz_sphere_sphere(self.chain.diameter, self.sphere_material)

    @property
    def striker_material(self) -> Material:
        """The striker's material: ``striker.material``, else the chain's."""
        if self.striker.material is None:
            return self.sphere_material
        return material_of(self.striker.material, "striker.material")

    @property
    def striker_differs(self) -> bool:
        """Whether the striker is not simply one more of the chain's spheres."""
        if self.striker.material is None:
            return False
        return _differ(self.striker_material, self.sphere_material)

    @property
    def striker_mass(self) -> float:
        """m_0, kg: a sphere of the chain's diameter in the striker's material."""
        if not self.striker_differs:
            return self.sphere_mass
        return sphere_mass(self.chain.diameter, self.striker_material)

    @property
    def a_0(self) -> float:
        """Hertz constant between the striker and the first chain sphere, N/m^1.5."""
        if not self.striker_differs:
            return self.a_s
        return hertz_two_spheres(self.chain.diameter, self.striker_material,
                                 self.sphere_material)

    @property
    def a_p(self) -> float:
        """Hertz constant between the last sphere and the plate, N/m^1.5."""
        return hertz_sphere_flat(self.chain.diameter, self.sphere_material, self.plate_material)

    @property
    def impact_velocity(self) -> float:
        """v_imp, m/s."""
        return self.striker.impact_velocity

    @property
    def plate_impedance(self) -> float:
        """Z = 8 sqrt(rho t D_p), N s/m."""
        return plate_impedance(self.plate.thickness, self.plate_material)

    @property
    def d_over_t(self) -> float:
        return self.chain.diameter / self.plate.thickness

    def constants(self) -> SceneConstants:
        """The derived constants a run reads, each computed once (the properties above, by the
        same formulas: the values are identical). Each property looks the materials up again,
        and a material given by properties is validated anew on every lookup; a run that reads
        the masses and Hertz constants a dozen times asks for them here once."""
        d = self.chain.diameter
        sphere, plate = self.sphere_material, self.plate_material
        m, a_s = sphere_mass(d, sphere), hertz_sphere_sphere(d, sphere)
        striker = (sphere if self.striker.material is None
                   else material_of(self.striker.material, "striker.material"))
        differs = striker is not sphere and _differ(striker, sphere)
        return SceneConstants(
            sphere_mass=m,
            a_s=a_s,
            striker_differs=differs,
            striker_mass=sphere_mass(d, striker) if differs else m,
            a_0=hertz_two_spheres(d, striker, sphere) if differs else a_s,
            a_p=hertz_sphere_flat(d, sphere, plate),
            plate_impedance=plate_impedance(self.plate.thickness, plate),
            impact_velocity=self.striker.impact_velocity,
            gravity=STANDARD_GRAVITY if self.effects.gravity else 0.0,
        )

    def to_dict(self) -> SceneDict:
        """Plain JSON-ready dict with every field, defaults included."""
        return cast(SceneDict, self.model_dump(mode="json"))

    def with_overrides(self, overrides: Iterable[str] | Mapping[str, Any]) -> Scene:
        """A new scene with dotted-key overrides applied and validated."""
        return scene_from_dict(apply_overrides(self.to_dict_explicit(), overrides))

    def to_dict_explicit(self) -> SceneDict:
        """Dict of the fields that were set explicitly (keeps 'either/or' choices intact)."""
        return cast(SceneDict, self.model_dump(mode="json", exclude_unset=True))


def _differ(a: Material, b: Material) -> bool:
    """Whether two materials differ in what the contact laws read (E, nu, rho)."""
    return ((a.youngs_modulus, a.poisson_ratio, a.density)
            != (b.youngs_modulus, b.poisson_ratio, b.density))


class SceneConstants(NamedTuple):
    """A scene's derived constants in SI units, as :meth:`Scene.constants` computes them once for
    a run (a snapshot: it does not follow later changes to the scene). A named tuple: immutable,
    and built in a fraction of a frozen dataclass's time, which counts at a run's scale.

    sphere_mass, a_s: m and the sphere-sphere Hertz constant. striker_differs, striker_mass, a_0:
    as the properties of those names. a_p: the sphere-on-plate Hertz constant. plate_impedance:
    Zener's Z. impact_velocity: v_imp. gravity: g, 0 when ``effects.gravity`` is off.
    """

    sphere_mass: float
    a_s: float
    striker_differs: bool
    striker_mass: float
    a_0: float
    a_p: float
    plate_impedance: float
    impact_velocity: float
    gravity: float


# Loading, overriding, validating -------------------------------------------------------------


def _field_of(loc: tuple[Any, ...]) -> str:
    """Dotted field path, without pydantic's internal union/validator tags."""
    parts = [str(p) for p in loc if not any(c in str(p) for c in "[(")]
    return ".".join(parts) or "scene"


def scene_from_dict(data: Mapping[str, Any]) -> Scene:
    """Validate a mapping into a Scene; raise one SceneError that names the first bad field."""
    if not isinstance(data, Mapping):
        raise SceneError("scene", f"expected a mapping of sections, got {type(data).__name__}",
                         allowed="chain, striker, plate, effects, output")
    try:
        return Scene.model_validate(dict(data))
    except ValidationError as exc:
        errors = exc.errors()
        first = errors[0]
        field = _field_of(first["loc"])
        message = _describe(first)
        if message.startswith("["):
            inner, _, message = message[1:].partition("] ")
            field = f"{field}.{inner}" if field != "scene" else inner
        if len(errors) > 1:
            others = ", ".join(sorted({_field_of(e["loc"]) for e in errors[1:]}))
            message += f" [also invalid: {others}]"
        raise SceneError(field, message) from None


def _describe(error: Mapping[str, Any]) -> str:
    """Turn one pydantic error into a sentence that says what is allowed."""
    kind = error["type"]
    ctx = error.get("ctx") or {}
    if kind == "extra_forbidden":
        parent: Any = Scene
        for part in error["loc"][:-1]:
            field = parent.model_fields.get(str(part)) if hasattr(parent, "model_fields") else None
            parent = field.annotation if field is not None else None
        known = ", ".join(parent.model_fields) if hasattr(parent, "model_fields") else ""
        return f"unknown key (allowed keys here: {known})"
    if kind == "greater_than":
        return f"must be > {ctx['gt']}, got {error.get('input')!r}"
    if kind == "greater_than_equal":
        return f"must be >= {ctx['ge']}, got {error.get('input')!r}"
    if kind == "less_than_equal":
        return f"must be <= {ctx['le']}, got {error.get('input')!r}"
    if kind == "literal_error":
        return f"got {error.get('input')!r}; allowed: {ctx.get('expected')}"
    if kind.startswith("bool"):
        return f"expected true or false, got {error.get('input')!r}"
    msg = str(error["msg"])
    return msg.removeprefix("Value error, ")


def parse_value(text: str) -> Any:
    """Parse a command-line value: JSON first (1e-3, true, lists), else YAML, else plain text."""
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        pass
    import yaml  # here, not at the top: `solitonde theory` starts without it

    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        return text
    return text if value is None else value


def apply_overrides(
    data: Mapping[str, Any], overrides: Iterable[str] | Mapping[str, Any]
) -> SceneDict:
    """A deep copy of ``data`` with ``section.key=value`` overrides applied (not validated);
    ``section.key=null`` removes the key, so its default applies."""
    result = json.loads(json.dumps(dict(data)))
    items: Iterable[tuple[str, Any]]
    if isinstance(overrides, Mapping):
        items = overrides.items()
    else:
        pairs = []
        for text in overrides:
            key, sep, raw = text.partition("=")
            if not sep or not key.strip():
                raise SceneError(text, "override must look like section.key=value",
                                 allowed="e.g. plate.thickness=3.18e-3")
            pairs.append((key.strip(), parse_value(raw.strip())))
        items = pairs
    for key, value in items:
        parts = key.split(".")
        node = result
        for i, part in enumerate(parts[:-1]):
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                raise SceneError(".".join(parts[: i + 1]), "is a value, not a section")
            node = child
        if value is None:  # key=null clears the key: the default applies again
            node.pop(parts[-1], None)
        else:
            node[parts[-1]] = value
    return cast(SceneDict, result)


def load_scene_file(path: str | Path) -> SceneDict:
    """Read a YAML or JSON scene file into a dict (not yet validated)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise SceneError("scene", f"cannot read scene file {str(path)!r}: {exc.strerror}") from None
    except UnicodeDecodeError as exc:
        raise SceneError(
            "scene",
            f"scene file {str(path)!r} is not UTF-8 text ({exc.reason} at byte {exc.start})",
            allowed="a YAML or JSON file in UTF-8",
        ) from None
    import yaml

    try:
        data = json.loads(text) if path.suffix.lower() == ".json" else yaml.safe_load(text)
    except (json.JSONDecodeError, yaml.YAMLError) as exc:
        kind = path.suffix.lstrip(".") or "YAML"
        raise SceneError("scene", f"{path.name} is not valid {kind}: {exc}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise SceneError("scene", f"{path.name} must hold a mapping of sections",
                         allowed="chain, striker, plate, effects, output")
    return cast(SceneDict, data)


def load_scene(path: str | Path | None = None, overrides: Iterable[str] = ()) -> Scene:
    """Load a scene file (or the defaults), apply ``--set`` overrides, validate."""
    data = load_scene_file(path) if path is not None else {}
    return scene_from_dict(apply_overrides(data, list(overrides)))
