"""Waveform files: read and write CSV, NPY/NPZ, HDF5, TDMS and the REST service's JSON.

``read(path, format=None, **options) -> list[Waveform]`` (one per shot) and
``write(path, waveforms, format=None, **options)``. The format comes from the extension; an
extension that could be several formats (``.txt``, ``.dat``) or none needs an explicit
``format=``, never a guess. Every reader takes the options

``sample_rate=`` (Hz) or ``dt=`` (s)
    The sample period of data without a time axis. Data with their own time axis (a time column,
    a ``dt``/``sample_rate`` attribute or comment, ``wf_increment``) keep it; an option that
    disagrees with it by more than 1 % of a period is an error naming the option.
``t0=`` (s)
    Time of the first sample; an explicit value wins over the file's.
``units=`` (``"N"`` or ``"V"``)
    Units of data that do not state them (default N). A file that states its units keeps them;
    an option that contradicts them is an error naming ``units``.
``calibration=`` (N/V)
    Sensor sensitivity for data in volts (it wins over the file's own). Giving one for a file
    whose data are all in newtons is an error naming ``calibration``.

plus ``dataset=`` (HDF5) and ``group=``, ``channel=`` (TDMS); :data:`READER_OPTIONS` lists them.
An unknown option is an error naming it. A file a parser cannot read raises
:class:`~.errors.WaveformError` (field ``file`` unless a field is known), never the parser's
own exception. Metadata identifiers (``plate_id``, ``position``, ``shot`` labels) stay text;
``t0``, ``dt``, ``sample_rate`` and ``calibration`` must be numbers; ``sphere_diameter``,
``x_m`` and ``y_m`` are numbers when they read as one (else left as given, for the consumer to
name); other text values are decoded only when they are JSON objects, lists, booleans or null.
Layouts:

csv
    Text tables as scopes, DAQ programs and spreadsheets write them (Tektronix, Keysight,
    Rigol, PicoScope, LeCroy, units in the column names, comma/semicolon/tab delimited, decimal
    commas: :mod:`.csv_layouts` lists them), and this project's own: optional leading
    ``# key: value`` comment lines (metadata; ``# dt:``, ``# sample_rate:``, ``# t0:``,
    ``# calibration:`` are used as such), then a header ``time_s,force_N``. UTF-8 (a byte-order
    mark is allowed) or Windows-1252. Units come from the file and are scaled to s and V or N;
    the time column is the time axis, never a shot; each value column is a channel (metadata
    ``channel``: its label) and a shot. A header-less table whose first column is a uniform,
    increasing ramp is ``time, values...``; otherwise every column is a shot. Without a time
    column the sample period comes from the comments or ``sample_rate=``; ``t0`` defaults to 0.
npy
    2-D ``(n_samples, 1 + shots)`` with a uniform time axis in column 0; otherwise samples only
    (1-D, or one shot per row), which need ``sample_rate=``.
npz
    ``samples`` (1-D or one shot per row) with ``dt`` or ``sample_rate`` (or the option), optional
    ``t0``, ``units``, ``calibration`` and ``metadata`` (a JSON string: an object, or a list of
    objects with one per shot).
hdf5
    Every dataset (or those under ``dataset=``, a path to a dataset or group) is a shot, or one
    shot per row when 2-D; attributes ``dt`` or ``sample_rate``, optional ``t0``, ``units``,
    ``calibration``; all other attributes become metadata.
tdms
    Channels with the NI waveform properties ``wf_increment`` and ``wf_start_offset``; select with
    ``group=`` and ``channel=`` (a name or a list); ``unit_string`` gives the units (``N``,
    ``Newtons``, ``V``, ``Volts``), other properties become metadata.
json
    The REST service's shot ``{"t0", "dt", "samples", "units", "calibration", "metadata"}`` (with
    ``metadata`` holding ``plate_id``, ``position``, ``sphere_diameter``, ``shot`` and ``extra``;
    a flat metadata object is read too), a list of them, or ``{"shots": [...]}``.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .atomic import atomic_path
from .errors import WaveformError
from .waveform import MIN_SAMPLES, UNIFORM_TOLERANCE, UNITS, Waveform, _jsonable, uniform_grid

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
_COMMON_OPTIONS = ("sample_rate", "dt", "t0", "units", "calibration")
READER_OPTIONS: dict[str, tuple[str, ...]] = {
    "csv": _COMMON_OPTIONS, "npy": _COMMON_OPTIONS, "npz": _COMMON_OPTIONS,
    "hdf5": (*_COMMON_OPTIONS, "dataset"), "tdms": (*_COMMON_OPTIONS, "group", "channel"),
    "json": _COMMON_OPTIONS,
}
"""The options each reader accepts (see the module docstring)."""

IDENTIFIERS = ("plate_id", "position")
"""Metadata that label things: kept as text, never read as numbers (``007`` is not 7)."""
NUMERIC_METADATA = ("t0", "dt", "sample_rate", "calibration", "wf_increment", "wf_start_offset")
"""Metadata the reader needs as numbers; a file holding anything else there is refused."""
UNIT_NAMES = {"n": "N", "newton": "N", "newtons": "N", "v": "V", "volt": "V", "volts": "V"}
"""Unit spellings found in files (TDMS ``unit_string``, attributes), case-insensitive."""


class OptionNeeded(WaveformError):
    """The data need an option the caller did not give: ``sample_rate`` (no time axis) or
    ``calibration`` (samples in volts without one). ``option`` names it; ``field`` may carry a
    path prefix (``shots[2].calibration``)."""

    def __init__(self, option: str, message: str, allowed: str | None = None,
                 field: str | None = None) -> None:
        super().__init__(field or option, message, allowed)
        self.option = option


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

    Options given as ``None`` are ignored. Every shot gets ``metadata["source"]`` (the file name)
    and ``metadata["shot"]`` (its index in the file) unless the file names them.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    WaveformError
        For an unknown option, and for anything wrong with the file: a parser's own exception
        (bad JSON, bad text encoding, a malformed table or array) becomes one naming ``file``.
    """
    path = Path(path)
    fmt = detect_format(path, format)
    if not path.exists():
        raise FileNotFoundError(f"no such file: {path}")
    given = {k: v for k, v in options.items() if v is not None}
    allowed = READER_OPTIONS[fmt]
    for key in given:
        if key not in allowed:
            raise WaveformError(key, f"not an option of the {fmt} reader", ", ".join(allowed))
    try:
        waves = _READERS[fmt](path, **given)
    except WaveformError:
        raise
    except Exception as exc:  # a malformed file broke a parser: the file's error, not a crash
        raise WaveformError(
            "file", f"{path.name} cannot be read as {fmt} ({type(exc).__name__}: {exc})"
        ) from None  # the message carries it; the traceback would pin the reader's open objects
    if not waves:
        raise WaveformError("samples", f"{path.name} holds no shots")
    out = []
    for i, w in enumerate(waves):
        meta = _identifiers_as_text({"source": path.name, "shot": i, **w.metadata})
        out.append(w.with_metadata(**meta))
    return out


