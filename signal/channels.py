"""Which channels of a file are sensor traces: choose by name, or tell them from triggers.

A DAQ or scope file often holds more than the sensor: a trigger or gate channel (a step or a
rectangle), an unconnected input (a flat line of noise). Analysed as a shot, a trigger step
becomes a made-up "incident pulse". :func:`select` picks the channels to analyse: those named,
or, when none is named and the file holds several channels, those that :func:`classify` finds to
be pulse traces; it says which it skipped and why, and refuses a file it cannot sort out.

A sensor trace here is what the chain's sensor records: the level sits at a baseline, rises in
pulses of a few to a few hundred microseconds that return to it, and ends near where it began.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .errors import WaveformError
from .waveform import Waveform

SENSOR, TRIGGER, FLAT, UNCLEAR = "sensor", "trigger", "flat", "unclear"
EVENT_SIGMA = 6.0
"""A channel whose largest excursion is under this many noise deviations holds no event."""
STEP_FRACTION = 0.5
"""A channel that ends this fraction of its largest excursion away from its start level has
stepped (a trigger or gate), not pulsed."""
GATE_FRACTION = 0.25
"""A channel above half its peak for more than this fraction of the record is a gate."""
EDGE_FRACTION = 0.6
"""A rise of this fraction of the peak within one sample is a digital edge: no solitary pulse
sampled at 1 MHz or more rises that fast (it takes tens of microseconds)."""


@dataclass(frozen=True)
class Verdict:
    """What :func:`classify` made of one channel: ``kind`` and, in words, why."""

    kind: str
    reason: str


def channel_name(wave: Waveform) -> str:
    """The name a user gives on the command line: ``group/channel`` for TDMS, the column name
    for tables, the dataset for HDF5, else the shot number."""
    meta = wave.metadata
    if meta.get("channel") is not None:
        group = meta.get("group")
        return f"{group}/{meta['channel']}" if group else str(meta["channel"])
    if meta.get("dataset") is not None:
        return str(meta["dataset"])
    return f"shot {meta.get('shot', 0)}"


def classify(wave: Waveform) -> Verdict:
    """Whether ``wave`` looks like a sensor trace, a trigger/gate, a flat line, or unclear."""
    x = np.asarray(wave.samples, dtype=np.float64)
    n = x.size
    edge = max(3, n // 20)
    start, end = float(np.median(x[:edge])), float(np.median(x[-edge:]))
    steps = np.diff(x)
    # the larger of two robust deviations: sample to sample (white noise) and about the median
    # level (noise a scope's bandwidth limit has smoothed, slow wander)
    noise = max(1.4826 * float(np.median(np.abs(steps - np.median(steps)))) / np.sqrt(2.0),
                1.4826 * float(np.median(np.abs(x - np.median(x)))))
    excursion = x - start
    k = int(np.argmax(np.abs(excursion)))
    peak = float(abs(excursion[k]))
    unit = wave.units
    if peak <= EVENT_SIGMA * max(noise, np.finfo(float).tiny) or peak == 0.0:
        return Verdict(FLAT, f"a flat line: its largest excursion ({peak:.3g} {unit}) is within "
                       f"{EVENT_SIGMA:g} times its noise ({noise:.3g} {unit})")
    if abs(end - start) > STEP_FRACTION * peak:
        return Verdict(TRIGGER, f"a step: the level moves from {start:.3g} to {end:.3g} {unit} "
                       "and stays (a trigger or gate, not a pulse)")
    above = float(np.mean(np.abs(excursion) > 0.5 * peak))
    if above > GATE_FRACTION:
        return Verdict(TRIGGER, f"a gate: above half its peak for {above:.0%} of the record")
    fastest = float(np.max(np.abs(steps)))
    if fastest > EDGE_FRACTION * peak:
        if wave.dt <= 1e-6:
            return Verdict(TRIGGER, f"a digital edge: it rises {fastest / peak:.0%} of its peak "
                           f"within one sample ({wave.dt * 1e6:.3g} us)")
        return Verdict(UNCLEAR, f"it rises {fastest / peak:.0%} of its peak within one sample "
                       f"of {wave.dt * 1e6:.3g} us: a pulse sampled too coarsely, or an edge")
    return Verdict(SENSOR, "pulses that return to the baseline")


def select(waves: Sequence[Waveform], channels: Sequence[str] | None = None,
           group: str | None = None, where: str = "the file"
           ) -> tuple[list[Waveform], list[dict[str, str]]]:
    """The waveforms to analyse and the channels skipped (``{"channel", "reason"}``).

    ``channels`` (names as :func:`channel_name` gives them, or a bare TDMS channel name) and
    ``group`` choose; an unknown name is an error listing those there are. Without a choice, a
    file whose shots come from two or more differently named channels keeps the sensor traces;
    one with no sensor trace, or a channel :func:`classify` cannot call, is refused, listing
    every channel and what was made of it.
    """
    names = [channel_name(w) for w in waves]
    if group is not None:
        groups = sorted({str(w.metadata.get("group")) for w in waves
                         if w.metadata.get("group") is not None})
        in_group = [i for i, w in enumerate(waves) if w.metadata.get("group") == group]
        if not in_group:
            raise WaveformError("group", f"no group {group!r} in {where}",
                                ", ".join(groups) or "(the file has no groups)")
        waves, names = [waves[i] for i in in_group], [names[i] for i in in_group]
    if channels:
        chosen: list[int] = []
        for spec in channels:
            hits = [i for i, (w, name) in enumerate(zip(waves, names, strict=True))
                    if spec in (name, str(w.metadata.get("channel")))]
            if not hits:
                raise WaveformError("channel", f"no channel {spec!r} in {where}",
                                    ", ".join(dict.fromkeys(names)))
            chosen.extend(i for i in hits if i not in chosen)
        skipped = [{"channel": names[i], "reason": "not chosen"}
                   for i in range(len(waves)) if i not in chosen]
        for i in chosen:
            verdict = classify(waves[i])
            if verdict.kind in (TRIGGER, FLAT):
                raise WaveformError("channel", f"channel {names[i]!r} of {where} is not a sensor "
                                    f"trace: {verdict.reason}", "a channel that records the "
                                    "sensor's pulses")
        return [waves[i] for i in chosen], skipped
    if len(set(names)) < 2:
        return list(waves), []
    verdicts = [classify(w) for w in waves]
    kept = [w for w, v in zip(waves, verdicts, strict=True) if v.kind == SENSOR]
    listing = "; ".join(f"{name}: {v.kind} ({v.reason})"
                        for name, v in zip(names, verdicts, strict=True))
    if any(v.kind == UNCLEAR for v in verdicts) or not kept:
        unclear = any(v.kind == UNCLEAR for v in verdicts)
        what = "cannot tell which channels are sensor traces" if unclear else \
            "no channel is a sensor trace"
        raise WaveformError("channel", f"{where}: {what}: {listing}",
                            "name the channels to analyse: " + ", ".join(dict.fromkeys(names)))
    skipped = [{"channel": name, "reason": v.reason}
               for name, v in zip(names, verdicts, strict=True) if v.kind != SENSOR]
    return kept, skipped
