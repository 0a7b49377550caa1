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
Layouts (one module each in :mod:`.formats`, listed once in :mod:`.formats.registry`):

csv
    Text tables as scopes, DAQ programs and spreadsheets write them (Tektronix, Keysight,
    Rigol, PicoScope, LeCroy, units in the column names, comma/semicolon/tab delimited, decimal
    commas: :mod:`.formats.csv_layouts` lists them), and this project's own: optional leading
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

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .atomic import atomic_path
from .errors import OptionNeeded, WaveformError
from .formats.reading import IDENTIFIERS, NUMERIC_METADATA, UNIT_NAMES, identifiers_as_text
from .formats.registry import AMBIGUOUS, EXTENSIONS, READER_OPTIONS, detect_format
from .formats.registry import FORMATS as _REGISTRY
from .formats.rest_json import from_json, to_json
from .waveform import Waveform

FORMATS = tuple(_REGISTRY)
"""The format names, in the order listings give them (:mod:`.formats.registry` holds them)."""

__all__ = ["AMBIGUOUS", "EXTENSIONS", "FORMATS", "IDENTIFIERS", "NUMERIC_METADATA",
           "READER_OPTIONS", "UNIT_NAMES", "OptionNeeded", "detect_format", "from_json", "read",
           "to_json", "write"]


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
    allowed = _REGISTRY[fmt].options
    for key in given:
        if key not in allowed:
            raise WaveformError(key, f"not an option of the {fmt} reader", ", ".join(allowed))
    try:
        waves = _REGISTRY[fmt].read(path, **given)
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
        meta = identifiers_as_text({"source": path.name, "shot": i, **w.metadata})
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
        _REGISTRY[fmt].write(tmp, waves, **options)
    return path
