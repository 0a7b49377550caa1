"""TDMS (NI): channels with the waveform properties ``wf_increment`` and ``wf_start_offset``;
``group=`` and ``channel=`` select; ``unit_string`` gives the units, other properties become
metadata. A file cut short is refused, not read in part."""

from __future__ import annotations

import json
import logging
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from ..errors import WaveformError
from ..waveform import Waveform, _jsonable
from .base import FileFormat
from .reading import (
    COMMON_OPTIONS,
    Part,
    as_waveforms,
    decode_value,
    float_array,
    positive,
    resolve_units,
    sample_period,
)


def _as_list(value: str | Iterable[str] | None) -> list[str] | None:
    if value is None:
        return None
    return [value] if isinstance(value, str) else list(value)


def read_tdms(
    path: Path, group: str | None = None, channel: str | Sequence[str] | None = None,
    sample_rate: float | None = None, dt: float | None = None, t0: float | None = None,
    units: str | None = None, calibration: float | None = None,
) -> list[Waveform]:
    tdms = _read_whole_tdms(path)
    groups = {g.name: g for g in tdms.groups()}
    if group is not None and group not in groups:
        raise WaveformError("group", f"no group {group!r} in {path.name}",
                            ", ".join(groups) or "(no groups)")
    chosen = [groups[group]] if group is not None else list(groups.values())
    wanted = _as_list(channel)
    parts: list[Part] = []
    for g in chosen:
        names = [c.name for c in g.channels()]
        if wanted is not None:
            missing = [c for c in wanted if c not in names]
            if missing and (group is not None or len(chosen) == 1):
                raise WaveformError("channel", f"no channel {missing[0]!r} in group {g.name!r}",
                                    ", ".join(names) or "(no channels)")
        for ch in g.channels():
            if wanted is not None and ch.name not in wanted:
                continue
            where = f"{path.name}:{g.name}/{ch.name}"
            props = {k: decode_value(v, k) for k, v in dict(ch.properties).items()}
            if "wf_increment" not in props:
                if wanted is not None:
                    raise WaveformError("dt", f"channel {g.name}/{ch.name} has no wf_increment",
                                        "NI waveform channels (wf_increment, wf_start_offset)")
                continue
            unit = resolve_units(props.pop("unit_string", None), units, where)
            own_cal = props.pop("calibration", None)
            start = float(props.pop("wf_start_offset", 0.0))
            step = sample_period(positive("dt", props.pop("wf_increment")), sample_rate, dt, where)
            meta = {k: v for k, v in props.items() if not k.startswith(("wf_", "NI_"))}
            meta.update(group=g.name, channel=ch.name)
            parts.append((start if t0 is None else t0, step, float_array(ch[:], "samples"),
                          unit, own_cal, meta))
    if wanted is not None and not parts:
        raise WaveformError("channel", f"none of {wanted} found in {path.name}")
    return as_waveforms(parts, calibration, path.name)


class _Collect(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())


def _read_whole_tdms(path: Path) -> Any:
    """The TDMS file, refused when it is cut short or damaged: npTDMS reads what it can of a
    truncated file and only logs a warning, which would store a shot with samples missing."""
    from nptdms import TdmsFile

    handler = _Collect()
    logger = logging.getLogger("nptdms")
    logger.addHandler(handler)
    try:
        tdms = TdmsFile.read(path)
    finally:
        logger.removeHandler(handler)
    if handler.messages:
        raise WaveformError("file", f"{path.name} is truncated or damaged: "
                            f"{handler.messages[0]}", "a complete TDMS file")
    for group in tdms.groups():
        for ch in group.channels():
            declared = ch.properties.get("wf_samples")
            if declared is not None and int(declared) != len(ch):
                raise WaveformError("file", f"{path.name}: channel {group.name}/{ch.name} "
                                    f"holds {len(ch)} samples, its wf_samples says "
                                    f"{int(declared)}: the file is truncated or damaged",
                                    "a complete TDMS file")
    return tdms


def write_tdms(path: Path, waves: list[Waveform], group: str = "shots") -> None:
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    with TdmsWriter(str(path)) as writer:
        objects: list[Any] = [RootObject(), GroupObject(group)]
        for i, w in enumerate(waves):
            props: dict[str, Any] = {
                "wf_start_offset": w.t0, "wf_increment": w.dt, "wf_samples": w.n,
                "unit_string": w.units,
            }
            if w.calibration is not None:
                props["calibration"] = w.calibration
            for key, value in w.metadata.items():
                if key in ("source", "group", "channel"):
                    continue
                props[key] = value if isinstance(value, int | float | str) and not \
                    isinstance(value, bool) else json.dumps(_jsonable(value))
            objects.append(ChannelObject(group, f"shot_{i:03d}", w.samples, properties=props))
        writer.write_segment(objects)


def tdms_values(path: Path, _dataset: str | None = None) -> int:
    """Values in every channel, from the file's metadata (``TdmsFile.read`` decodes them all)."""
    from nptdms import TdmsFile

    meta = TdmsFile.read_metadata(path)
    return sum(len(ch) for g in meta.groups() for ch in g.channels())


FORMAT = FileFormat("tdms", (".tdms",), (*COMMON_OPTIONS, "group", "channel"), read_tdms,
                    write_tdms, declared_values=tdms_values)
