"""On-disk store of the plate's contact responses (the ``greens`` plate model).

The model layer computes a response once per plate, mesh, position, supports, material and step
and asks a cache object for it (:mod:`solitonde.model.greens`); this module is that object on disk:
one ``<key>.npz`` per response under ``$SOLITONDE_CACHE/greens``, else under the root the compiled
kernels' cache uses (:func:`solitonde.model.jit_cache.default_root`, ``~/.cache/solitonde`` by
default). The key holds everything the response depends on, so any process, Dask worker or
machine that reads the same folder may use what another wrote.

Files are written to a temporary name and renamed, so a reader never sees half a file and two
processes computing the same response at once both end with a whole one. The folder is held under
a size cap (``$SOLITONDE_CACHE_MAX_MB``, default :data:`DEFAULT_MAX_MB`): past it, the responses
used longest ago are deleted (a load marks a file as used).
"""

from __future__ import annotations

import contextlib
import math
import os
import time
import warnings
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from solitonde.model import greens
from solitonde.model.jit_cache import default_root
from solitonde.signal.atomic import atomic_path

DEFAULT_MAX_MB = 4096
"""The store's default size cap, MB: a few full tables' responses."""
PRUNE_EVERY = 16
"""A process checks the folder against the cap at its first store and every this many after
(listing a large folder on a network share at every store would cost more than the store): the
cap may be passed by as many responses for a while."""
STALE_TMP_S = 3600.0
"""A temporary file this old is a write that was killed; ``clear`` deletes it."""


DEFAULT_STORE = "<default>"
"""A store folder passed to another process as "its own default" (:func:`cache_dir` there: on a
cluster, each machine's), never a path; :class:`DiskGreensCache` takes it as None."""


def cache_dir() -> Path:
    """Where responses live: ``$SOLITONDE_CACHE/greens``, else ``<root>/greens`` under the
    compiled kernels' root (``$SOLITONDE_CACHE_DIR``, ..., ``~/.cache/solitonde``)."""
    root = os.environ.get("SOLITONDE_CACHE")
    return (Path(root) if root else default_root()) / "greens"


def max_bytes() -> int:
    """The size cap: ``$SOLITONDE_CACHE_MAX_MB`` (a finite number of MB above 0), else the
    default; a value that is none says so (a warning) and the default holds: a cache setting must
    not stop a build or a simulation."""
    raw = os.environ.get("SOLITONDE_CACHE_MAX_MB", "")
    try:
        mb = float(raw) if raw.strip() else float(DEFAULT_MAX_MB)
    except ValueError:
        mb = math.nan
    if not (math.isfinite(mb) and mb > 0):
        warnings.warn(f"SOLITONDE_CACHE_MAX_MB: {raw!r} is not a size in MB (a number above 0); "
                      f"the default {DEFAULT_MAX_MB} MB holds", stacklevel=2)
        mb = float(DEFAULT_MAX_MB)
    return int(mb * 1e6)


@dataclass(frozen=True)
class StoreInfo:
    """What the store holds: its folder, how many responses and how many bytes."""

    folder: Path
    responses: int
    bytes: int
    max_bytes: int


_STORES: dict[str, int] = {}
"""Responses this process has stored, per folder (when to check the cap)."""


