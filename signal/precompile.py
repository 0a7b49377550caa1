"""The per-shot kernels compiled on two cores at once, the first time a version runs.

A fresh install, or an update (the cache folder follows the version and the source,
:mod:`solitonde.model.jit_cache`), has no compiled kernels, and the first shot's feature
extraction compiles them: most of the time to the first answer of ``solitonde serve`` and of
``solitonde analyze``. :func:`solitonde.signal.pulses.detect` runs two kernels of about equal
size one after the other, :func:`~solitonde.signal.kernels.locate` and
:func:`~solitonde.signal.kernels.measure`, and numba compiles a function only in the process that
calls it. So :func:`start` has a child process compile ``measure`` (and the samples' check,
:func:`~solitonde.signal.kernels.first_invalid`, which every Waveform runs) into the on-disk
cache while this one goes on (importing, reading files, loading tables), and :func:`finish`
compiles ``locate`` here and waits for the child; the first shot then loads the rest from the
cache.

Once both are in the cache, :func:`finish` leaves a marker file beside them, named for the CPU
numba compiles for, and later runs start no child. Nothing depends on it for correctness: when a
kernel is not in the cache after all (another CPU, a deleted file), ``detect`` compiles it, as
it would without this module. Callers that never call :func:`start` or :func:`finish` (tests,
library use) compile both halves one after the other in the first ``detect``.
"""

from __future__ import annotations

import atexit
import contextlib
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

CHILD_TIMEOUT_S = 900.0
"""The longest :func:`finish` waits for the child (a loaded machine compiles for minutes); after
that it stops the child and ``detect`` compiles ``measure`` itself."""

_child: subprocess.Popen[bytes] | None = None
_done = False


def _example_args(n: int = 64) -> tuple[tuple[Any, ...], tuple[Any, ...]]:
    """Arguments of the types :func:`~solitonde.signal.pulses.detect` passes to ``locate`` and
    ``measure`` (default options): numba compiles for the types, whatever the values. The
    samples (``locate``'s first argument) are also what a Waveform passes to ``first_invalid``."""
    from . import kernels as K
    from .pulses import DetectOptions, kernel_args

    x = np.zeros(n)
    x.setflags(write=False)  # a Waveform's samples, as detect passes them
    args = kernel_args(DetectOptions(), n, 1e-6)
    located = (np.zeros(K.HEAD), x, np.zeros(n), np.zeros(n), np.zeros(n),
               np.zeros(0, dtype=np.int64))
    return (x, *args[: K.LOCATE_ARGS]), (*located, *args[K.LOCATE_ARGS :])


def _marker() -> Path:
    """The file that says both halves are in the cache, for this CPU."""
    import numba
    from llvmlite import binding

    from . import kernels as K

    cpu = getattr(numba.config, "CPU_NAME", None) or binding.get_host_cpu_name()
    return Path(str(K.measure.stats.cache_path)) / f"shot-kernels-{cpu}.compiled"


def start() -> None:
    """Start compiling ``measure`` in a child process, unless the marker says it is cached or a
    child was started already. Returns at once."""
    global _child
    if _child is not None or _done or _marker().is_file():
        return
    _child = subprocess.Popen(  # inherits NUMBA_CACHE_DIR, which jit_cache.configure set
        [sys.executable, "-m", "solitonde.signal.precompile"],
        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    atexit.register(_stop_child)


def finish() -> None:
    """Compile (or load) ``locate`` here and wait for the child of :func:`start` (started now
    when it was not); afterwards the first ``detect`` compiles nothing."""
    global _child, _done
    if _done:
        return
    start()
    from . import kernels as K

    locate_args, _ = _example_args()
    K.locate(*locate_args)
    child, _child = _child, None
    if child is not None:
        try:
            ok = child.wait(CHILD_TIMEOUT_S) == 0
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()
            ok = False
        if ok:  # a read-only cache: no marker, and the child compiles again next time, no harm
            with contextlib.suppress(OSError):
                _marker().touch()
    _done = True


def _stop_child() -> None:
    """At exit, a child :func:`finish` never waited for (the command failed first) is stopped:
    no compilation goes on after the command that started it."""
    if _child is not None and _child.poll() is None:
        _child.kill()
        _child.wait()


def _compile_measure() -> None:
    """The child's work: compile ``measure`` (running it on no pulses) and ``first_invalid``
    into the cache."""
    from . import kernels as K

    locate_args, measure_args = _example_args()
    K.measure(*measure_args)
    K.first_invalid(locate_args[0])


if __name__ == "__main__":
    _compile_measure()
