"""Writing a file so that it is either whole or absent: a temporary name in the same folder, then
a rename over the target (atomic on one filesystem). A reader never sees half a file, a crash or
a full disk leaves the old file as it was, and the temporary file is removed on failure.

The one helper for every file the project writes (waveforms, tables' caches, calibrations,
figures, the watch queue); in the signal layer because that is the lowest layer that writes.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def atomic_path(path: str | Path, *, durable: bool = False) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` to write to; on leaving the block without an
    error, give it the permissions of any file the user makes (0644 under the usual umask, not
    the temporary file's 0600) and rename it onto ``path``; on an error, remove it.

    ``durable`` also flushes the file and the folder's entry to disk (fsync) before returning:
    for records a later run must find after a power cut (the watch queue).
    """
    path = Path(path)
    fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        if durable:
            with tmp.open("rb+") as fh:
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    if durable:
        with contextlib.suppress(OSError):  # the rename itself, where the OS allows it
            folder = os.open(path.parent, os.O_RDONLY)
            try:
                os.fsync(folder)
            finally:
                os.close(folder)


def write_bytes(path: str | Path, data: bytes, *, durable: bool = False) -> None:
    """Write ``data`` to ``path`` atomically (:func:`atomic_path`)."""
    with atomic_path(path, durable=durable) as tmp:
        tmp.write_bytes(data)


def write_text(path: str | Path, text: str, *, durable: bool = False) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically (:func:`atomic_path`)."""
    with atomic_path(path, durable=durable) as tmp:
        tmp.write_text(text, encoding="utf-8")
