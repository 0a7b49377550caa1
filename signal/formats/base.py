"""What a waveform file format declares: a plug-in's one record (:class:`FileFormat`).

Each module of this folder (``csv_text``, ``npy``, ``npz``, ``hdf5``, ``tdms``, ``rest_json``)
defines one ``FORMAT``, in the manner of ObsPy's ``obspy/io/<format>/core.py``, and
:mod:`.registry` lists them. Everything that knows formats (:mod:`solitonde.signal.io`, the
service's upload checks, the command line's suffix filters) asks the registry, so a new format
is one new module and one line there.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ..waveform import Waveform

Reader = Callable[..., list[Waveform]]
"""``reader(path, **options) -> shots``; options as :attr:`FileFormat.options` lists them."""
Writer = Callable[..., None]
"""``writer(path, shots, **options)``: writes the file (the caller makes it atomic)."""
Sizer = Callable[[Path, str | None], int | None]
"""``sizer(path, dataset) -> values``: from the headers alone, or None when unknown."""
Outside = Callable[[Path], list[str]]
"""``outside(path) -> problems``: what in the file reaches other files (empty: none)."""


def no_size(_path: Path, _dataset: str | None = None) -> int | None:
    """For formats without a size header (text, whose size the body limit bounds)."""
    return None


def nothing_outside(_path: Path) -> list[str]:
    """For formats that cannot name another file."""
    return []


@dataclass(frozen=True)
class FileFormat:
    """One waveform file format.

    Attributes
    ----------
    name:
        The ``format=`` name (``"hdf5"``).
    extensions:
        File-name suffixes that mean this format, lower-case with the dot; the first is the one a
        file written for it gets (the service's temporary upload files).
    aliases:
        Other ``format=`` spellings accepted for it (``"h5"``, ``"hdf"``).
    options:
        The keyword options its reader takes; any other is refused, naming it.
    read, write:
        The reader and the writer.
    declared_values:
        How many values the file's arrays declare, read from headers alone (so that a small
        compressed file declaring 10^8 samples is refused before it is decoded).
    outside_references:
        What in a file would make reading it read other files (HDF5 external storage, links,
        virtual datasets); a server reads only files for which this is empty.
    """

    name: str
    extensions: tuple[str, ...]
    options: tuple[str, ...]
    read: Reader
    write: Writer
    aliases: tuple[str, ...] = ()
    declared_values: Sizer = no_size
    outside_references: Outside = nothing_outside

    def __post_init__(self) -> None:
        if not self.extensions or any(not e.startswith(".") or e != e.lower()
                                      for e in self.extensions):
            raise ValueError(f"{self.name}: extensions must be lower-case suffixes with the dot")
