"""Where numba files solitonde's compiled kernels inside the cache folder: by the module's place
in the package, not by the absolute path of the checkout it was imported from.

numba's own locator (``UserProvidedCacheLocator``) names a module's folder in the cache after a
hash of the module's absolute folder, so a second clone of the same source, a checkout moved
elsewhere, or a CI job in another work folder compiles every kernel again (minutes) although the
cache folder (:mod:`solitonde.model.jit_cache`, keyed by the version and a hash of the kernels'
source) already holds them. :class:`PackageLocator` names it after the module's folder relative to
its package (``model``, ``model/tiers``, ``signal``, ``instrument/inference``) instead. That is
safe because the cache folder already changes with any change of the model's and the signal's
source, and numba checks each file's content hash: the inference's kernels, which call nothing
outside their own file, are kept true by that check alone.

:func:`solitonde.model.jit_cache.configure` puts it first among numba's locators in the process
(numba's own follow, for any other code) once numba's caching module is loaded; this module
imports numba, so it is imported only then.
"""

from __future__ import annotations

import os
from importlib import util
from pathlib import Path
from typing import Any

from numba.core import config
from numba.core.caching import UserProvidedCacheLocator

PACKAGES = ("solitonde.model", "solitonde.signal", "solitonde.instrument")
"""The packages whose kernels this locator files: every kernel of solitonde lives in them (the
instrument's in :mod:`solitonde.instrument.inference`). Named, not imported: finding a package
imports only its parent."""


def _roots() -> list[tuple[str, Path]]:
    out = []
    for name in PACKAGES:
        spec = util.find_spec(name)
        for root in (spec.submodule_search_locations or []) if spec else []:
            out.append((name.rsplit(".", 1)[1], Path(root).resolve()))
    return out


_ROOTS = _roots()


def package_folder(py_file: str) -> str | None:
    """``py_file``'s folder relative to its package (``model``, ``model/tiers``, ``signal``,
    ``instrument/inference``), or None for a file outside the kernel packages."""
    path = Path(py_file).parent.resolve()
    for name, root in _ROOTS:
        if path == root or root in path.parents:
            return "/".join((name, *path.relative_to(root).parts))
    return None


def _cache_dir() -> str:
    """numba's cache folder as set now (:func:`solitonde.model.jit_cache.configure` sets it)."""
    return str(getattr(config, "CACHE_DIR", "") or "")


class PackageLocator(UserProvidedCacheLocator):
    """numba's cache-folder locator, with a module's subfolder named by its package folder."""

    def __init__(self, py_func: Any, py_file: str) -> None:
        super().__init__(py_func, py_file)
        folder = package_folder(py_file)
        assert folder is not None  # from_function returns None otherwise
        self._cache_path = os.path.join(_cache_dir(), folder.replace("/", "_"))

    @classmethod
    def from_function(cls, py_func: Any, py_file: str) -> PackageLocator | None:
        if not _cache_dir() or package_folder(py_file) is None:
            return None
        found: PackageLocator | None = super().from_function(py_func, py_file)
        return found
