"""The background compile of a fresh install: the extractor into the cache, its halves side by
side.

``python -m solitonde.signal.precompile MARKER``, started by
:func:`solitonde.signal.kernel_choice.start`, compiles :func:`~solitonde.signal.kernels.locate`
in a second process while it compiles :func:`~solitonde.signal.kernels.measure` and the samples'
check :func:`~solitonde.signal.kernels.first_invalid` (about equal halves, on two cores), by
running them on arguments of the very types ``detect`` passes (numba keys its cache by them).
Then it compiles :func:`~solitonde.signal.kernels.analyze`, the call ``detect`` makes, which
links the compiled halves from the cache (a few seconds, against tens for the halves), leaves
the marker file, and removes the lock beside it either way.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np


def _example_args(n: int = 64) -> tuple[tuple[Any, ...], tuple[Any, ...], tuple[Any, ...]]:
    """Arguments of the types :func:`~solitonde.signal.pulses.detect` passes to ``analyze``,
    and as ``locate`` and ``measure`` take them (default options): numba compiles for the
    types, whatever the values. The samples (the first argument of ``locate`` and ``analyze``)
    are also what a Waveform passes to ``first_invalid``."""
    from . import kernels as K
    from .pulses import DetectOptions, kernel_args

    x = np.zeros(n)
    x.setflags(write=False)  # a Waveform's samples, as detect passes them
    args = kernel_args(DetectOptions(), n, 1e-6)
    located = (np.zeros(K.HEAD), x, np.zeros(n), np.zeros(n), np.zeros(n),
               np.zeros(0, dtype=np.int64))
    return (x, *args[: K.LOCATE_ARGS]), (*located, *args[K.LOCATE_ARGS :]), (x, *args)


def _compile(part: str) -> None:
    """A background process's work: compile ``locate``; ``measure`` and ``first_invalid``; or
    ``analyze`` (once both halves are in the cache), into the cache by running them on example
    arguments."""
    from . import kernels as K

    locate_args, measure_args, analyze_args = _example_args()
    if part == "locate":
        K.locate(*locate_args)
    elif part == "analyze":
        K.analyze(*analyze_args)
    else:
        K.measure(*measure_args)
        K.first_invalid(locate_args[0])


def _main(argv: list[str]) -> int:
    """The background compile, ``python -m solitonde.signal.precompile MARKER``: ``locate`` in
    a second process while this one compiles ``measure``, then ``analyze`` here; the marker file
    once all are in the cache, and the lock beside it removed either way."""
    if argv == ["locate"]:
        _compile("locate")
        return 0
    marker = Path(argv[0])
    try:
        other = subprocess.Popen([sys.executable, "-m", "solitonde.signal.precompile", "locate"],
                                 stdin=subprocess.DEVNULL)
        _compile("measure")
        if other.wait() == 0:
            _compile("analyze")
            marker.touch()
        return 0
    finally:
        marker.with_suffix(".compiling").unlink(missing_ok=True)


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
