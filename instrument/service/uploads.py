"""Uploaded waveform files: written to a private temporary file the server names, sized up from
their headers before any data is read, then handed to the signal readers.

A compressed NPZ or HDF5 file of a few hundred kilobytes can declare 10^8 samples; reading the
headers first turns that into a 413 instead of gigabytes of memory.
"""

from __future__ import annotations

import errno
import os
import tempfile
import uuid
import zipfile
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from solitonde.instrument.service.problems import Problem

FORMATS: dict[str, str] = {"csv": ".csv", "npy": ".npy", "npz": ".npz", "hdf5": ".h5",
                           "tdms": ".tdms", "json": ".json"}
"""Upload formats and the suffix the server gives the temporary file."""

SUFFIXES: dict[str, str] = {".csv": "csv", ".npy": "npy", ".npz": "npz", ".h5": "hdf5",
                            ".hdf5": "hdf5", ".hdf": "hdf5", ".tdms": "tdms", ".json": "json"}

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
    """The upload's format: the explicit ``format`` field, else the file name's suffix."""
    if explicit:
        fmt = explicit.strip().lower()
        if fmt == "h5":
            fmt = "hdf5"
        if fmt not in FORMATS:
            raise Problem(422, f"format: unknown format {explicit!r} (allowed: "
                          f"{', '.join(FORMATS)})", kind="invalid-input", field="format")
        return fmt
    suffix = Path(filename or "").suffix.lower()
    if suffix in SUFFIXES:
        return SUFFIXES[suffix]
    raise Problem(422, f"format: cannot tell the format of {filename or 'the upload'!r} from its "
                  f"name; send a 'format' field (allowed: {', '.join(FORMATS)})",
                  kind="invalid-input", field="format")


def check_self_contained(path: Path, fmt: str) -> None:
    """Refuse HDF5 files that reach outside themselves.

    HDF5 can store a dataset's bytes in an external file named inside the file, link to objects
    in other files, or map virtual datasets onto other files: reading such an upload would read
    files on the server, which is exactly a client-supplied path. Only self-contained files are
    read.
    """
    if fmt != "hdf5":
        return
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
        return  # not readable as HDF5 at all: the reader reports it
    if problems:
        raise Problem(422, f"file: only self-contained HDF5 files are accepted; {problems[0]}",
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
        if fmt == "npy":
            with open(path, "rb") as fh:
                return _npy_values(fh)
        if fmt == "npz":
            return _npz_values(path)
        if fmt == "hdf5":
            return _hdf5_values(path, dataset)
        if fmt == "tdms":
            from nptdms import TdmsFile

            meta = TdmsFile.read_metadata(path)  # TdmsFile.read decodes every channel
            return sum(len(ch) for g in meta.groups() for ch in g.channels())
    except Exception:
        return None
    return None


def _npz_values(path: Path) -> int:
    """Every member of the archive, whatever its name (numpy reads ``samples`` as well as
    ``samples.npy``), sized by the larger of its .npy header's shape and its uncompressed size
    in the zip directory, so that nothing is inflated before the limit is checked."""
    total = 0
    with zipfile.ZipFile(path) as zf:
        for info in zf.infolist():
            by_size = -(-int(info.file_size) // 8)
            try:
                with zf.open(info) as member:
                    by_header = _npy_values(member)
            except Exception:  # not an array header: its uncompressed size bounds it
                by_header = 0
            total += max(by_size, by_header)
    return total


def _values(shape: tuple[int, ...] | None, dtype: np.dtype) -> int:
    """Values of an array of ``shape`` and ``dtype``, one per 8 bytes of each element."""
    count = int(np.prod(shape, dtype=np.int64)) if shape else 1
    return count * max(1, -(-int(dtype.itemsize) // 8))


def _npy_values(fh: BinaryIO) -> int:
    version = np.lib.format.read_magic(fh)
    if version == (1, 0):
        shape, _, dtype = np.lib.format.read_array_header_1_0(fh)
    else:
        shape, _, dtype = np.lib.format.read_array_header_2_0(fh)
    return _values(shape, np.dtype(dtype))


def _hdf5_values(path: Path, dataset: str | None = None) -> int | None:
    import h5py

    total = 0

    def visit(_name: str, obj: Any) -> None:
        nonlocal total
        if isinstance(obj, h5py.Dataset) and obj.shape is not None:
            total += _values(obj.shape, obj.dtype)

    with h5py.File(path, "r") as fh:
        root = fh
        if dataset is not None:
            if dataset not in fh:
                return None  # the reader names what the file holds
            root = fh[dataset]
        if isinstance(root, h5py.Dataset):
            visit(root.name, root)
        else:
            root.visititems(visit)  # the objects the reader visits, each once
    return total
