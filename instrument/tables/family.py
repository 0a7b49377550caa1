"""Plate families: what a model table was built for, and whether a measurement is of it.

A table's features hold only for the set-up it simulated: the sphere and plate materials, the
plate's size and supports, gravity, the chain's length and sensor, the striker. That is its
family. Two families differ in the keys :func:`differences` lists; a measurement of one family is
never inverted against a table of another.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, NotRequired, TypedDict, cast

from solitonde.model.materials import properties_from

FAMILY_KEYS = ("sphere_material", "plate_material", "plate_size_m", "supports", "gravity",
               "n_particles", "sensor_index", "impact_velocity_m_s", "striker_material")
"""The keys of a family, in the order they are reported."""


class MaterialProperties(TypedDict):
    """A material as :func:`solitonde.model.materials.properties_from` gives it, with the
    spread a property mapping states, if it states one."""

    name: str
    youngs_modulus: float
    poisson_ratio: float
    density: float
    youngs_modulus_rel_sd: NotRequired[float]
    poisson_ratio_sd: NotRequired[float]
    density_rel_sd: NotRequired[float]


class Family(TypedDict):
    """A table's family (:data:`FAMILY_KEYS`); materials as their property mappings."""

    sphere_material: MaterialProperties
    plate_material: MaterialProperties
    plate_size_m: list[float]
    supports: str
    gravity: bool
    n_particles: int
    sensor_index: int
    impact_velocity_m_s: float
    striker_material: MaterialProperties


def family_of_scene(scene: Any) -> Family:
    """The family of a validated scene (solitonde.model.scene.Scene)."""
    return {
        "sphere_material": material_properties(scene.chain.material),
        "plate_material": material_properties(scene.plate.material),
        "plate_size_m": [float(s) for s in scene.plate.size],
        "supports": scene.plate.supports,
        "gravity": bool(scene.effects.gravity),
        "n_particles": int(scene.chain.n_particles),
        "sensor_index": int(scene.chain.sensor_index),
        "impact_velocity_m_s": float(scene.impact_velocity),
        "striker_material": material_properties(scene.striker.material
                                                if scene.striker.material is not None
                                                else scene.chain.material),
    }


def material_properties(material: Any) -> MaterialProperties:
    """A material (a library name, a :class:`~solitonde.model.materials.Material` or a property
    mapping) as its property mapping; ValueError naming the key at fault."""
    return cast(MaterialProperties, properties_from(material))


def family_of_table(provenance: Mapping[str, Any]) -> Family | None:
    """The family recorded in a table's provenance (its base scene), or None if it has none."""
    from solitonde.model.errors import SceneError
    from solitonde.model.scene import scene_from_dict

    base = provenance.get("scene_defaults")
    if not isinstance(base, Mapping):
        return None
    try:
        return family_of_scene(scene_from_dict(base))
    except SceneError:
        return None


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, Mapping) and isinstance(b, Mapping):  # a material: its properties decide
        return all(_same(a.get(k), b.get(k)) for k in ("youngs_modulus", "poisson_ratio",
                                                      "density"))
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, bool) or isinstance(b, bool):
        return a == b
    if isinstance(a, int | float) and isinstance(b, int | float):
        return math.isclose(float(a), float(b), rel_tol=1e-6, abs_tol=1e-12)
    return a == b


def differences(stated: Mapping[str, Any], family: Mapping[str, Any]) -> list[str]:
    """The keys of ``stated`` (a partial family: what a measurement says of itself) whose values
    differ from ``family``'s."""
    return [k for k in FAMILY_KEYS if k in stated and stated[k] is not None
            and not _same(stated[k], family.get(k))]


def describe(value: Any) -> str:
    """A family value in words (a material by its name and properties)."""
    if isinstance(value, Mapping):
        return (f"{value.get('name')} (E {float(value['youngs_modulus']) / 1e9:g} GPa, nu "
                f"{float(value['poisson_ratio']):g}, rho {float(value['density']):g} kg/m^3)")
    return str(value)
