"""Where numba keeps solitonde's compiled kernels: a folder keyed by the version and the source.

numba's own cache (``@njit(cache=True)``) is checked against the timestamp and size of the one
file that defines a kernel. A kernel that inlines a helper from another module (the contact laws
of ``laws.py`` in every integrator, the pulse fit in the signal kernels) keeps its compiled code
when only the helper changes, so an update or an edit can run stale machine code without a word.

:func:`configure` points numba's cache at

    <root>/solitonde-<version>-<hash of every .py file of solitonde.model and solitonde.signal>

so that any change to the source the kernels are compiled from starts from an empty folder, and
the code of one release never meets the cache of another. ``<root>`` is ``$SOLITONDE_CACHE_DIR``,
else a ``$NUMBA_CACHE_DIR`` the user set, else ``$XDG_CACHE_HOME/solitonde`` (``~/.cache``
when unset). Folders of earlier versions can be deleted at any time; nothing else is kept there.

Inside that folder a kernel's files are named by its module's place in the package
(:mod:`solitonde.model.jit_locator`), not by the checkout's absolute path as numba's own locator
does: a clone at another path, of the same source, reuses the compiled kernels.

It runs first thing when ``solitonde.model`` or ``solitonde.instrument`` is imported (before any
kernel is decorated: numba fixes a kernel's cache folder when the decorator runs). It sets
``NUMBA_CACHE_DIR``, so worker processes (uvicorn, Dask) inherit the same folder; they import
solitonde, which registers the locator in each of them. A process that
imports only ``solitonde.signal`` modules, which have no package ``__init__`` to run it, gets
numba's default cache beside the source unless it calls :func:`configure` first.
"""

from __future__ import annotations

import hashlib
import importlib.abc
import os
import sys
from importlib import util
from pathlib import Path
from typing import Any

from solitonde.model.version import package_version

PREFIX = "solitonde-"
"""Leaf folders start with this; an inherited ``NUMBA_CACHE_DIR`` with it is one of ours."""

KERNEL_PACKAGES = ("solitonde.model", "solitonde.signal")
"""Every numba kernel that can inline code of another module lives in these two packages. The
inference's kernels (``solitonde.instrument.inference.*_kernel``) call nothing outside their own
file, so numba's check of that file keeps their cache true without them."""


def source_digest(packages: tuple[str, ...] = KERNEL_PACKAGES) -> str:
    """SHA-256 (first 16 hex digits) of the names and bytes of every ``.py`` file of
    ``packages``, found where Python imports them from (a checkout or site-packages)."""
    h = hashlib.sha256()
    for name in packages:
        spec = util.find_spec(name)
        roots = list(spec.submodule_search_locations or []) if spec else []
        for root in roots:
            for path in sorted(Path(root).rglob("*.py")):
                h.update(f"{name}/{path.relative_to(root).as_posix()}\0".encode())
                h.update(path.read_bytes())
                h.update(b"\0")
    return h.hexdigest()[:16]


def default_root(environ: dict[str, str] | os._Environ[str] | None = None) -> Path:
    """The folder the keyed cache folders go in (see the module docstring for the order)."""
    env = os.environ if environ is None else environ
    if env.get("SOLITONDE_CACHE_DIR"):
        return Path(env["SOLITONDE_CACHE_DIR"])
    numba_dir = env.get("NUMBA_CACHE_DIR")
    if numba_dir:
        given = Path(numba_dir)
        # inherited from a process that ran configure() for another source tree: its parent
        return given.parent if given.name.startswith(PREFIX) else given
    xdg = env.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "solitonde"


def cache_dir(environ: dict[str, str] | os._Environ[str] | None = None) -> Path:
    """The keyed folder for this version and source."""
    return default_root(environ) / f"{PREFIX}{package_version()}-{source_digest()}"


_configured: Path | None = None


def configure() -> Path:
    """Point numba's cache at :func:`cache_dir` (idempotent; cheap after the first call).

    Sets ``NUMBA_CACHE_DIR`` for this process and its children, and numba's live setting when
    numba is already imported. Kernels decorated before this call keep their earlier folder."""
    global _configured
    if _configured is not None and os.environ.get("NUMBA_CACHE_DIR") == str(_configured):
        return _configured
    inherited = os.environ.get("NUMBA_CACHE_DIR", "")
    leaf = f"{PREFIX}{package_version()}-{source_digest()}"
    if Path(inherited).name == leaf and not os.environ.get("SOLITONDE_CACHE_DIR"):
        target = Path(inherited)
    else:
        target = default_root() / leaf
    os.environ["NUMBA_CACHE_DIR"] = str(target)
    config = sys.modules.get("numba.core.config")
    if config is not None:
        config.CACHE_DIR = str(target)  # type: ignore[attr-defined]
    _register_locator()
    _configured = target
    return target


def _register_locator() -> None:
    """Put :class:`~solitonde.model.jit_locator.PackageLocator` first among numba's cache
    locators, in this process only: now if numba's caching module is loaded, else the moment it
    is (a finder on ``sys.meta_path`` waits for it, so that importing solitonde does not import
    numba). Nothing goes into the environment: another program this process starts, with
    another Python, keeps numba's own locators."""
    caching = sys.modules.get("numba.core.caching")
    if caching is not None:
        _prepend_locator(caching)
    elif not any(isinstance(f, _CachingFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, _CachingFinder())


def _prepend_locator(caching: Any) -> None:
    from solitonde.model.jit_locator import PackageLocator

    classes = caching.CacheImpl._locator_classes
    if PackageLocator not in classes:
        classes.insert(0, PackageLocator)


class _CachingFinder(importlib.abc.MetaPathFinder):
    """Runs :func:`_prepend_locator` once ``numba.core.caching`` has been executed."""

    def find_spec(self, name: str, path: Any, target: Any = None) -> Any:
        if name != "numba.core.caching":
            return None
        sys.meta_path.remove(self)
        spec = util.find_spec(name)
        if spec is None or spec.loader is None:
            return spec
        loader = spec.loader
        run = loader.exec_module

        def exec_module(module: Any) -> None:
            run(module)
            _prepend_locator(module)

        loader.exec_module = exec_module  # type: ignore[method-assign]
        return spec
