"""The features of a measured shot, read with what its chain tells (:mod:`.chain_geometry`): the
travel gate and the width check where the sphere size is known, and the baseline measured on the
gap against the chain's own relaxation, or on the pre-trigger alone.

The result's provenance names this step ``solitonde.instrument.inference.chain_geometry
.measure_shot``, the name it was stored under before it had a module of its own: stored results
keep that name.
"""

from __future__ import annotations

from typing import Any

from solitonde.instrument.inference.chain_geometry import (
    chain_relaxation,
    chain_scene,
    sphere_size,
)
from solitonde.instrument.tables.measured import detect_options
from solitonde.model.errors import ModelError
from solitonde.model.scene import Scene
from solitonde.signal.features import Features, extract
from solitonde.signal.waveform import Waveform

BASELINES = ("gap", "pre-trigger")
"""What a measured shot's baseline is measured on (metadata key ``baseline``, ``analyze
--baseline``): ``gap``, the pre-trigger and the gap before the reflection less the chain's
relaxation (the default where the sphere size is stated), or ``pre-trigger`` alone, for a chain
unlike the model's (another sensor position or chain length, a horizontal chain)."""


def measure_shot(waveform: Waveform, diameter: Any, family: Scene | None = None,
                 baseline: str = "gap") -> Features:
    """The features of a measured shot (:func:`measure_shot_baseline`, its first value)."""
    return measure_shot_baseline(waveform, diameter, family, baseline)[0]


def measure_shot_baseline(waveform: Waveform, diameter: Any, family: Scene | None = None,
                          baseline: str = "gap") -> tuple[Features, str]:
    """The features of a measured shot, with what its chain tells where ``diameter`` is known,
    and the baseline they were measured on (:data:`BASELINES`).

    With a size (a positive number of metres): the travel gate and the width check
    (:func:`~.chain_geometry.shot_options`), and, unless ``baseline`` is ``pre-trigger``, the
    drift measured on the gap against the chain's own relaxation
    (:func:`~.chain_geometry.relaxation`; a second pass once the incident's force is read).
    Without a size, without a reflection to bound the gap, or for a chain the model cannot run:
    the pre-trigger's baseline."""
    if baseline not in BASELINES:
        raise ValueError(f"baseline must be one of {BASELINES}, got {baseline!r}")
    d = sphere_size(diameter)
    scene = None if d is None else chain_scene(d, family)  # built once for both uses
    options = {} if scene is None else detect_options(scene)
    features = extract(waveform, **options)
    if (d is None or scene is None or baseline == "pre-trigger" or features.tof_s is None
            or not features.incident_peak_N > 0):
        return features, "pre-trigger"
    try:
        relax = chain_relaxation(d, scene, family, features.incident_peak_N, float(waveform.dt))
    except ModelError:  # a chain the model cannot run: the row says which baseline it got
        return features, "pre-trigger"
    return extract(waveform, **options, relaxation_N=relax), "gap"
