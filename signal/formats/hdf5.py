"""HDF5: every dataset (or those under ``dataset=``) is a shot, or one shot per row when 2-D;
attributes ``dt`` or ``sample_rate``, optional ``t0``, ``units``, ``calibration``; all other
attributes become metadata. A file can reach outside itself (external storage, external links,
virtual datasets): :func:`outside_references` names how, for a server that must not follow."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from ..errors import WaveformError
from ..waveform import Waveform, _jsonable
from .base import FileFormat
from .npy import array_values
from .reading import (
    COMMON_OPTIONS,
    Part,
    as_waveforms,
    decode_value,
    float_array,
    resolve_units,
    sample_period,
    shot_rows,
    stated_period,
)

_HDF_KEYS = ("dt", "sample_rate", "t0", "units", "calibration")


def read_hdf5(
    path: Path, dataset: str | None = None, sample_rate: float | None = None,
    dt: float | None = None, t0: float | None = None, units: str | None = None,
    calibration: float | None = None,
) -> list[Waveform]:
    import h5py

    parts: list[Part] = []
    with h5py.File(path, "r") as fh:
        root = fh
        if dataset is not None:
            if dataset not in fh:
                names: list[str] = []
                fh.visit(names.append)
                raise WaveformError("dataset", f"no {dataset!r} in {path.name}",
                                    ", ".join(names) or "(file is empty)")
            root = fh[dataset]
        items: list[Any] = []
        if isinstance(root, h5py.Dataset):
            items = [root]
        else:
            root.visititems(lambda _n, obj: items.append(obj)
                            if isinstance(obj, h5py.Dataset) else None)
        for ds in items:
            where = f"{path.name}:{ds.name}"
            # read every attribute before decoding: an error raised while h5py's attribute
            # iterator is suspended would keep its global lock held by the traceback
            raw = {k: ds.attrs[k] for k in list(ds.attrs.keys())}
            attrs = {k: decode_value(v, k) for k, v in raw.items()}
            own = stated_period(attrs.get("dt"), attrs.get("sample_rate"))
            step = sample_period(own, sample_rate, dt, where)
            start = attrs.get("t0", 0.0) if t0 is None else t0
            unit = resolve_units(attrs.get("units"), units, where)
            meta = {k: v for k, v in attrs.items() if k not in _HDF_KEYS}
            meta.setdefault("dataset", ds.name)
            rows = shot_rows(float_array(ds[()], f"samples[{ds.name}]"), f"samples[{ds.name}]")
            for j, r in enumerate(rows):
                m = dict(meta)
                if len(rows) > 1:
                    m["row"] = j
                parts.append((start, step, r, unit, attrs.get("calibration"), m))
    return as_waveforms(parts, calibration, path.name)


def write_hdf5(path: Path, waves: list[Waveform], group: str = "shots") -> None:
    import h5py

    with h5py.File(path, "w") as fh:
        grp = fh.require_group(group)
        for i, w in enumerate(waves):
            ds = grp.create_dataset(f"shot_{i:03d}", data=w.samples, compression="gzip")
            ds.attrs["t0"] = w.t0
            ds.attrs["dt"] = w.dt
            ds.attrs["units"] = w.units
            if w.calibration is not None:
                ds.attrs["calibration"] = w.calibration
            for key, value in w.metadata.items():
                if key in ("source", "dataset"):
                    continue
                ds.attrs[key] = value if isinstance(value, int | float | str) and not \
                    isinstance(value, bool) else json.dumps(_jsonable(value))


def outside_references(path: Path) -> list[str]:
    """What in the file reaches outside it: external links, datasets stored in external files,
    virtual datasets (each would make a reader read other files: a path the file's author
    chose). Empty for a self-contained file, and for a file not readable as HDF5 at all (the
    reader reports that)."""
    import h5py

    problems: list[str] = []

    def visit(name: str, link: Any) -> None:
        if isinstance(link, h5py.ExternalLink):
            problems.append(f"{name!r} is an external link")

    def visit_obj(name: str, obj: Any) -> None:
        if isinstance(obj, h5py.Dataset):
            if obj.external:
                problems.append(f"{name!r} stores its data in an external file")
            if obj.is_virtual:
                problems.append(f"{name!r} is a virtual dataset")

    try:
        with h5py.File(path, "r") as fh:
            fh.visititems_links(visit)
            if not problems:
                fh.visititems(visit_obj)
    except Exception:
        return []  # not readable as HDF5 at all: the reader reports it
    return problems


def hdf5_values(path: Path, dataset: str | None = None) -> int | None:
    """Values in every dataset the reader would decode (all, or those under ``dataset``), from
    their shapes and types; None for a ``dataset`` the file lacks (the reader names what the
    file holds)."""
    import h5py

    total = 0

    def visit(_name: str, obj: Any) -> None:
        nonlocal total
        if isinstance(obj, h5py.Dataset) and obj.shape is not None:
            total += array_values(obj.shape, obj.dtype)

    with h5py.File(path, "r") as fh:
        root = fh
        if dataset is not None:
            if dataset not in fh:
                return None
            root = fh[dataset]
        if isinstance(root, h5py.Dataset):
            visit(root.name, root)
        else:
            root.visititems(visit)  # the objects the reader visits, each once
    return total


FORMAT = FileFormat("hdf5", (".h5", ".hdf5", ".hdf"), (*COMMON_OPTIONS, "dataset"), read_hdf5,
                    write_hdf5, aliases=("h5", "hdf"), declared_values=hdf5_values,
                    outside_references=outside_references)