def write(
    path: str | Path, waveforms: Waveform | Sequence[Waveform], format: str | None = None,
    **options: Any,
) -> Path:
    """Write shots to ``path`` atomically (temporary name, then rename); returns the path.

    The file gets the permissions of any file the user makes (0644 under the usual umask), not
    the temporary file's 0600."""
    path = Path(path)
    fmt = detect_format(path, format)
    waves = [waveforms] if isinstance(waveforms, Waveform) else list(waveforms)
    if not waves:
        raise WaveformError("waveforms", "nothing to write", "at least one shot")
    with atomic_path(path) as tmp:
        _WRITERS[fmt](tmp, waves, **options)
    return path


# --- shared helpers ---------------------------------------------------------------------------


def _identifiers_as_text(meta: Mapping[str, Any]) -> dict[str, Any]:
    """``plate_id`` and ``position`` as text (a file may store them as numbers)."""
    out = dict(meta)
    for key in IDENTIFIERS:
        if out.get(key) is not None and not isinstance(out[key], str):
            out[key] = str(out[key])
    return out


def _decode(value: Any, key: str | None = None) -> Any:
    """Metadata value ``key`` from a file as Python: bytes to str, numpy to Python.

    Identifiers stay text; the keys the reader needs as numbers must be one number;
    ``sphere_diameter`` text becomes a number when it is one; other text is decoded only when it
    is a JSON object, list, boolean or null (``# scene: {...}``), so labels keep their digits.
    """
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, bytes):
        value = value.decode("utf-8", "replace")
    if key in IDENTIFIERS or key == "shot":
        return value.strip() if isinstance(value, str) else value
    if key in ("sphere_diameter", "x_m", "y_m") and isinstance(value, str):
        try:  # a number when it is one; anything else is left for the consumer to name
            return float(value)
        except ValueError:
            return value
    if key in NUMERIC_METADATA:
        if isinstance(value, bool) or not isinstance(value, str | int | float):
            raise WaveformError(key, f"expected one number, got {value!r}")
        try:
            return float(value)
        except ValueError:
            raise WaveformError(key, f"expected a number, got {value!r}") from None
    if isinstance(value, str):
        text = value.strip()
        if text[:1] in "{[" or text in ("true", "false", "null"):
            try:
                return json.loads(text)
            except ValueError:
                return value
    return value


