"""solitonde.model: the physics (chain, plate, Zener theory, Lamb waves). No files, no HTTP."""

from .errors import SceneError, SimulationError
from .jit_cache import configure as _configure_jit_cache
from .materials import MATERIALS, Material, get_material
from .scene import Scene, load_scene, scene_from_dict

# Before any kernel module is imported (the imports above load no numba): numba fixes a kernel's
# cache folder when its decorator runs.
_configure_jit_cache()

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
