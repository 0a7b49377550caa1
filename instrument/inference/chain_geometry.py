"""What the chain tells a measured shot: where the reflection arrives and how wide a solitary
wave of the measured force is.

A solitary wave's speed grows as its force to the 1/6 and its length is about five diameters
(Nesterenko), so a chain of known spheres ties three things a recording shows: the incident's
amplitude, its width and the time the reflection takes to come back from the plate. The
extractor uses them (:class:`~solitonde.signal.pulses.DetectOptions` ``travel_time_1n_s`` and
``pulse_width_1n_s``) to find the reflection where the geometry puts it, whatever the striker
launched before it, and to flag ``implausible_units`` when the width and the amplitude disagree.
With gravity the chain also has a level of its own between the pulses (the spheres above the
sensor let go of part of their weight and settle back): :func:`relaxation` simulates it, and
:func:`~.shot_measure.measure_shot` hands it to the extractor so that a drifting baseline is
measured on the gap as well as on the pre-trigger (``relaxation_N``,
:mod:`solitonde.signal.gap_drift`).
The chain is the paper's (440C spheres, 20 of them, the sensor 7th from the top) at the stated
sphere size, or a model table's family.
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from solitonde.model import zener
from solitonde.model.scene import Scene, scene_from_dict
from solitonde.signal.features import Features

from ..tables.measured import detect_options

STANDARD_DIAMETERS = (4.76e-3, 9.53e-3, 19.05e-3)
"""The paper's sphere sizes (3/16, 3/8 and 3/4 in), the bundled table's: a shot whose size is not
stated must fit one of them."""


def chain_scene(diameter: float, family: Scene | None = None) -> Scene:
    """The scene of a chain of ``diameter`` spheres: ``family``'s with that size, or the paper's
    (validated once per size: every measured shot asks)."""
    if family is None:
        return _paper_chain(float(diameter))
    data = family.model_dump(mode="json")
    data["chain"]["diameter"] = float(diameter)
    return scene_from_dict(data)


@functools.lru_cache(maxsize=64)
def _paper_chain(diameter: float) -> Scene:
    return scene_from_dict({"chain": {"diameter": diameter}})


@functools.lru_cache(maxsize=64)
def _paper_chain_json(diameter: float) -> str:
    return _paper_chain(diameter).model_dump_json()


def sphere_size(diameter: Any) -> float | None:
    """``diameter`` as a sphere size in metres, or None where it is not one."""
    try:
        d = float(diameter)
    except (TypeError, ValueError):
        return None
    return d if 1e-4 <= d <= 1.0 else None


def shot_options(diameter: Any, family: Scene | None = None) -> dict[str, float]:
    """:func:`detect_options` for a measured shot whose sphere size is ``diameter`` (m); none
    where the size is not a positive number (the shot is then measured without them)."""
    d = sphere_size(diameter)
    return {} if d is None else detect_options(chain_scene(d, family))


def _solitary_width(force: float, diameter: float, family: Scene | None) -> float:
    """The FWHM of a solitary wave of ``force`` N in a chain of ``diameter`` m spheres, s."""
    scene = chain_scene(diameter, family)
    return zener.pulse_width_at_unit_force(scene) * max(force, 1e-300) ** (-1.0 / 6.0)


def _size_of_width(width: float, force: float, stated: float, family: Scene | None
                   ) -> float | None:
    """Another of the paper's sphere sizes whose solitary wave of this force is as wide as the
    incident (within the detector's tolerance, the closest), where the stated size's is not;
    None otherwise. A force in the wrong units can mimic one (a factor 1000 widens a wave 3.2
    times, two sizes apart 2.5 times), so the message names both causes."""
    from solitonde.signal.pulses import WIDTH_TOLERANCE

    def off(d: float) -> float:
        return abs(math.log(width / _solitary_width(force, d, family)))

    if not (width > 0 and force > 0) or off(stated) <= math.log(WIDTH_TOLERANCE):
        return None
    fits = [d for d in STANDARD_DIAMETERS if abs(d - stated) > 0.01 * stated
            and off(d) <= math.log(WIDTH_TOLERANCE)]
    return min(fits, key=off) if fits else None


def units_message(features: Features, diameter: float | None,
                  family: Scene | None = None) -> str:
    """Why a shot flagged ``implausible_units`` is not used, with the expected and measured
    widths, and what to check (the flags and the file's unit row)."""
    force = features.incident_peak_N
    width = features.incident_width_s
    if diameter is not None:
        expected = _solitary_width(force, diameter, family)
        said = (f"a solitary wave of {force:.4g} N in a chain of {diameter * 1e3:.3g} mm "
                f"spheres is {expected * 1e6:.3g} us wide at half height, the incident pulse "
                f"{width * 1e6:.3g} us ({width / expected:.3g} times)")
        other = _size_of_width(width, force, diameter, family)
        if other is not None and fits_some_chain(features, [other], family):
            # a wave's width and its round trip scale alike with the size and the force, so a
            # size stated wrong and a force in the wrong units look the same: both are named
            return (f"implausible_units: the incident pulse is {width * 1e6:.3g} us wide: a "
                    f"solitary wave of {other * 1e3:.4g} mm spheres, not {diameter * 1e3:.4g} "
                    f"mm ({said}). Check the "
                    "sphere size stated (--sphere-diameter, a manifest's sphere_diameter_m or "
                    "the file's sphere_diameter: sizes are in metres); if it is right, the force "
                    "or the time axis is not in the units stated: check --calibration (N/V), the "
                    "file's unit row (V or mV, s or ms or us) or --units; the shot is not "
                    "inverted")
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


RELAXATION_STEP = 0.01
"""The relaxation is simulated for incident forces on a grid of this relative step (1 %: its
level changes by about 0.1 % of itself, far below the noise of any gap)."""
INCIDENT_BY = 4e-4
"""Time after the impact by which the incident has passed the sensor, s (a 1.25 mm drop on the
largest spheres: under 200 us)."""
RELAXATION_OVERSAMPLE = 8
"""The simulated trace is this many times finer than the shot's sampling, then interpolated at
the shot's sample times after the model's incident peak."""


def relaxation(scene: Scene, incident_peak_N: float, dt: float) -> np.ndarray:
    """The chain's own sensor level after an incident of ``incident_peak_N``, above the pre-impact
    reading, N, every ``dt`` from the incident's peak on, far enough for the latest reflection
    the travel gate accepts (``GATE_HI`` round trips).

    A model run of ``scene``'s chain, struck at the velocity that gives that incident
    (F ~ v^(6/5)), lengthened below the sensor so that nothing returns from the plate within the
    window: until the reflection comes back the sensor cannot tell the plate, so any plate gives
    the same level. Zeros after the incident without gravity (the contacts open behind the wave).
    """
    return _relaxation(scene.model_dump_json(), _force_key(incident_peak_N), float(dt))


def _force_key(incident_peak_N: float) -> int:
    """The incident force's place on the grid of :data:`RELAXATION_STEP`."""
    if not (math.isfinite(incident_peak_N) and incident_peak_N > 0):
        raise ValueError(f"incident_peak_N must be a positive force, got {incident_peak_N!r}")
    return round(math.log(incident_peak_N) / math.log1p(RELAXATION_STEP))


@functools.lru_cache(maxsize=256)
def _relaxation(scene_json: str, force_key: int, dt: float) -> np.ndarray:
    from solitonde.model.simulate import simulate
    from solitonde.signal.kernels import GATE_HI

    data = json.loads(scene_json)
    force = math.exp(force_key * math.log1p(RELAXATION_STEP))
    window = GATE_HI * zener.travel_time_at_unit_force(scene_from_dict(data)) * force ** (-1 / 6)
    chain = data["chain"]
    below = chain["n_particles"] - chain["sensor_index"]
    # Longer than the latest accepted reflection's trip: nothing comes back within the window.
    chain["n_particles"] = chain["sensor_index"] + math.ceil(GATE_HI * max(below, 1)) + 4
    data["effects"]["plate_model"] = "rigid"
    data["output"].update(sample_rate=RELAXATION_OVERSAMPLE / dt, duration=INCIDENT_BY + window)
    velocity = scene_from_dict(data).impact_velocity
    data["striker"].pop("drop_height", None)
    for _ in range(2):  # the incident's force goes as v^(6/5); one correction lands within 0.1 %
        data["striker"]["velocity"] = velocity
        result = simulate(scene_from_dict(data))
        reached = result.truth["incident_peak_N"] - result.truth["static_sensor_N"]
        velocity *= (force / reached) ** (5.0 / 6.0)
    t_peak = result.truth["incident_time_s"]
    t = result.t0 + result.dt * np.arange(result.samples.size)
    at = t_peak + dt * np.arange(int((t[-1] - t_peak) / dt))
    level = np.interp(at, t, result.samples) - result.truth["static_sensor_N"]
    level.setflags(write=False)  # shared by every caller of the cache
    return level


def chain_relaxation(diameter: float, scene: Scene, family: Scene | None,
                     incident_peak_N: float, dt: float) -> np.ndarray:
    """:func:`relaxation` of ``scene``, the chain of ``diameter`` spheres already built from
    ``family`` (None: the paper's chain, whose JSON is kept per size)."""
    scene_json = _paper_chain_json(diameter) if family is None else scene.model_dump_json()
    return _relaxation(scene_json, _force_key(incident_peak_N), float(dt))
