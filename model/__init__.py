"""solitonde.model: the physics (chain, plate, Zener theory, Lamb waves). No files, no HTTP."""

from .errors import SceneError, SimulationError
from .materials import MATERIALS, Material, get_material
from .scene import Scene, load_scene, scene_from_dict

__all__ = [
    "MATERIALS",
    "Material",
    "Scene",
    "SceneError",
    "SimulationError",
    "get_material",
    "load_scene",
    "scene_from_dict",
]
