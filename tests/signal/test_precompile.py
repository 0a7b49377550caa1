"""The first answer after an install: the extractor runs interpreted while its two halves
compile side by side in the background (then the call detect makes, which links them), and what
the background compiled is what detect loads.

The interpreted kernels must give the compiled ones' numbers (to round-off) and flags. The
background's work is only of use when its kernels have the very argument types detect passes
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

from solitonde.signal import kernel_choice, precompile
from solitonde.signal import kernels as K
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
    detect hands ``analyze`` the types precompile compiles it for, and a Waveform its samples'
    check, so one compilation serves; ``analyze`` hands its halves the types they are compiled
    for (numba compiles a caller's calls for the argument types it infers)."""
    seen: dict[str, tuple[object, ...]] = {}

    def recorder(name: str, real):  # real: a numba dispatcher
        def call(*args):
            seen[name] = _types(args)
            return real(*args)
        return call

    monkeypatch.setattr(K, "analyze", recorder("analyze", K.analyze))
    monkeypatch.setattr(K, "first_invalid", recorder("first_invalid", K.first_invalid))
    detection = detect(_shot(units), **options)
    assert detection.incident is not None and detection.reflected is not None
    locate_args, measure_args, analyze_args = precompile._example_args()
    assert seen["analyze"] == _types(analyze_args)
    assert seen["first_invalid"] == _types(locate_args[:1])
    # analyze passes its own arguments on to locate, and locate's results with the rest to
    # measure: the types the background compiles each half for
    K.locate.compile(_types(locate_args))  # from the cache, where analyze's run left it
    located = tuple(K.locate.overloads[_types(locate_args)].signature.return_type)
    rest = _types(measure_args)[len(located):]
    assert _types(analyze_args) == (*_types(locate_args), *rest)
    assert (*located, *rest) == _types(measure_args)


@pytest.fixture
def bridging(tmp_path, monkeypatch):
    """kernel_choice's state as after :func:`kernel_choice.start` on a fresh cache, with the marker
    and lock in ``tmp_path``: no background compile started (the suite's kernels are compiled)."""
    marker = tmp_path / "shot-kernels-cpu.compiled"
    monkeypatch.setattr(kernel_choice, "_marker", lambda: marker)
    monkeypatch.setattr(kernel_choice, "_bridging", True)
    monkeypatch.setattr(kernel_choice, "_driver", None)
    monkeypatch.setattr(kernel_choice, "_spent", 0.0)
    return marker


def _noisy_shots() -> list[Waveform]:
    """Bundled sample files and noisy synthetic shots, volts and newtons, with and without a
    reflection: every branch of the extractor the first answers take."""
    from solitonde.signal.io import read

    samples = Path(__file__).resolve().parents[2] / "data_samples" / "waveforms"
    shots = [w for f in sorted(samples.glob("synthetic_*")) for w in read(f)]
    rng = np.random.default_rng(7)
    for k in range(6):
        x = pulse_train(8000, DT, [(600e-6, 40.0, 38e-6), (1500e-6, 12.0 * k, 42e-6)])
        drift = 0.3 * k * np.arange(x.size) / x.size  # up to 1.5 N over the record
        shots.append(Waveform(0.0, DT, x + rng.normal(0.0, 0.4, x.size) + drift))
    shots.append(_shot("V"))
    return shots


def test_interpreted_kernels_give_the_compiled_numbers(bridging):
    """The first shots of a fresh install, interpreted: the same flags and pulses, every number
    within 1e-12 relative of the compiled kernels' (round-off: the fast-math power sums add in
    another order compiled)."""
    from solitonde.signal.features import extract

    shots = _noisy_shots()
    assert kernel_choice.current() is not K
    interpreted = [extract(w).to_dict() for w in shots]
    assert kernel_choice._spent > 0.0, "the interpreted kernels ran"
    kernel_choice._bridging = False
    compiled = [extract(w).to_dict() for w in shots]
    compared = 0
    for got, want in zip(interpreted, compiled, strict=True):
        assert got.keys() == want.keys()
        for key, value in want.items():
            if isinstance(value, float) and np.isfinite(value):
                assert got[key] == pytest.approx(value, rel=1e-12, abs=1e-300), key
                compared += 1
            else:
                assert got[key] == value or (value != value and got[key] != got[key]), key
    assert compared > 100


def test_detect_loads_the_compiled_kernels_once_the_marker_is_there(bridging):
    """While bridging, detect runs interpreted; the background's marker switches it to the
    compiled kernels at the next shot, without waiting."""
    detect(_shot())
    assert kernel_choice._spent > 0.0 and kernel_choice._bridging
    bridging.touch()
    assert kernel_choice.current() is K
    assert not kernel_choice._bridging


def test_a_large_job_waits_for_the_compile(bridging, monkeypatch):
    """Past the interpreted budget, detect waits for the background compile (finish) and goes
    on compiled: a large job is faster so."""
    waited: list[float] = []
    monkeypatch.setattr(kernel_choice, "finish", lambda: waited.append(kernel_choice._spent))
    monkeypatch.setattr(kernel_choice, "_spent", kernel_choice.BRIDGE_BUDGET_S + 0.1)
    assert kernel_choice.current() is K
    assert waited