def _units(stated: Any, option: str | None, where: str) -> str:
    """Units of the data: the file's (``stated``, any spelling in :data:`UNIT_NAMES`), else the
    ``units=`` option, else N; an option contradicting the file is an error."""
    if option is not None and option not in UNITS:
        raise WaveformError("units", f"unknown units {option!r}", "'N' or 'V'")
    if stated is None or (isinstance(stated, str) and not stated.strip()):
        return option or "N"
    unit = UNIT_NAMES.get(str(stated).strip().lower())
    if unit is None:
        raise WaveformError("units", f"{where}: unknown units {stated!r}",
                            "N (Newtons) or V (Volts)")
    if option is not None and option != unit:
        raise WaveformError("units", f"{where}: the file says its data are in {unit}, not "
                            f"{option}", f"units='{unit}' or no units= option")
    return unit


def _positive(name: str, value: Any) -> float:
    number = float(value)
    if not np.isfinite(number) or number <= 0:
        raise WaveformError(name, f"must be positive and finite, got {value!r}",
                            "Hz > 0" if name == "sample_rate" else "s > 0")
    return number


def _own_dt(dt: Any, sample_rate: Any) -> float | None:
    """The sample period a file states (``dt`` or ``sample_rate``), or None."""
    if dt is not None:
        return _positive("dt", dt)
    if sample_rate is not None:
        return 1.0 / _positive("sample_rate", sample_rate)
    return None


def _step(own: float | None, sample_rate: float | None, dt: float | None, where: str,
          hint: str = "sample_rate= in Hz (or dt= in s)") -> float:
    """The sample period: the file's own (an option must agree with it), else the option's."""
    given = _own_dt(dt, sample_rate)
    if own is None:
        if given is None:
            raise OptionNeeded("sample_rate", f"{where} has no time axis; give the sample rate",
                               hint)
        return given
    if given is not None and abs(given - own) > UNIFORM_TOLERANCE * own:
        name = "dt" if dt is not None else "sample_rate"
        raise WaveformError(
            name, f"{where} has its own time axis (dt = {own:.6g} s, {1 / own:.6g} Hz); "
            f"{name}= says dt = {given:.6g} s ({1 / given:.6g} Hz)",
            "the file's own rate, or no option",
        )
    return own


def _shots(parts: list[tuple[float, float, Any, str, Any, dict[str, Any]]],
           calibration: float | None, where: str, prefix: str | None = None) -> list[Waveform]:
    """Waveforms from ``(t0, dt, samples, units, own calibration, metadata)`` tuples.

    ``calibration=`` applies to the shots in volts (over their own); a file with none in volts
    refuses it, and a shot in volts with no calibration at all raises :class:`OptionNeeded`.
    With ``prefix``, a shot's error names ``prefix[i].field``.
    """
    if calibration is not None and not any(p[3] == "V" for p in parts):
        raise WaveformError("calibration", f"{where}: the data are in newtons; a calibration "
                            "(N/V) converts volts only", "no calibration for data in N")
    out = []
    for i, (t0, dt, samples, units, own_cal, meta) in enumerate(parts):
        cal = calibration if calibration is not None and units == "V" else own_cal
        try:
            if units == "V" and cal is None:
                raise OptionNeeded("calibration", f"{where}: samples are in volts but no "
                                   "calibration was given", "calibration= sensor sensitivity "
                                   "in N/V")
            out.append(Waveform(t0, dt, samples, units, cal, meta))
        except WaveformError as exc:
            if prefix is None:
                raise
            raise _prefixed(exc, f"{prefix}[{i}]") from None
    return out


def _float_array(data: Any, name: str) -> np.ndarray:
    """Real numeric data as float64; text, objects and complex numbers are refused."""
    array = np.asarray(data)
    if array.dtype.kind not in "biuf":
        raise WaveformError(name, f"not real numbers (dtype {array.dtype})", "integer or float")
    return array.astype(np.float64)


