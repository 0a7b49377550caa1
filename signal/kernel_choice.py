"""Which kernels ``detect`` runs: the compiled ones, or interpreted ones while those compile.

A fresh install, or an update (the cache folder follows the version and the source,
:mod:`solitonde.model.jit_cache`), has no compiled kernels. ``detect`` runs the feature
extractor as one call, :func:`~solitonde.signal.kernels.analyze`, which numba would compile with
its two halves, :func:`~solitonde.signal.kernels.locate` and
:func:`~solitonde.signal.kernels.measure`, in the first shot's ``detect``: tens of seconds on one
core before the first answer of ``solitonde serve`` or ``solitonde analyze``.

Instead, :func:`start` (which those commands call) starts a background process
(:mod:`solitonde.signal.precompile`) that compiles both halves side by side into the on-disk
cache (``locate`` in one process, ``measure`` and the
samples' check :func:`~solitonde.signal.kernels.first_invalid` in another), then ``analyze``,
which links the two compiled halves (a few seconds). Until they are
there ``detect`` runs the same kernels interpreted (:mod:`solitonde.signal.interpreted`): a
fraction of a second per shot instead of a fraction of a millisecond, the same numbers to
round-off. When the background compile has finished, the next shot loads the compiled kernels
from the cache. A job larger than a few shots (:data:`BRIDGE_BUDGET_S` of interpreted work)
waits for the compile instead (:func:`finish`), which has been running meanwhile.

The background compile outlives a command that ends first, so the next command finds the
compiled kernels; a lock file beside the cache stops two commands from compiling at once, and a
marker file (per CPU numba compiles for) says the cache holds both halves. Nothing depends on
either for correctness: a kernel missing from the cache is compiled where it is needed. Callers
that never call :func:`start` (tests, library use) compile in the first ``detect``, as numba
does.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import threading
import time
import types
from pathlib import Path
from typing import Any

import numpy as np

CHILD_TIMEOUT_S = 900.0
"""The longest :func:`finish` waits for the background compile (a loaded machine compiles for
minutes), and the age after which a lock file left by a killed compile is ignored."""

COMPILE_FIRST_ENV = "SOLITONDE_COMPILE_FIRST"
"""Set to 1, :func:`start` does nothing: the first shot compiles the kernels in this process
before it is extracted (the first answer waits, and every shot has the compiled kernels' bits).
The test suite sets it, so that no test's numbers depend on whether a background compile of
another test has finished."""

BRIDGE_BUDGET_S = 5.0
"""Seconds of interpreted extraction a process spends before it waits for the compiled kernels
(a few dozen shots; a large job is faster compiled, even counting the wait)."""

_state = threading.Lock()
_bridging = False
_driver: subprocess.Popen[bytes] | None = None
_spent = 0.0
_kernels: types.ModuleType | None = None


def _compiled() -> types.ModuleType:
    """:mod:`solitonde.signal.kernels`, imported on first use and kept: it imports numba, which
    importing this module (:mod:`.waveform` does) should not, and an import statement run per
    shot costs about half a microsecond of the extractor's hundred."""
    global _kernels
    if _kernels is None:
        from . import kernels

        _kernels = kernels
    return _kernels


def _marker() -> Path:
    """The file that says the halves and ``analyze`` are in the cache, for this CPU."""
    import numba
    from llvmlite import binding

    from . import kernels as K

    cpu = getattr(numba.config, "CPU_NAME", None) or binding.get_host_cpu_name()
    return Path(str(K.measure.stats.cache_path)) / f"shot-kernels-{cpu}.compiled"


def _lock() -> Path:
    """The file that says a background compile for this CPU is under way."""
    return _marker().with_suffix(".compiling")


def _take_lock() -> bool | None:
    """Create the lock file: True when taken, False when a live compile holds it, None when the
    cache folder cannot hold one (read-only: then nothing is compiled in the background)."""
    lock = _lock()
    for _ in range(2):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            try:
                if time.time() - lock.stat().st_mtime < CHILD_TIMEOUT_S:
                    return False
                lock.unlink()  # left by a compile that was killed: take it over
            except OSError:
                return False
            continue
        except OSError:
            return None
        os.close(fd)
        return True
    return False


def start() -> None:
    """Start compiling both halves in the background unless the cache holds them (or a compile
    is under way already), and extract interpreted until they are there. Returns at once."""
    global _bridging, _driver
    import numba

    with _state:
        config: Any = numba.config  # its settings are set at run time: untyped
        if (config.DISABLE_JIT or _bridging or os.environ.get(COMPILE_FIRST_ENV) == "1"
                or _marker().is_file()):
            return
        from . import interpreted

        try:  # imported now, before other threads decorate numba functions
            interpreted.kernels()
        except Exception:  # only a speed-up: without it, compile first, as numba does
            return
        taken = _take_lock()
        if taken is None:
            return
        if taken:
            _driver = subprocess.Popen(  # inherits NUMBA_CACHE_DIR, which jit_cache.configure set
                [sys.executable, "-m", "solitonde.signal.precompile", str(_marker())],
                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                start_new_session=True, env=_compile_env())
        _bridging = True


def _compile_env() -> dict[str, str]:
    """The background compile's environment: this process's, with numba's cache locators as
    this process has them. The compile imports only this package, so it would otherwise file
    the kernels under numba's own names, where this process (whose locators the application may
    have set, :mod:`solitonde.model.jit_locator`) does not look for them."""
    env = dict(os.environ)
    caching = sys.modules.get("numba.core.caching")
    if caching is not None:
        classes = caching.CacheImpl._locator_classes
        env["NUMBA_CACHE_LOCATOR_CLASSES"] = ",".join(
            c.__name__ if c.__module__ == caching.__name__ else f"{c.__module__}.{c.__qualname__}"
            for c in classes)
    return env


def current() -> types.ModuleType:
    """The kernels ``detect`` uses now: the compiled :mod:`solitonde.signal.kernels`, or the
    interpreted copy while a background compile started by :func:`start` runs and this process
    has spent less than :data:`BRIDGE_BUDGET_S` on interpreted work."""
    global _bridging, _driver
    K = _compiled()
    if not _bridging:
        return K
    if _marker().is_file():
        if _driver is not None:  # reap it (it has left the marker, so it is ending)
            _driver.poll()
            _driver = None if _driver.returncode is not None else _driver
        _bridging = False
        return K
    if _spent > BRIDGE_BUDGET_S:
        finish()
        return K
    from . import interpreted

    return interpreted.kernels()


def analyze(x: np.ndarray, args: tuple[Any, ...]) -> tuple[np.ndarray, np.ndarray]:
    """The extractor on one shot's samples, with :func:`current`'s kernels: ``head`` and the
    pulse rows of :func:`~solitonde.signal.kernels.analyze` (``args`` from
    :func:`~solitonde.signal.pulses.kernel_args`). Interpreted work counts against
    :data:`BRIDGE_BUDGET_S`."""
    global _spent
    K = _compiled()
    kern = current()
    if kern is K:  # compiled: no interpreted time to count
        return K.analyze(x, *args)
    started = time.perf_counter()
    head, rows = kern.analyze(x, *args)
    _spent += time.perf_counter() - started
    return head, rows


def finish(timeout_s: float = CHILD_TIMEOUT_S) -> None:
    """Wait for the background compile (this process's, or another command's under the lock);
    afterwards ``detect`` uses the compiled kernels. Returns at once when nothing is compiling.
    After ``timeout_s``, or when the compile failed, the kernels compile where they are needed."""
    global _bridging, _driver
    with _state:
        if not _bridging:
            return
        deadline = time.monotonic() + timeout_s
        if _driver is not None:
            with contextlib.suppress(subprocess.TimeoutExpired):  # then compiled where needed
                _driver.wait(timeout_s)
            _driver = None
        else:  # another command's compile: wait for its marker, or for its lock to go
            while (time.monotonic() < deadline and not _marker().is_file()
                   and _lock().is_file()):
                time.sleep(0.1)
        _bridging = False
