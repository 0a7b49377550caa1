"""Uploaded waveform files: written to a private temporary file the server names, sized up from
their headers before any data is read, then handed to the signal readers.

A compressed NPZ or HDF5 file of a few hundred kilobytes can declare 10^8 samples; reading the
headers first turns that into a 413 instead of gigabytes of memory. What each format accepts,
how it is sized and whether it can reach outside itself are the format's own declarations
(:mod:`solitonde.signal.formats.registry`); this module turns them into HTTP problems.
"""

from __future__ import annotations

import errno
import os
import tempfile
import uuid
from pathlib import Path
from typing import BinaryIO

from solitonde.instrument.service.problems import Problem
from solitonde.signal.formats.registry import FORMATS as REGISTRY
from solitonde.signal.formats.registry import by_suffix, resolve

FORMATS: dict[str, str] = {name: f.extensions[0] for name, f in REGISTRY.items()}
"""Upload formats and the suffix the server gives the temporary file (the format's first)."""

_CHUNK = 1 << 20


class UploadDir:
    """A private folder (mode 0700) for upload files, removed when closed."""

    def __init__(self) -> None:
        self.path = Path(tempfile.mkdtemp(prefix="solitonde-uploads-"))
        os.chmod(self.path, 0o700)

    def write(self, source: BinaryIO, fmt: str) -> Path:
        """Copy an upload stream into a new file named by the server; returns its path."""
        target = self.path / f"upload-{uuid.uuid4().hex}{FORMATS[fmt]}"
        try:
            fd = os.open(target, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
            with os.fdopen(fd, "wb") as out:
                while chunk := source.read(_CHUNK):
                    out.write(chunk)
        except OSError as exc:
            target.unlink(missing_ok=True)
            if exc.errno in (errno.ENOSPC, errno.EFBIG, errno.EDQUOT):
                raise Problem(507, f"file: no room to receive the upload in the server's "
                              f"temporary folder ({exc.strerror}); nothing was stored, retry "
                              "later", kind="insufficient-storage", field="file",
                              headers={"Retry-After": "60"}) from None
            raise
        return target

    def close(self) -> None:
        for child in self.path.glob("*"):
            child.unlink(missing_ok=True)
        self.path.rmdir()


def pick_format(explicit: str | None, filename: str | None) -> str:
    """The upload's format: the explicit ``format`` field (a name or an alias such as ``h5``,
    ``hdf``, as the readers take it), else the file name's suffix."""
    if explicit:
        fmt = resolve(explicit.strip())
        if fmt is None:
            raise Problem(422, f"format: unknown format {explicit!r} (allowed: "
                          f"{', '.join(FORMATS)})", kind="invalid-input", field="format")
        return fmt
    fmt = by_suffix(filename or "")
    if fmt is not None:
        return fmt
    raise Problem(422, f"format: cannot tell the format of {filename or 'the upload'!r} from its "
                  f"name; send a 'format' field (allowed: {', '.join(FORMATS)})",
                  kind="invalid-input", field="format")


def check_self_contained(path: Path, fmt: str) -> None:
    """Refuse files that reach outside themselves.

    HDF5 can store a dataset's bytes in an external file named inside the file, link to objects
    in other files, or map virtual datasets onto other files: reading such an upload would read
    files on the server, which is exactly a client-supplied path. Only self-contained files are
    read (each format says what in it reaches outside).
    """
    problems = REGISTRY[fmt].outside_references(path)
    if problems:
        raise Problem(422, f"file: only self-contained {fmt.upper()} files are accepted; "
                      f"{problems[0]}",
                      kind="invalid-input", field="file")


def declared_values(path: Path, fmt: str, dataset: str | None = None) -> int | None:
    """How many values the file declares in all the arrays the reader decodes, from headers alone.

    The readers decode every dataset of an HDF5 file (or of its ``dataset=`` subtree), every
    channel of a TDMS file and the arrays of an NPZ archive, so the count is their sum: a limit
    on the largest array alone lets a small compressed file of many arrays just under it
    through. A value is counted per 8 bytes of its element (an HDF5 array type or a long
    fixed-width string is several), since the readers decode each element whole. Returns
    ``None`` for formats without a size header (CSV, whose size the body limit bounds) and for
    a ``dataset=`` the file lacks. A file too broken to size is left to the reader, which
    reports it properly.
    """
    try:
        return REGISTRY[fmt].declared_values(path, dataset)
    except Exception:
        return None