def _is_time_axis(column: np.ndarray) -> bool:
    try:
        uniform_grid(column)
    except WaveformError:
        return False
    return True


def _rows(array: np.ndarray, name: str) -> list[np.ndarray]:
    if array.ndim == 1:
        return [array]
    if array.ndim == 2:
        return list(array)
    raise WaveformError(name, f"expected 1-D or 2-D data, got shape {array.shape}")


# --- CSV ----------------------------------------------------------------------------------------

def _read_csv(
    path: Path, sample_rate: float | None = None, dt: float | None = None,
    t0: float | None = None, units: str | None = None, calibration: float | None = None,
) -> list[Waveform]:
    """Any layout :mod:`.csv_layouts` knows; one waveform per value column."""
    from .csv_layouts import SCOPE_LAYOUTS, parse

    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        try:  # Windows spreadsheets and scope software write the ANSI code page ("µs")
            text = raw.decode("cp1252")
        except UnicodeDecodeError:
            raise WaveformError("file", f"{path.name}: not text (byte "
                                f"{exc.object[exc.start]:#x} at offset {exc.start})",
                                "UTF-8 or Windows-1252 text") from None
    table = parse(text, path.name)
    meta = {k: _decode(v, k) for k, v in table.metadata.items()}
    file_t0, file_dt, file_rate = (meta.pop(k, None) for k in ("t0", "dt", "sample_rate"))
    own: float | None
    if table.time is not None:
        own_t0, own = uniform_grid(table.time, rounding=table.time_resolution)
    else:
        own_t0 = 0.0 if file_t0 is None else file_t0
        own = _own_dt(file_dt, file_rate)
    step = _step(own, sample_rate, dt, path.name)
    start = own_t0 if t0 is None else t0
    own_cal = meta.pop("calibration", None)
    vendor = table.layout in SCOPE_LAYOUTS or table.layout == "generic"
    parts = []
    for j, column in enumerate(table.columns):
        unit = _units(column.unit, units, f"{path.name} column {column.label!r}")
        m = dict(meta)
        if len(table.columns) > 1 or vendor:
            m.setdefault("channel", column.label)
        if len(table.columns) > 1:
            m["shot"] = j
        parts.append((start, step, column.values, unit, own_cal, m))
    return _shots(parts, calibration, path.name)


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
        fh.write(f"# n_samples: {ref.n}\n")  # lets a reader tell a file cut short
        labels = ["time_s"] + [("force_N" if w.units == "N" else "voltage_V") for w in waves]
        fh.write(",".join(labels) + "\n")
        table = np.column_stack([ref.times] + [w.samples for w in waves])
        np.savetxt(fh, table, delimiter=",", fmt="%.9g")


# --- NPY / NPZ ------------------------------------------------------------------------------------


def _read_npy(
    path: Path, sample_rate: float | None = None, dt: float | None = None,
    t0: float | None = None, units: str | None = None, calibration: float | None = None,
) -> list[Waveform]:
    array = _float_array(np.load(path, allow_pickle=False), "samples")
    unit = _units(None, units, path.name)
    if array.ndim == 2 and array.shape[0] >= MIN_SAMPLES and array.shape[1] >= 2 \
            and _is_time_axis(array[:, 0]):
        own_t0, own = uniform_grid(array[:, 0])
        step = _step(own, sample_rate, dt, path.name)
        start = own_t0 if t0 is None else t0
        parts = [(start, step, array[:, j], unit, None, {"shot": j - 1})
                 for j in range(1, array.shape[1])]
        return _shots(parts, calibration, path.name)
    if sample_rate is None and dt is None and array.ndim == 2 and array.shape[1] >= 2 \
            and array.shape[0] >= MIN_SAMPLES:
        uniform_grid(array[:, 0])  # raises, naming what is wrong with the would-be time column
    step = _step(None, sample_rate, dt, f"{path.name} (shape {array.shape})",
                 "a 2-D array (n_samples, 1 + shots) with time in column 0, or sample_rate=")
    start = 0.0 if t0 is None else t0
    parts = [(start, step, r, unit, None, {}) for r in _rows(array, "samples")]
    return _shots(parts, calibration, path.name)


def _write_npy(path: Path, waves: list[Waveform]) -> None:
    ref = waves[0]
    for w in waves[1:]:
        if w.n != ref.n or w.t0 != ref.t0 or w.dt != ref.dt:
            raise WaveformError("waveforms", "NPY shots must share t0, dt and length")
    table = np.column_stack([ref.times] + [w.force for w in waves])
    with path.open("wb") as fh:
        np.save(fh, table)


