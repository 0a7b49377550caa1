"""On-disk cache of the plate's contact responses (the ``greens`` plate model).

The model layer computes a response once per plate, mesh, position, supports, material and step
and asks a cache object for it (:mod:`solitonde.model.greens`); this module is that object on disk:
one ``<key>.npz`` per response under ``$SOLITONDE_CACHE/greens`` or ``~/.cache/solitonde/greens``.
Files are written to a temporary name and renamed, so a reader never sees half a file and two
processes computing the same response at once both end with a whole one.
"""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

import numpy as np

from solitonde.model import greens
from solitonde.signal.atomic import atomic_path


def cache_dir() -> Path:
    """Where responses live: ``$SOLITONDE_CACHE/greens``, else ``~/.cache/solitonde/greens``."""
    root = os.environ.get("SOLITONDE_CACHE")
    base = Path(root) if root else Path.home() / ".cache" / "solitonde"
    return base / "greens"


class DiskGreensCache:
    """Responses as ``<key>.npz`` files (array ``response``) in one folder."""

    def __init__(self, folder: str | Path | None = None) -> None:
        self.folder = Path(folder) if folder is not None else cache_dir()

    def path(self, key: str) -> Path:
        if not key.isalnum():
            raise ValueError(f"cache key must be alphanumeric, got {key!r}")
        return self.folder / f"{key}.npz"

    def load(self, key: str) -> np.ndarray | None:
        path = self.path(key)
        try:
            with np.load(path) as data:
                return np.asarray(data["response"], dtype=float)
        except (FileNotFoundError, KeyError, ValueError, OSError, zipfile.BadZipFile):
            return None  # missing or unreadable: recompute (and overwrite)

    def store(self, key: str, response: np.ndarray) -> None:
        path = self.path(key)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            with atomic_path(path) as tmp, tmp.open("wb") as fh:
                np.savez(fh, response=np.asarray(response, dtype=float))
        except OSError:
            return  # a read-only or full disk must not stop a simulation: it stays in memory


class LayeredCache:
    """Memory in front of disk: repeated runs in one process never touch the file twice."""

    def __init__(self, disk: DiskGreensCache) -> None:
        self.memory = greens.MemoryCache()
        self.disk = disk

    def load(self, key: str) -> np.ndarray | None:
        found = self.memory.load(key)
        if found is None:
            found = self.disk.load(key)
            if found is not None:
                self.memory.store(key, found)
        return found

    def store(self, key: str, response: np.ndarray) -> None:
        self.memory.store(key, response)
        self.disk.store(key, response)


def disk_cache(folder: str | Path | None = None) -> LayeredCache:
    """The disk cache (``folder``, default :func:`cache_dir`) behind a memory cache, to pass as
    ``simulate(scene, greens_cache=...)``."""
    return LayeredCache(DiskGreensCache(folder))
