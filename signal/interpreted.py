"""The feature extractor's kernels as plain Python: the same source, run by the interpreter.

numba compiles a kernel the first time it runs, and on a fresh install the extractor's kernels
take tens of seconds to compile on two cores, for an extraction that then costs a fraction of a
millisecond per shot. Interpreted, the same source extracts a 10,000-sample shot in a fraction of
a second: the first few shots of a fresh install are answered that way while the compiled
kernels build in the background (:mod:`solitonde.signal.kernel_choice` decides which is used).

:func:`kernels` imports a second copy of :mod:`solitonde.signal.kernels` and of the modules it
imports from this folder, under a package name of its own, with numba's ``DISABLE_JIT`` set
while their decorators run: ``@njit`` then returns each function as written. The compiled
kernels (the package's own modules) are untouched. The two agree to round-off: the only
fast-math kernel (the power sums of :func:`~solitonde.signal.kernels.quadratic_fit`) may add in
another order compiled (``tests/signal/test_precompile.py`` compares them shot by shot).
"""

from __future__ import annotations

import importlib
import sys
import threading
import types
from pathlib import Path
from typing import Any

PACKAGE = "_solitonde_signal_interpreted"
"""The name the interpreted copy is imported under (never the package's own name)."""

_lock = threading.Lock()


def kernels() -> types.ModuleType:
    """The interpreted copy of :mod:`solitonde.signal.kernels`, imported on the first call.

    Call it first from one thread before others decorate numba functions (``solitonde serve``
    does at start): numba reads ``DISABLE_JIT`` when a decorator runs, process-wide.
    """
    with _lock:
        loaded = sys.modules.get(f"{PACKAGE}.kernels")
        if loaded is not None:
            return loaded
        import numba

        config: Any = numba.config  # its settings are set at run time: untyped
        package = types.ModuleType(PACKAGE)
        package.__path__ = [str(Path(__file__).resolve().parent)]
        package.__package__ = PACKAGE
        sys.modules[PACKAGE] = package
        saved = config.DISABLE_JIT
        config.DISABLE_JIT = True
        try:
            return importlib.import_module(f"{PACKAGE}.kernels")
        finally:
            config.DISABLE_JIT = saved