def _read_npz(
    path: Path, sample_rate: float | None = None, dt: float | None = None,
    t0: float | None = None, units: str | None = None, calibration: float | None = None,
) -> list[Waveform]:
    with np.load(path, allow_pickle=False) as data:
        if "samples" not in data:
            raise WaveformError("samples", f"{path.name}: no 'samples' array",
                                f"keys samples, dt or sample_rate; found {sorted(data.files)}")
        samples = _float_array(data["samples"], "samples")
        found = {k: _decode(data[k], k) for k in ("dt", "sample_rate", "t0", "calibration")
                 if k in data}
        stated = _decode(data["units"]) if "units" in data else None
        meta_text = _decode(data["metadata"]) if "metadata" in data else {}
    step = _step(_own_dt(found.get("dt"), found.get("sample_rate")), sample_rate, dt, path.name)
    start = found.get("t0", 0.0) if t0 is None else t0
    unit = _units(stated, units, path.name)
    try:
        meta = json.loads(meta_text) if isinstance(meta_text, str) else meta_text
    except ValueError:
        raise WaveformError("metadata", f"{path.name}: not valid JSON ({meta_text[:80]!r})",
                            "a JSON object, or a list of one object per shot") from None
    meta = {} if meta is None else meta
    rows = _rows(samples, "samples")
    metas = meta if isinstance(meta, list) else [meta] * len(rows)
    if len(metas) != len(rows) or not all(isinstance(m, dict) for m in metas):
        raise WaveformError("metadata", f"{path.name}: {meta_text!r} for {len(rows)} shots",
                            "a JSON object, or a list of one object per shot")
    parts = [(start, step, r, unit, found.get("calibration"), m)
             for r, m in zip(rows, metas, strict=True)]
    return _shots(parts, calibration, path.name)


def _write_npz(path: Path, waves: list[Waveform]) -> None:
    ref = waves[0]
    for w in waves[1:]:
        if w.n != ref.n or w.t0 != ref.t0 or w.dt != ref.dt or w.units != ref.units:
            raise WaveformError("waveforms", "NPZ shots must share t0, dt, length and units")
    extra: dict[str, Any] = ({"calibration": np.float64(ref.calibration)}
                             if ref.calibration is not None else {})
    with path.open("wb") as fh:
        np.savez_compressed(
            fh, samples=np.vstack([w.samples for w in waves]), t0=np.float64(ref.t0),
            dt=np.float64(ref.dt), units=np.str_(ref.units),
            metadata=np.str_(json.dumps([_jsonable(w.metadata) for w in waves])), **extra,
        )


# --- HDF5 -----------------------------------------------------------------------------------------

_HDF_KEYS = ("dt", "sample_rate", "t0", "units", "calibration")


def _read_hdf5(
    path: Path, dataset: str | None = None, sample_rate: float | None = None,
    dt: float | None = None, t0: float | None = None, units: str | None = None,
    calibration: float | None = None,
) -> list[Waveform]:
    import h5py

    parts: list[tuple[float, float, Any, str, Any, dict[str, Any]]] = []
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
            attrs = {k: _decode(v, k) for k, v in raw.items()}
            step = _step(_own_dt(attrs.get("dt"), attrs.get("sample_rate")), sample_rate, dt,
                         where)
            start = attrs.get("t0", 0.0) if t0 is None else t0
            unit = _units(attrs.get("units"), units, where)
            meta = {k: v for k, v in attrs.items() if k not in _HDF_KEYS}
            meta.setdefault("dataset", ds.name)
            rows = _rows(_float_array(ds[()], f"samples[{ds.name}]"), f"samples[{ds.name}]")
            for j, r in enumerate(rows):
                m = dict(meta)
                if len(rows) > 1:
                    m["row"] = j
                parts.append((start, step, r, unit, attrs.get("calibration"), m))
    return _shots(parts, calibration, path.name)


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
    parts: list[tuple[float, float, Any, str, Any, dict[str, Any]]] = []
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
            props = {k: _decode(v, k) for k, v in dict(ch.properties).items()}
            if "wf_increment" not in props:
                if wanted is not None:
                    raise WaveformError("dt", f"channel {g.name}/{ch.name} has no wf_increment",
                                        "NI waveform channels (wf_increment, wf_start_offset)")
                continue
            unit = _units(props.pop("unit_string", None), units, where)
            own_cal = props.pop("calibration", None)
            start = float(props.pop("wf_start_offset", 0.0))
            step = _step(_positive("dt", props.pop("wf_increment")), sample_rate, dt, where)
            meta = {k: v for k, v in props.items() if not k.startswith(("wf_", "NI_"))}
            meta.update(group=g.name, channel=ch.name)
            parts.append((start if t0 is None else t0, step, _float_array(ch[:], "samples"),
                          unit, own_cal, meta))
    if wanted is not None and not parts:
        raise WaveformError("channel", f"none of {wanted} found in {path.name}")
    return _shots(parts, calibration, path.name)


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