class DiskGreensCache:
    """Responses as ``<key>.npz`` files (array ``response``) in one folder, under a size cap."""

    def __init__(self, folder: str | Path | None = None, cap_bytes: int | None = None) -> None:
        self.folder = Path(folder) if folder is not None else cache_dir()
        self.cap_bytes = max_bytes() if cap_bytes is None else int(cap_bytes)

    def path(self, key: str) -> Path:
        if not key.isalnum():
            raise ValueError(f"cache key must be alphanumeric, got {key!r}")
        return self.folder / f"{key}.npz"

    def load(self, key: str) -> np.ndarray | None:
        path = self.path(key)
        try:
            with np.load(path) as data:
                found = np.asarray(data["response"], dtype=float)
        except (FileNotFoundError, KeyError, ValueError, OSError, zipfile.BadZipFile):
            return None  # missing or unreadable: recompute (and overwrite)
        with contextlib.suppress(OSError):
            os.utime(path)  # used now: the last to go when the cap is reached
        return found

    def store(self, key: str, response: np.ndarray) -> None:
        path = self.path(key)
        kept = self.load(key)  # another process may have stored a longer one meanwhile
        if kept is not None and kept.size >= np.asarray(response).size:
            return
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            with atomic_path(path) as tmp, tmp.open("wb") as fh:
                np.savez(fh, response=np.asarray(response, dtype=float))
        except OSError:
            return  # a read-only or full disk must not stop a simulation: it stays in memory
        # counted per folder for the process (a build makes a store object per plate)
        n = _STORES[str(self.folder)] = _STORES.get(str(self.folder), 0) + 1
        if n % PRUNE_EVERY == 1 or PRUNE_EVERY == 1:
            with contextlib.suppress(OSError):  # nor must a file another user owns
                self.prune(keep=path)

    def _files(self) -> list[os.DirEntry[str]]:
        try:
            with os.scandir(self.folder) as entries:
                return [e for e in entries if e.name.endswith(".npz") and e.is_file()]
        except OSError:
            return []

    def info(self) -> StoreInfo:
        files = self._files()
        return StoreInfo(self.folder, len(files), sum(_size(e) for e in files), self.cap_bytes)

    def prune(self, keep: Path | None = None) -> int:
        """Delete the responses used longest ago (never ``keep``, the one just written) until the
        folder is under 90 % of its cap; returns how many were deleted. A file another process
        deletes first, or one this process may not delete, is passed over."""
        files = self._files()
        total = sum(_size(e) for e in files)
        if total <= self.cap_bytes:
            return 0
        removed = 0
        for entry in sorted(files, key=_mtime):
            if total <= 0.9 * self.cap_bytes:
                break
            if keep is not None and entry.name == keep.name:
                continue
            size = _size(entry)
            with contextlib.suppress(OSError):
                os.unlink(entry.path)
                removed += 1
            total -= size
        return removed

    def clear(self) -> int:
        """Delete every response, and the temporary files of writes that were killed (older than
        :data:`STALE_TMP_S`); returns how many responses."""
        removed = 0
        for entry in self._files():
            with contextlib.suppress(OSError):
                os.unlink(entry.path)
                removed += 1
        with contextlib.suppress(OSError), os.scandir(self.folder) as entries:
            for entry in entries:
                if entry.name.endswith(".tmp") and time.time() - _mtime(entry) > STALE_TMP_S:
                    with contextlib.suppress(OSError):
                        os.unlink(entry.path)
        return removed


def _size(entry: os.DirEntry[str]) -> int:
    try:
        return entry.stat().st_size
    except OSError:
        return 0


def _mtime(entry: os.DirEntry[str]) -> float:
    try:
        return entry.stat().st_mtime
    except OSError:
        return 0.0


class LayeredCache:
    """Memory in front of disk: repeated runs in one process never touch the file twice.
    ``computed`` counts the responses stored, that is computed here (a found one is not
    stored again)."""

    def __init__(self, disk: DiskGreensCache, memory: greens.MemoryCache | None = None) -> None:
        self.memory = greens.MemoryCache() if memory is None else memory
        self.disk = disk
        self.computed = 0

    def load(self, key: str) -> np.ndarray | None:
        found = self.memory.load(key)
        if found is None:
            found = self.disk.load(key)
            if found is not None:
                self.memory.store(key, found)
        return found

    def store(self, key: str, response: np.ndarray) -> None:
        self.computed += 1
        self.memory.store(key, response)
        self.disk.store(key, response)


def disk_cache(folder: str | Path | None = None) -> LayeredCache:
    """The disk cache (``folder``, default :func:`cache_dir`) behind a memory cache, to pass as
    ``simulate(scene, greens_cache=...)``."""
    return LayeredCache(DiskGreensCache(folder))
