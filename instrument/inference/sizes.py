"""Sphere sizes as every door takes them: metres, and a clear word where a size is in mm.

A chain's spheres are millimetres across; a size given as 9.53 is almost surely 9.53 mm typed
where metres are asked. Every input of a sphere size (the CLI's ``--sphere-diameter`` and
``--diameter``, a file's or a form's ``sphere_diameter``, a summary's ``diameter_m``) refuses a
size beyond :data:`SPHERE_DIAMETER_MAX` with :func:`size_in_metres_message`.
"""

from __future__ import annotations

import math

SPHERE_DIAMETER_MAX = 0.1
"""The largest sphere size taken, m: ten times the largest chain the paper or the library knows
(19.05 mm). A size over it is a size in millimetres."""


def size_in_metres_message(value: float) -> str:
    """What to say of a sphere size over :data:`SPHERE_DIAMETER_MAX`: sizes are in metres."""
    return (f"sizes are in metres: {value:g} mm is {value:g}e-3 (got {value:g}, over "
            f"{SPHERE_DIAMETER_MAX:g} m)")


def size_problem(value: object) -> str | None:
    """Why ``value`` is not a sphere size in metres, or None where it is one."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        return f"{value!r} is not a number of metres"
    if value <= 0:
        return f"{value:g} is not a size (> 0 m)"
    if value > SPHERE_DIAMETER_MAX:
        return size_in_metres_message(float(value))
    return None