def test_start_compiles_in_the_background_and_leaves_the_marker(tmp_path, monkeypatch):
    """start takes the lock and runs the background compile (here it loads the halves from the
    suite's cache); finish waits for it: the marker is there, the lock gone, and a second start
    runs nothing."""
    monkeypatch.delenv(kernel_choice.COMPILE_FIRST_ENV)
    marker = tmp_path / "shot-kernels-cpu.compiled"
    monkeypatch.setattr(kernel_choice, "_marker", lambda: marker)
    monkeypatch.setattr(kernel_choice, "_bridging", False)
    monkeypatch.setattr(kernel_choice, "_driver", None)
    kernel_choice.start()
    driver = kernel_choice._driver
    assert driver is not None and kernel_choice._bridging
    assert marker.with_suffix(".compiling").is_file()
    kernel_choice.finish()
    assert driver.returncode == 0
    assert marker.is_file() and not marker.with_suffix(".compiling").exists()
    assert not kernel_choice._bridging and kernel_choice.current() is K
    kernel_choice.start()
    assert kernel_choice._driver is None and not kernel_choice._bridging, "marked: nothing to do"


def test_a_compile_under_way_is_not_started_twice(tmp_path, monkeypatch):
    """Another command's live lock: this one bridges without a compile of its own, and finish
    waits for that lock. A lock older than the longest compile was left by a killed one: taken
    over."""
    monkeypatch.delenv(kernel_choice.COMPILE_FIRST_ENV)
    marker = tmp_path / "shot-kernels-cpu.compiled"
    lock = marker.with_suffix(".compiling")
    lock.touch()
    monkeypatch.setattr(kernel_choice, "_marker", lambda: marker)
    monkeypatch.setattr(kernel_choice, "_bridging", False)
    monkeypatch.setattr(kernel_choice, "_driver", None)
    kernel_choice.start()
    assert kernel_choice._bridging and kernel_choice._driver is None
    lock.unlink()  # the other command's compile ended
    kernel_choice.finish(timeout_s=5.0)
    assert not kernel_choice._bridging

    lock.touch()
    old = lock.stat().st_mtime - kernel_choice.CHILD_TIMEOUT_S - 1
    os.utime(lock, (old, old))
    assert kernel_choice._take_lock() is True
    assert lock.stat().st_mtime > old


@pytest.mark.slow
def test_from_an_empty_cache_detect_loads_the_backgrounds_kernels(tmp_path: Path) -> None:
    """A fresh cache folder: start compiles both halves, then ``analyze``, in the background
    while the first shot is extracted interpreted; after finish the next shot compiles nothing:
    ``analyze`` and ``first_invalid`` come from the cache the background wrote."""
    code = """
        import json
        import solitonde.instrument  # configures the cache folder
        from solitonde.signal import kernels as K, kernel_choice
        from solitonde.signal.pulses import detect
        from solitonde.signal.synth import pulse_train
        from solitonde.signal.waveform import Waveform
        kernel_choice.start()
        x = pulse_train(4000, 5e-7, [(300e-6, 50.0, 40e-6), (900e-6, 30.0, 40e-6)])
        first = detect(Waveform(0.0, 5e-7, x))
        interpreted = kernel_choice._spent > 0 and not K.analyze.signatures
        kernel_choice.finish()
        d = detect(Waveform(0.0, 5e-7, x))
        print(json.dumps({
            "interpreted_first": interpreted,
            "hits": [sum(f.stats.cache_hits.values()) for f in (K.analyze, K.first_invalid)],
            "misses": [sum(f.stats.cache_misses.values()) for f in (K.analyze, K.first_invalid)],
            "marker": kernel_choice._marker().is_file(),
            "tof_first": first.reflected.time_s - first.incident.time_s,
            "tof": d.reflected.time_s - d.incident.time_s}))
    """
    env = {k: v for k, v in os.environ.items()
           if k not in ("NUMBA_CACHE_DIR", kernel_choice.COMPILE_FIRST_ENV)}
    env["SOLITONDE_CACHE_DIR"] = str(tmp_path / "cache")
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], env=env,
                         capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result["interpreted_first"]
    assert result["hits"] == [1, 1] and result["misses"] == [0, 0]
    assert result["marker"]
    assert result["tof"] == pytest.approx(600e-6, abs=2 * DT)
    assert result["tof_first"] == pytest.approx(result["tof"], rel=1e-12)


def test_compiled_halves_give_what_the_kernel_in_one_call_gives():
    """The halves a fresh install compiles side by side, called one after the other, and
    analyze (detect's call): the same numbers, bit for bit."""
    from solitonde.signal.pulses import DetectOptions, kernel_args

    x = np.ascontiguousarray(_shot().samples)
    args = kernel_args(DetectOptions(travel_time_1n_s=2e-3), x.size, DT)
    head, rows = K.analyze(x, *args)
    located = K.locate(x, *args[: K.LOCATE_ARGS])
    halves = K.measure(*located, *args[K.LOCATE_ARGS :])
    np.testing.assert_array_equal(located[0], head)
    np.testing.assert_array_equal(halves, rows)
