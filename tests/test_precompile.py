"""The first answer after an install: the extractor's two halves compile side by side, and what
the child process compiled is what detect loads.

The child's work is only of use when its kernel has the very argument types detect passes
(numba keys its cache by them): checked here cheaply on the suite's compiled kernels, and end to
end, from an empty cache, in a slow test.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numba
import numpy as np
import pytest

from solitonde.signal import kernels as K
from solitonde.signal import precompile, waveform
from solitonde.signal.pulses import detect
from solitonde.signal.synth import pulse_train
from solitonde.signal.waveform import Waveform

DT = 5e-7


def _shot(units: str = "N") -> Waveform:
    x = pulse_train(4000, DT, [(300e-6, 50.0, 40e-6), (900e-6, 30.0, 40e-6)])
    if units == "V":
        return Waveform(0.0, DT, x / 20.0, units="V", calibration=20.0)
    return Waveform(0.0, DT, x)


def _types(args: tuple[object, ...]) -> tuple[object, ...]:
    return tuple(numba.typeof(a) for a in args)


@pytest.mark.parametrize(("units", "options"), [("N", {}), ("V", {}), ("N", {"lowpass_hz": 2e5})])
def test_the_example_arguments_have_the_types_detect_passes(monkeypatch, units, options):
    """Newtons (read-only samples), volts scaled (a new, writable array) and a low-passed trace:
    detect hands each half the types precompile compiles them for, and a Waveform its samples'
    check, so one compilation serves."""
    seen: dict[str, tuple[object, ...]] = {}

    def recorder(name: str, real):  # real: a numba dispatcher
        def call(*args):
            seen[name] = _types(args)
            return real(*args)
        return call

    monkeypatch.setattr(K, "locate", recorder("locate", K.locate))
    monkeypatch.setattr(K, "measure", recorder("measure", K.measure))
    monkeypatch.setattr(waveform, "first_invalid", recorder("first_invalid", K.first_invalid))
    detection = detect(_shot(units), **options)
    assert detection.incident is not None and detection.reflected is not None
    locate_args, measure_args = precompile._example_args()
    assert seen["locate"] == _types(locate_args)
    assert seen["measure"] == _types(measure_args)
    assert seen["first_invalid"] == _types(locate_args[:1])


def test_finish_waits_for_the_child_and_marks_the_cache(tmp_path, monkeypatch):
    """start runs a child (here it only loads ``measure`` from the suite's cache), finish waits
    for it and leaves the marker; with the marker, start runs no child."""
    marker = tmp_path / "shot-kernels.compiled"
    monkeypatch.setattr(precompile, "_marker", lambda: marker)
    monkeypatch.setattr(precompile, "_child", None)
    monkeypatch.setattr(precompile, "_done", False)
    precompile.start()
    child = precompile._child
    assert child is not None
    precompile.finish()
    assert child.returncode == 0
    assert marker.is_file()
    assert precompile._child is None

    monkeypatch.setattr(precompile, "_done", False)
    precompile.start()
    assert precompile._child is None, "marked as compiled: no child"
    precompile.finish()


@pytest.mark.slow
def test_from_an_empty_cache_detect_loads_the_childs_half(tmp_path: Path) -> None:
    """A fresh cache folder: start and finish compile ``locate`` here and ``measure`` and
    ``first_invalid`` in the child; the first shot then compiles nothing: they come from the
    cache the child wrote."""
    code = """
        import json
        import solitonde.instrument  # configures the cache folder
        from solitonde.signal import kernels as K, precompile
        from solitonde.signal.pulses import detect
        from solitonde.signal.synth import pulse_train
        from solitonde.signal.waveform import Waveform
        precompile.start()
        precompile.finish()
        x = pulse_train(4000, 5e-7, [(300e-6, 50.0, 40e-6), (900e-6, 30.0, 40e-6)])
        d = detect(Waveform(0.0, 5e-7, x))
        print(json.dumps({
            "measure_hits": sum(K.measure.stats.cache_hits.values()),
            "measure_misses": sum(K.measure.stats.cache_misses.values()),
            "first_invalid_misses": sum(K.first_invalid.stats.cache_misses.values()),
            "locate_signatures": len(K.locate.signatures),
            "marker": precompile._marker().is_file(),
            "tof": d.reflected.time_s - d.incident.time_s}))
    """
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["SOLITONDE_CACHE_DIR"] = str(tmp_path / "cache")
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], env=env,
                         capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result["measure_hits"] == 1 and result["measure_misses"] == 0
    assert result["first_invalid_misses"] == 0
    assert result["locate_signatures"] == 1
    assert result["marker"]
    assert result["tof"] == pytest.approx(600e-6, abs=2 * DT)


def test_the_child_is_stopped_when_the_command_ends_first(tmp_path, monkeypatch):
    """A command that fails before finish (a usage error) leaves no compilation running."""
    monkeypatch.setattr(precompile, "_marker", lambda: tmp_path / "absent")
    monkeypatch.setattr(precompile, "_child", None)
    monkeypatch.setattr(precompile, "_done", False)
    precompile.start()
    child = precompile._child
    assert child is not None
    precompile._stop_child()
    assert child.poll() is not None
    monkeypatch.setattr(precompile, "_child", None)


def test_compiled_halves_give_what_the_kernel_in_one_call_gives():
    """detect's two calls and analyze's one: the same numbers, bit for bit."""
    from solitonde.signal.pulses import DetectOptions, kernel_args

    x = np.ascontiguousarray(_shot().samples)
    args = kernel_args(DetectOptions(travel_time_1n_s=2e-3), x.size, DT)
    head, rows = K.analyze(x, *args)
    located = K.locate(x, *args[: K.LOCATE_ARGS])
    halves = K.measure(*located, *args[K.LOCATE_ARGS :])
    np.testing.assert_array_equal(located[0], head)
    np.testing.assert_array_equal(halves, rows)
