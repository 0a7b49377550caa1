"""The one bridge from a simulation to the signal package: a simulated shot as it is recorded.

The inversion compares a measured shot with model-table points whose features were extracted
from simulated shots, so both must be measured the same way for the extractor's biases to cancel.
Every producer of features from a simulation (the table builder, ``solitonde simulate``,
``POST /v1/simulate``, the sample files, validation, reproduction and the accuracy study) therefore
turns its :class:`~solitonde.model.simulate.SimulationResult` into a
:class:`~solitonde.signal.waveform.Waveform` here and nowhere else (a test walks the code for
other bridges). Noise, drift and quantisation are applied to the returned samples, pre-trigger
included, as an acquisition would record them (:func:`solitonde.signal.synth.degrade`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from solitonde.model import zener
from solitonde.model.scene import Scene
from solitonde.model.simulate import SimulationResult
from solitonde.signal.errors import WaveformError
from solitonde.signal.waveform import Waveform

PRETRIGGER_FRACTION = 0.25
"""A simulated record starts at the impact; the sensor's static reading is prepended for this
fraction of the record (at least :data:`MIN_PRETRIGGER` samples), as a triggered acquisition keeps
a pre-trigger segment: the detector estimates baseline and noise there, exactly as on measured
shots."""
MIN_PRETRIGGER = 64
MIN_PULSE_SAMPLES = 4.0
"""Fewest samples across the incident solitary pulse (5 D / V_s wide, Nesterenko's long-wave
solution) for its peak to be measured; below it a shot is refused rather than measured at
random (a 20 kHz record of the default scene has 1.8)."""


def detect_options(scene: Scene) -> dict[str, float]:
    """The extractor's options for a shot of this scene's chain: where its geometry puts the
    reflection (``travel_time_1n_s``, a striker's train never taken for it) and how wide a
    solitary wave of the measured force is (``pulse_width_1n_s``, ``implausible_units``). The
    model tables measure their points with them, and measured shots of a stated sphere size too
    (:mod:`solitonde.instrument.inference.chain_geometry`)."""
    return {"travel_time_1n_s": zener.travel_time_at_unit_force(scene),
            "pulse_width_1n_s": zener.pulse_width_at_unit_force(scene)}


def pulse_samples(scene: Scene) -> float:
    """Samples across the incident solitary pulse at the scene's sample rate: 5 D / V_s(v_in)
    (Nesterenko's speed, the paper's Eq. 12) times ``output.sample_rate``."""
    v_in = zener.incident_velocity(scene)
    d = scene.chain.diameter
    width = 5.0 * d / zener.solitary_wave_speed(d, scene.a_s, scene.sphere_mass, v_in)
    return width * scene.output.sample_rate


def check_resolved(scene: Scene) -> None:
    """Refuse (WaveformError naming ``output.sample_rate``) a sample rate too low to measure the
    pulse (:data:`MIN_PULSE_SAMPLES`); known from the scene, so callers check before running."""
    resolved = pulse_samples(scene)
    if resolved < MIN_PULSE_SAMPLES:
        rate = scene.output.sample_rate
        raise WaveformError(
            "output.sample_rate",
            f"{rate:,.0f} Hz puts {resolved:.1f} samples across the solitary pulse "
            f"({resolved / rate * 1e6:.0f} us wide): too few samples to measure its peak",
            f"a sample rate with at least {MIN_PULSE_SAMPLES:.0f} samples across the pulse, "
            f"above {MIN_PULSE_SAMPLES / resolved * rate:,.0f} Hz",
        )


def as_measured(result: SimulationResult, metadata: Mapping[str, Any] | None = None) -> Waveform:
    """The simulated sensor trace as an acquisition records it: a static pre-trigger, then the shot.

    The samples are in N; ``t0`` is negative so that the impact stays at t = 0 and the model's
    peak times (``result.truth``) keep their meaning. Metadata: ``source`` ("simulation"),
    ``sphere_diameter`` and ``plate_model`` of the run, then ``metadata`` (which may replace them).
    A record too coarse to resolve the pulse is refused (:func:`check_resolved`).
    """
    check_resolved(result.scene)
    x = np.asarray(result.samples, dtype=np.float64)
    n_pre = max(MIN_PRETRIGGER, int(PRETRIGGER_FRACTION * x.size))
    padded = np.concatenate([np.full(n_pre, x[0]), x])
    meta = {"source": "simulation", "sphere_diameter": result.scene.chain.diameter,
            "plate_model": result.plate_model, **(metadata or {})}
    return Waveform(result.t0 - n_pre * result.dt, result.dt, padded, "N", metadata=meta)
