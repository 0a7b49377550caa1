"""Where numba files solitonde's compiled kernels inside the cache folder: by the module's place
in the package, not by the absolute path of the checkout it was imported from.

numba's own locator (``UserProvidedCacheLocator``) names a module's folder in the cache after a
hash of the module's absolute folder, so a second clone of the same source, a checkout moved
elsewhere, or a CI job in another work folder compiles every kernel again (minutes) although the
cache folder (:mod:`solitonde.model.jit_cache`, keyed by the version and a hash of the kernels'
source) already holds them. :class:`PackageLocator` names it after the module's folder relative to
the ``solitonde`` package (``model``, ``model/tiers``, ``signal``, ``instrument/inference``)
instead. That is safe because the cache folder already changes with any change of the model's and
the signal's source, and numba checks each file's content hash: the inference's kernels, which
call nothing outside their own file, are kept true by that check alone.

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


def _roots() -> list[Path]:
    """The folders ``solitonde`` is imported from: the parent of each of ``solitonde.model``'s
    folders (a checkout's root, or ``site-packages/solitonde``). Found through the model's
    package, since an editable install's ``solitonde`` lists an import hook, not a folder."""
    spec = util.find_spec("solitonde.model")
    return [Path(root).resolve().parent
            for root in ((spec.submodule_search_locations or []) if spec else [])]


_ROOTS = _roots()


def package_folder(py_file: str) -> str | None:
    """``py_file``'s folder relative to the ``solitonde`` package (``model``, ``model/tiers``,
    ``signal``, ``instrument/inference``), or None for a file outside it."""
    path = Path(py_file).parent.resolve()
    for root in _ROOTS:
        if root in path.parents:
            return path.relative_to(root).as_posix()
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
