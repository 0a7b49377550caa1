"""What the chain tells a measured shot: where the reflection arrives and how wide a solitary
wave of the measured force is.

A solitary wave's speed grows as its force to the 1/6 and its length is about five diameters
(Nesterenko), so a chain of known spheres ties three things a recording shows: the incident's
amplitude, its width and the time the reflection takes to come back from the plate. The
extractor uses them (:class:`~solitonde.signal.pulses.DetectOptions` ``travel_time_1n_s`` and
``pulse_width_1n_s``) to find the reflection where the geometry puts it, whatever the striker
launched before it, and to flag ``implausible_units`` when the width and the amplitude disagree.
The chain is the paper's (440C spheres, 20 of them, the sensor 7th from the top) at the stated
sphere size, or a model table's family.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from solitonde.model import zener
from solitonde.model.scene import Scene, scene_from_dict
from solitonde.signal.features import Features

from ..tables.measured import detect_options

STANDARD_DIAMETERS = (4.76e-3, 9.53e-3, 19.05e-3)
"""The paper's sphere sizes (3/16, 3/8 and 3/4 in), the bundled table's: a shot whose size is not
stated must fit one of them."""


def chain_scene(diameter: float, family: Scene | None = None) -> Scene:
    """The scene of a chain of ``diameter`` spheres: ``family``'s with that size, or the paper's."""
    if family is None:
        return scene_from_dict({"chain": {"diameter": float(diameter)}})
    data = family.model_dump(mode="json")
    data["chain"]["diameter"] = float(diameter)
    return scene_from_dict(data)


def shot_options(diameter: Any, family: Scene | None = None) -> dict[str, float]:
    """:func:`detect_options` for a measured shot whose sphere size is ``diameter`` (m); none
    where the size is not a positive number (the shot is then measured without them)."""
    try:
        d = float(diameter)
    except (TypeError, ValueError):
        return {}
    if not 1e-4 <= d <= 1.0:
        return {}
    return detect_options(chain_scene(d, family))


def units_message(features: Features, diameter: float | None,
                  family: Scene | None = None) -> str:
    """Why a shot flagged ``implausible_units`` is not used, with the expected and measured
    widths, and what to check (the flags and the file's unit row)."""
    force = features.incident_peak_N
    width = features.incident_width_s
    if diameter is not None:
        scene = chain_scene(diameter, family)
        expected = zener.pulse_width_at_unit_force(scene) * max(force, 1e-300) ** (-1.0 / 6.0)
        said = (f"a solitary wave of {force:.4g} N in a chain of {diameter * 1e3:.3g} mm "
                f"spheres is {expected * 1e6:.3g} us wide at half height, the incident pulse "
                f"{width * 1e6:.3g} us ({width / expected:.3g} times)")
    else:
        said = (f"a reflection {(features.tof_s or 0.0) * 1e6:.3g} us after a {force:.4g} N "
                "incident fits no chain of the table's sphere sizes (the round trip from the "
                "sensor to the plate at the incident's solitary-wave speed)")
    return (f"implausible_units: {said}. The force or the time axis is not in the units "
            "stated: check --calibration (N/V), the file's unit row (V or mV, s or ms or us) or "
            "--units; the shot is not inverted")


def fits_some_chain(features: Features, diameters: Sequence[float],
                    family: Scene | None = None) -> bool:
    """Whether some sphere size of ``diameters`` makes the shot's TOF a round trip of its chain
    at the incident's solitary-wave speed (the travel gate), for a shot whose sphere size is not
    stated. Only the TOF is asked: the pulse's width would also need the size, and a chain of
    another size or material than the table's may be fine. A shot without a reflection passes."""
    from solitonde.signal.kernels import GATE_HI, GATE_LO

    force = features.incident_peak_N
    if features.tof_s is None:
        return True
    if not force > 0:
        return False
    for d in diameters:
        trip = zener.travel_time_at_unit_force(chain_scene(d, family)) * force ** (-1.0 / 6.0)
        if GATE_LO * trip <= features.tof_s <= GATE_HI * trip:
            return True
    return False