def from_json(
    body: Any, sample_rate: float | None = None, dt: float | None = None,
    t0: float | None = None, units: str | None = None, calibration: float | None = None,
) -> list[Waveform]:
    """Shots from the REST service's JSON shape (a shot object, a list, or ``{"shots": [...]}``).

    Metadata is the service's (``plate_id``, ``position``, ``sphere_diameter``, ``shot`` and
    free-form ``extra``, merged into one mapping as the service does) or a flat mapping. The
    options mean what they mean for files (see the module docstring).
    """
    if isinstance(body, Mapping) and "shots" in body:
        shots = body["shots"]
        common = _flat_metadata(body.get("metadata"), "metadata")
        if not isinstance(shots, list):
            raise WaveformError("shots", "must be a list of shot objects")
    elif isinstance(body, list):
        shots, common = body, {}
    elif isinstance(body, Mapping):
        shots, common = [body], {}
    else:
        raise WaveformError("body", f"expected an object or a list, got {type(body).__name__}")
    parts = []
    for i, shot in enumerate(shots):
        where = f"shots[{i}]"
        if not isinstance(shot, Mapping):
            raise WaveformError(where, "must be an object with t0, dt, samples")
        if "samples" not in shot:
            raise WaveformError(f"{where}.samples", "missing", "a list of numbers")
        try:
            own = _own_dt(shot.get("dt"), shot.get("sample_rate"))
            if own is None and sample_rate is None and dt is None:
                raise WaveformError("dt", "missing (no dt nor sample_rate)", "dt in s > 0")
            step = _step(own, sample_rate, dt, where)
            meta = {**common, **_flat_metadata(shot.get("metadata"), "metadata")}
            parts.append((shot.get("t0", 0.0) if t0 is None else t0, step,
                          _float_array(shot["samples"], "samples"),
                          _units(shot.get("units"), units, where), shot.get("calibration"),
                          _identifiers_as_text(meta)))
        except WaveformError as exc:
            raise _prefixed(exc, where) from None
        except (TypeError, ValueError) as exc:
            raise WaveformError(where, f"not a valid shot ({exc})") from None
    return _shots(parts, calibration, "body", prefix="shots")


def _prefixed(exc: WaveformError, where: str) -> WaveformError:
    field = f"{where}.{exc.field}"
    if isinstance(exc, OptionNeeded):
        return OptionNeeded(exc.option, exc.message, exc.allowed, field=field)
    return WaveformError(field, exc.message, exc.allowed)


def _flat_metadata(metadata: Any, where: str) -> dict[str, Any]:
    """The service's metadata (schema keys plus ``extra``) or a flat mapping, as one mapping."""
    if metadata is None:
        return {}
    if not isinstance(metadata, Mapping):
        raise WaveformError(where, f"must be an object, got {type(metadata).__name__}")
    flat = {k: v for k, v in metadata.items() if k != "extra"}
    extra = metadata.get("extra") or {}
    if not isinstance(extra, Mapping):
        raise WaveformError(f"{where}.extra", "must be an object of key/value pairs")
    flat.update({str(k): _decode(v, str(k)) for k, v in extra.items()})
    return flat


def to_json(waves: Sequence[Waveform]) -> dict[str, Any]:
    """The ``{"shots": [...]}`` JSON shape of :func:`from_json`."""
    return {"shots": [w.to_dict() for w in waves]}


def _read_json(path: Path, **options: Any) -> list[Waveform]:
    try:
        body = json.loads(path.read_bytes().decode("utf-8-sig"))
    except ValueError as exc:  # UnicodeDecodeError and JSONDecodeError are ValueErrors
        raise WaveformError("file", f"{path.name}: not valid UTF-8 JSON ({exc})") from None
    return from_json(body, **options)


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
