"""Waveform files: read and write CSV, NPY/NPZ, HDF5, TDMS and the REST service's JSON.

``read(path, format=None, **options) -> list[Waveform]`` (one per shot) and
``write(path, waveforms, format=None, **options)``. The format comes from the extension; an
extension that could be several formats (``.txt``, ``.dat``) or none needs an explicit
``format=``, never a guess. Layouts:

csv
    Optional leading ``# key: value`` comment lines (metadata; values that parse as JSON are
    decoded, e.g. ``# scene: {...}``), then a header ``time_s,force_N`` (more force columns = more
    shots; ``voltage_V`` columns need ``calibration=``). A single column of samples without a time
    column needs ``sample_rate=`` (Hz); ``t0=`` defaults to 0.
npy
    2-D ``(n_samples, 1 + shots)`` with time in column 0; or, with ``sample_rate=``, samples only
    (1-D, or one shot per row).
npz
    ``samples`` (1-D or one shot per row) with ``dt`` or ``sample_rate``, optional ``t0``,
    ``units``, ``calibration`` and ``metadata`` (a JSON string: an object, or a list of objects
    with one per shot).
hdf5
    Every dataset (or those under ``dataset=``, a path to a dataset or group) is a shot, or one
    shot per row when 2-D; attributes ``dt`` or ``sample_rate``, optional ``t0``, ``units``,
    ``calibration``; all other attributes become metadata.
tdms
    Channels with the NI waveform properties ``wf_increment`` and ``wf_start_offset``; select with
    ``group=`` and ``channel=`` (a name or a list); ``unit_string`` gives the units, other
    properties become metadata.
json
    ``{"t0", "dt", "samples", "units", "calibration", "metadata"}`` or ``{"shots": [...]}``.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .errors import WaveformError
from .waveform import UNITS, Waveform, _jsonable, check_samples, uniform_grid

FORMATS = ("csv", "npy", "npz", "hdf5", "tdms", "json")
EXTENSIONS = {
    ".csv": "csv",
    ".npy": "npy",
    ".npz": "npz",
    ".h5": "hdf5",
    ".hdf5": "hdf5",
    ".hdf": "hdf5",
    ".tdms": "tdms",
    ".json": "json",
}
AMBIGUOUS = (".txt", ".dat", ".asc", ".tsv")


def detect_format(path: str | Path, format: str | None = None) -> str:
    """The format to use for ``path``: ``format`` when given, else from the extension."""
    if format is not None:
        fmt = str(format).lower()
        fmt = {"h5": "hdf5", "hdf": "hdf5"}.get(fmt, fmt)
        if fmt not in FORMATS:
            raise WaveformError("format", f"unknown format {format!r}", ", ".join(FORMATS))
        return fmt
    ext = Path(path).suffix.lower()
    if ext in EXTENSIONS:
        return EXTENSIONS[ext]
    if ext in AMBIGUOUS:
        raise WaveformError(
            "format", f"the extension {ext!r} of {Path(path).name} could be several formats; "
            "pass format= explicitly", ", ".join(FORMATS),
        )
    raise WaveformError(
        "format", f"unknown extension {ext or '(none)'!r} of {Path(path).name}; pass format=",
        "extensions " + ", ".join(sorted(EXTENSIONS)),
    )


def read(path: str | Path, format: str | None = None, **options: Any) -> list[Waveform]:
    """Read every shot in ``path``; ``options`` depend on the format (see the module docstring).

    Every shot gets ``metadata["source"]`` (the file name) and ``metadata["shot"]`` (its index in
    the file) unless the file names them.
    """
    path = Path(path)
    fmt = detect_format(path, format)
    if not path.exists():
        raise FileNotFoundError(f"no such file: {path}")
    reader = _READERS[fmt]
    try:
        waves = reader(path, **options)
    except TypeError as exc:
        if "unexpected keyword" in str(exc):
            raise WaveformError("options", f"{fmt} reader: {exc}") from None
        raise
    if not waves:
        raise WaveformError("samples", f"{path.name} holds no shots")
    out = []
    for i, w in enumerate(waves):
        meta = {"source": path.name, "shot": i, **w.metadata}
        out.append(w.with_metadata(**meta))
    return out


def write(
    path: str | Path, waveforms: Waveform | Sequence[Waveform], format: str | None = None,
    **options: Any,
) -> Path:
    """Write shots to ``path`` atomically (temporary name, then rename); returns the path."""
    path = Path(path)
    fmt = detect_format(path, format)
    waves = [waveforms] if isinstance(waveforms, Waveform) else list(waveforms)
    if not waves:
        raise WaveformError("waveforms", "nothing to write", "at least one shot")
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=path.suffix)
    os.close(fd)
    try:
        _WRITERS[fmt](Path(tmp), waves, **options)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


# --- shared helpers ---------------------------------------------------------------------------


def _units_of(label: str) -> str:
    """Units from a column label such as ``force_N`` or ``voltage_V``."""
    suffix = label.rsplit("_", 1)[-1] if "_" in label else ""
    if suffix not in UNITS:
        raise WaveformError(
            "units", f"column {label!r} does not end in a known unit", "a '_N' or '_V' suffix"
        )
    return suffix


def _dt_from(options: Mapping[str, Any], where: str) -> float:
    if options.get("dt") is not None:
        return float(options["dt"])
    rate = options.get("sample_rate")
    if rate is None:
        raise WaveformError(
            "sample_rate", f"{where} has no time column; give the sample rate",
            "sample_rate= in Hz (or dt= in s)",
        )
    rate = float(rate)
    if not np.isfinite(rate) or rate <= 0:
        raise WaveformError("sample_rate", f"must be positive, got {rate}", "Hz > 0")
    return 1.0 / rate


def _decode(value: Any) -> Any:
    """Metadata value from a file: bytes to str, numpy scalars to Python, JSON text decoded."""
    if isinstance(value, bytes):
        value = value.decode("utf-8", "replace")
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, str):
        text = value.strip()
        if text[:1] in "{[" or text in ("true", "false", "null"):
            try:
                return json.loads(text)
            except ValueError:
                return value
        try:
            number = float(text)
        except ValueError:
            return value
        return int(number) if number.is_integer() and "." not in text and "e" not in text.lower() \
            else number
    return value


def _rows(array: np.ndarray, name: str) -> list[np.ndarray]:
    if array.ndim == 1:
        return [array]
    if array.ndim == 2:
        return list(array)
    raise WaveformError(name, f"expected 1-D or 2-D data, got shape {array.shape}")


# --- CSV ----------------------------------------------------------------------------------------


def _read_csv(
    path: Path, sample_rate: float | None = None, dt: float | None = None, t0: float = 0.0,
    calibration: float | None = None, units: str | None = None,
) -> list[Waveform]:
    import pandas as pd

    meta: dict[str, Any] = {}
    skip = 0
    with path.open("r", encoding="utf-8") as fh:
        for line in fh:
            if not line.startswith("#"):
                break
            skip += 1
            key, sep, value = line[1:].partition(":")
            if sep and key.strip():
                meta[key.strip()] = _decode(value.strip())
    try:
        frame = pd.read_csv(path, skiprows=skip, header=None, dtype=str, skip_blank_lines=True)
    except pd.errors.EmptyDataError:
        raise WaveformError("samples", f"{path.name}: empty, no samples") from None
    first = [str(c).strip() for c in frame.iloc[0]]
    has_header = any(_not_number(c) for c in first)
    labels = first if has_header else None
    body = frame.iloc[1:] if has_header else frame
    if body.empty:
        raise WaveformError("samples", f"{path.name}: empty, no samples")
    try:
        data = body.apply(pd.to_numeric, errors="raise").to_numpy(dtype=np.float64)
    except (ValueError, TypeError) as exc:
        raise WaveformError("samples", f"{path.name}: non-numeric value ({exc})") from None
    options = {"sample_rate": sample_rate, "dt": dt}
    if labels is not None and labels[0].lower() in ("time_s", "time", "t_s", "t"):
        if data.shape[1] < 2:
            raise WaveformError("channel", f"{path.name}: a time column but no sample column",
                                "time_s,force_N")
        time = data[:, 0]
        _t0, _dt = uniform_grid(time)
        columns = [(labels[j], data[:, j]) for j in range(1, data.shape[1])]
    else:
        _dt = _dt_from(options, f"{path.name}")
        _t0 = float(meta.pop("t0", t0)) if "t0" in meta else float(t0)
        names = labels if labels is not None else [f"force_{units or 'N'}"] * data.shape[1]
        columns = [(names[j], data[:, j]) for j in range(data.shape[1])]
    for key in ("t0", "dt", "sample_rate"):
        meta.pop(key, None)
    cal = calibration if calibration is not None else meta.pop("calibration", None)
    out = []
    for j, (label, column) in enumerate(columns):
        u = units or _units_of(label)
        m = dict(meta)
        if len(columns) > 1:
            m.setdefault("channel", label)
            m["shot"] = j
        out.append(Waveform(_t0, _dt, check_samples(column), u, cal, m))
    return out


def _not_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return True
    return False


def _write_csv(path: Path, waves: list[Waveform]) -> None:
    ref = waves[0]
    for w in waves[1:]:
        if w.n != ref.n or w.t0 != ref.t0 or w.dt != ref.dt:
            raise WaveformError("waveforms", "CSV shots must share t0, dt and length",
                                "one CSV per time axis")
    with path.open("w", encoding="utf-8", newline="\n") as fh:
        for key, value in ref.metadata.items():
            if key in ("shot", "source"):
                continue
            text = value if isinstance(value, str) else json.dumps(_jsonable(value))
            fh.write(f"# {key}: {text}\n")
        if ref.calibration is not None:
            fh.write(f"# calibration: {ref.calibration!r}\n")
        labels = ["time_s"] + [("force_N" if w.units == "N" else "voltage_V") for w in waves]
        fh.write(",".join(labels) + "\n")
        table = np.column_stack([ref.times] + [w.samples for w in waves])
        np.savetxt(fh, table, delimiter=",", fmt="%.9g")


# --- NPY / NPZ ------------------------------------------------------------------------------------


def _read_npy(
    path: Path, sample_rate: float | None = None, dt: float | None = None, t0: float = 0.0,
    units: str = "N", calibration: float | None = None,
) -> list[Waveform]:
    array = np.load(path, allow_pickle=False)
    if sample_rate is not None or dt is not None:
        step = _dt_from({"sample_rate": sample_rate, "dt": dt}, path.name)
        return [Waveform(t0, step, check_samples(r), units, calibration)
                for r in _rows(np.asarray(array, dtype=np.float64), "samples")]
    if array.ndim != 2 or array.shape[1] < 2:
        raise WaveformError(
            "sample_rate", f"{path.name}: shape {array.shape} has no time column",
            "a 2-D array (n_samples, 1 + shots) with time in column 0, or sample_rate=",
        )
    t_0, step = uniform_grid(array[:, 0])
    return [Waveform(t_0, step, check_samples(array[:, j]), units, calibration, {"shot": j - 1})
            for j in range(1, array.shape[1])]


def _write_npy(path: Path, waves: list[Waveform]) -> None:
    ref = waves[0]
    for w in waves[1:]:
        if w.n != ref.n or w.t0 != ref.t0 or w.dt != ref.dt:
            raise WaveformError("waveforms", "NPY shots must share t0, dt and length")
    table = np.column_stack([ref.times] + [w.force for w in waves])
    with path.open("wb") as fh:
        np.save(fh, table)


def _read_npz(path: Path, **options: Any) -> list[Waveform]:
    with np.load(path, allow_pickle=False) as data:
        if "samples" not in data:
            raise WaveformError("samples", f"{path.name}: no 'samples' array",
                                f"keys samples, dt or sample_rate; found {sorted(data.files)}")
        samples = np.asarray(data["samples"], dtype=np.float64)
        found = {k: data[k].item() for k in ("dt", "sample_rate", "t0", "calibration")
                 if k in data}
        units = str(data["units"]) if "units" in data else options.get("units", "N")
        meta_text = str(data["metadata"]) if "metadata" in data else "{}"
    merged = {**found, **{k: v for k, v in options.items() if v is not None}}
    step = _dt_from(merged, path.name)
    meta = json.loads(meta_text)
    rows = _rows(samples, "samples")
    metas = meta if isinstance(meta, list) else [meta] * len(rows)
    if len(metas) != len(rows):
        raise WaveformError("metadata", f"{len(metas)} metadata entries for {len(rows)} shots")
    return [Waveform(float(merged.get("t0", 0.0)), step, check_samples(r), units,
                     merged.get("calibration"), dict(m)) for r, m in zip(rows, metas, strict=True)]


def _write_npz(path: Path, waves: list[Waveform]) -> None:
    ref = waves[0]
    for w in waves[1:]:
        if w.n != ref.n or w.t0 != ref.t0 or w.dt != ref.dt or w.units != ref.units:
            raise WaveformError("waveforms", "NPZ shots must share t0, dt, length and units")
    extra = {"calibration": np.float64(ref.calibration)} if ref.calibration is not None else {}
    with path.open("wb") as fh:
        np.savez_compressed(
            fh, samples=np.vstack([w.samples for w in waves]), t0=np.float64(ref.t0),
            dt=np.float64(ref.dt), units=np.str_(ref.units),
            metadata=np.str_(json.dumps([_jsonable(w.metadata) for w in waves])), **extra,
        )


# --- HDF5 -----------------------------------------------------------------------------------------

_HDF_KEYS = ("dt", "sample_rate", "t0", "units", "calibration")


def _read_hdf5(path: Path, dataset: str | None = None, **options: Any) -> list[Waveform]:
    import h5py

    out: list[Waveform] = []
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
            attrs = {k: _decode(v) for k, v in ds.attrs.items()}
            merged = {**{k: attrs.get(k) for k in _HDF_KEYS if k in attrs},
                      **{k: v for k, v in options.items() if v is not None}}
            step = _dt_from(merged, f"{path.name}:{ds.name}")
            meta = {k: v for k, v in attrs.items() if k not in _HDF_KEYS}
            meta.setdefault("dataset", ds.name)
            rows = _rows(np.asarray(ds[()], dtype=np.float64), f"samples[{ds.name}]")
            for j, r in enumerate(rows):
                m = dict(meta)
                if len(rows) > 1:
                    m["row"] = j
                out.append(Waveform(float(merged.get("t0", 0.0)), step,
                                    check_samples(r),
                                    str(merged.get("units", "N")), merged.get("calibration"), m))
    return out


def _write_hdf5(path: Path, waves: list[Waveform], group: str = "shots") -> None:
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


# --- TDMS -----------------------------------------------------------------------------------------


def _as_list(value: str | Iterable[str] | None) -> list[str] | None:
    if value is None:
        return None
    return [value] if isinstance(value, str) else list(value)


def _read_tdms(
    path: Path, group: str | None = None, channel: str | Sequence[str] | None = None,
    calibration: float | None = None,
) -> list[Waveform]:
    from nptdms import TdmsFile

    tdms = TdmsFile.read(path)
    groups = {g.name: g for g in tdms.groups()}
    if group is not None and group not in groups:
        raise WaveformError("group", f"no group {group!r} in {path.name}",
                            ", ".join(groups) or "(no groups)")
    chosen = [groups[group]] if group is not None else list(groups.values())
    wanted = _as_list(channel)
    out = []
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
            props = {k: _decode(v) for k, v in ch.properties.items()}
            if "wf_increment" not in props:
                if wanted is not None:
                    raise WaveformError("dt", f"channel {g.name}/{ch.name} has no wf_increment",
                                        "NI waveform channels (wf_increment, wf_start_offset)")
                continue
            unit = str(props.pop("unit_string", "N")) or "N"
            cal = calibration if calibration is not None else props.pop("calibration", None)
            t0 = float(props.pop("wf_start_offset", 0.0))
            step = float(props.pop("wf_increment"))
            meta = {k: v for k, v in props.items() if not k.startswith(("wf_", "NI_"))}
            meta.update(group=g.name, channel=ch.name)
            out.append(Waveform(t0, step, check_samples(ch[:]), unit, cal,
                                meta))
    if wanted is not None and not out:
        raise WaveformError("channel", f"none of {wanted} found in {path.name}")
    return out


def _write_tdms(path: Path, waves: list[Waveform], group: str = "shots") -> None:
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


# --- JSON ---


def from_json(body: Any) -> list[Waveform]:
    """Shots from the REST service's JSON shape (a shot object, a list, or ``{"shots": [...]}``)."""
    if isinstance(body, Mapping) and "shots" in body:
        shots = body["shots"]
        common = body.get("metadata") or {}
        if not isinstance(shots, list):
            raise WaveformError("shots", "must be a list of shot objects")
    elif isinstance(body, list):
        shots, common = body, {}
    elif isinstance(body, Mapping):
        shots, common = [body], {}
    else:
        raise WaveformError("body", f"expected an object or a list, got {type(body).__name__}")
    out = []
    for i, shot in enumerate(shots):
        where = f"shots[{i}]"
        if not isinstance(shot, Mapping):
            raise WaveformError(where, "must be an object with t0, dt, samples")
        if "samples" not in shot:
            raise WaveformError(f"{where}.samples", "missing", "a list of numbers")
        if "dt" not in shot and "sample_rate" not in shot:
            raise WaveformError(f"{where}.dt", "missing (no dt nor sample_rate)", "dt in s > 0")
        step = shot["dt"] if "dt" in shot else 1.0 / float(shot["sample_rate"])
        meta = {**common, **(shot.get("metadata") or {})}
        try:
            out.append(Waveform(shot.get("t0", 0.0), step, shot["samples"],
                                shot.get("units", "N"), shot.get("calibration"), meta))
        except WaveformError as exc:
            raise WaveformError(f"{where}.{exc.field}", exc.message, exc.allowed) from None
    return out


def to_json(waves: Sequence[Waveform]) -> dict[str, Any]:
    """The ``{"shots": [...]}`` JSON shape of :func:`from_json`."""
    return {"shots": [w.to_dict() for w in waves]}


def _read_json(path: Path) -> list[Waveform]:
    try:
        body = json.loads(path.read_text(encoding="utf-8"))
    except ValueError as exc:
        raise WaveformError("body", f"{path.name}: not valid JSON ({exc})") from None
    return from_json(body)


def _write_json(path: Path, waves: list[Waveform]) -> None:
    path.write_text(json.dumps(to_json(waves)), encoding="utf-8")


_READERS: dict[str, Callable[..., list[Waveform]]] = {
    "csv": _read_csv, "npy": _read_npy, "npz": _read_npz, "hdf5": _read_hdf5,
    "tdms": _read_tdms, "json": _read_json,
}
_WRITERS: dict[str, Callable[..., None]] = {
    "csv": _write_csv, "npy": _write_npy, "npz": _write_npz, "hdf5": _write_hdf5,
    "tdms": _write_tdms, "json": _write_json,
}
