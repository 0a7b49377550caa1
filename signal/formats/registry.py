"""The one list of waveform file formats, and the lookups everything else makes in it.

:data:`FORMATS` maps each ``format=`` name to its :class:`~.base.FileFormat` (one module per
format in this folder). :func:`resolve` turns a name or alias into the format's name,
:func:`by_suffix` a file-name suffix; :func:`detect_format` does what the readers need (an
explicit name wins, else the suffix; an ambiguous suffix is never guessed). The service's upload
checks and the command line's suffix filters use the same lookups, so they cannot drift apart.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import WaveformError
from . import csv_text, hdf5, npy, npz, rest_json, tdms
from .base import FileFormat

FORMATS: dict[str, FileFormat] = {
    f.name: f for f in (csv_text.FORMAT, npy.FORMAT, npz.FORMAT, hdf5.FORMAT, tdms.FORMAT,
                        rest_json.FORMAT)
}
"""Every format by its ``format=`` name, in the order listings give them."""
EXTENSIONS: dict[str, str] = {ext: f.name for f in FORMATS.values() for ext in f.extensions}
"""File-name suffix (lower-case, with the dot) -> format name."""
ALIASES: dict[str, str] = {alias: f.name for f in FORMATS.values() for alias in f.aliases}
"""Other spellings of a format's name (``h5``, ``hdf``) -> its name."""
AMBIGUOUS = (".txt", ".dat", ".asc", ".tsv")
"""Suffixes that several formats (or none) use: a reader needs ``format=`` for them."""
READER_OPTIONS: dict[str, tuple[str, ...]] = {f.name: f.options for f in FORMATS.values()}
"""The options each reader accepts (see :mod:`solitonde.signal.io`)."""


def resolve(name: str) -> str | None:
    """The format a ``format=`` value names (case-insensitive, aliases allowed), or None."""
    key = name.lower()
    key = ALIASES.get(key, key)
    return key if key in FORMATS else None


def by_suffix(path: str | Path) -> str | None:
    """The format a file name's suffix means, or None (no suffix, or not a known one)."""
    return EXTENSIONS.get(Path(path).suffix.lower())


def all_reader_options() -> tuple[str, ...]:
    """Every option some reader takes, each once, in the order the formats list them."""
    return tuple(dict.fromkeys(o for f in FORMATS.values() for o in f.options))


def detect_format(path: str | Path, format: str | None = None) -> str:
    """The format to use for ``path``: ``format`` when given, else from the extension."""
    if format is not None:
        fmt = resolve(str(format))
        if fmt is None:
            raise WaveformError("format", f"unknown format {format!r}", ", ".join(FORMATS))
        return fmt
    fmt = by_suffix(path)
    if fmt is not None:
        return fmt
    ext = Path(path).suffix.lower()
    if ext in AMBIGUOUS:
        raise WaveformError(
            "format", f"the extension {ext!r} of {Path(path).name} could be several formats; "
            "pass format= explicitly", ", ".join(FORMATS),
        )
    raise WaveformError(
        "format", f"unknown extension {ext or '(none)'!r} of {Path(path).name}; pass format=",
        "extensions " + ", ".join(sorted(EXTENSIONS)),
    )
