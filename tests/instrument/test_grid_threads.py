"""The inversion's heaviest grid pass in bands of rows on two threads: every row once, the same
numbers to the bit as one thread, a band the helper cannot take run by the caller, errors
raised, one thread where the process is limited, and a forked child that makes its own helper."""

from __future__ import annotations

import multiprocessing
import sys
import threading
import time
from concurrent.futures import Future

import numpy as np
import pytest

import solitonde.instrument.inference.grid_threads as gt
import solitonde.instrument.inference.likelihood as lk
from solitonde.instrument import parallel
from solitonde.instrument.inference.fine_grid import predict
from solitonde.instrument.inference.inversion_inputs import FeatureSummary
from solitonde.instrument.inference.material_spread import spread_of
from solitonde.instrument.tables import bundled
from solitonde.instrument.tables.table import ModelTable


@pytest.fixture
def two_cores(monkeypatch: pytest.MonkeyPatch) -> None:
    """Two bands whatever this machine has (one core time-slices them)."""
    monkeypatch.setattr(gt, "default_workers", lambda: 2)
    monkeypatch.setattr(parallel, "_thread_limit", None)


def _recorder(seen: list[tuple[int, int, str]], wait_for_helper: bool = False):  # type: ignore[no-untyped-def]
    """A kernel that marks its rows in ``out`` and records its band and thread; with
    ``wait_for_helper``, the first band waits (up to 10 s) until another band has started, so
    that the helper takes its band however busy the machine."""
    started = threading.Event()

    def kernel(out: np.ndarray, start: int, stop: int) -> None:
        if start > 0:
            started.set()
        elif wait_for_helper:
            started.wait(10.0)
        out[start:stop] += 1
        seen.append((start, stop, threading.current_thread().name))
    return kernel


@pytest.mark.parametrize("n_rows", [1, 63, 64, 481])
def test_bands_cover_every_row_once(n_rows: int) -> None:
    for parts in (1, 2, 3):
        spans = gt.bands(n_rows, parts)
        rows = [i for a, b in spans for i in range(a, b)]
        assert rows == list(range(n_rows))
        sizes = [b - a for a, b in spans]
        assert max(sizes) - min(sizes) <= 1


def test_two_bands_run_on_two_threads(two_cores: None) -> None:
    seen: list[tuple[int, int, str]] = []
    out = np.zeros(481)
    gt.run_in_bands(_recorder(seen, wait_for_helper=True), 481, out)
    assert np.all(out == 1)
    assert sorted(s[:2] for s in seen) == [(0, 240), (240, 481)]
    names = {start: name for start, _, name in seen}
    assert names[0] == threading.current_thread().name
    assert names[240].startswith("solitonde-grid")


def test_a_band_the_helper_has_not_started_runs_here(two_cores: None) -> None:
    """The helper busy with another caller's band (held here by an event): this call does not
    wait for it, it runs its second band itself."""
    release = threading.Event()
    blocker: Future[bool] = gt._helpers().submit(release.wait, 10.0)
    try:
        seen: list[tuple[int, int, str]] = []
        out = np.zeros(200)
        start = time.perf_counter()
        gt.run_in_bands(_recorder(seen), 200, out)
        took = time.perf_counter() - start
    finally:
        release.set()
        blocker.result()
    assert np.all(out == 1)
    assert {name for *_, name in seen} == {threading.current_thread().name}
    assert took < 5.0  # not the blocker's 10 s


def test_an_error_in_either_band_is_raised(two_cores: None) -> None:
    def kernel(start: int, stop: int) -> None:
        if start > 0:
            raise ValueError("band 2")
        time.sleep(0.05)

    with pytest.raises(ValueError, match="band 2"):
        gt.run_in_bands(kernel, 100)


def test_the_callers_error_is_raised_once_the_helper_has_stopped(two_cores: None) -> None:
    """Both bands fail: the caller's error is the one raised, and only after the helper's band
    has ended (no thread writes the arrays once the call is over)."""
    started = threading.Event()
    ended: list[str] = []

    def kernel(start: int, stop: int) -> None:
        if start == 0:
            assert started.wait(10.0)  # the helper has its band
            raise KeyError("band 1")
        started.set()
        time.sleep(0.1)
        ended.append("band 2")
        raise ValueError("band 2")

    with pytest.raises(KeyError, match="band 1"):
        gt.run_in_bands(kernel, 100)
    assert ended == ["band 2"]


def test_without_new_threads_every_band_runs_here(two_cores: None,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """While the interpreter shuts down a pool takes no new work: the caller runs it all."""
    class Closed:
        def submit(self, *args: object) -> None:
            raise RuntimeError("cannot schedule new futures after interpreter shutdown")

    monkeypatch.setattr(gt, "_helpers", Closed)
    seen: list[tuple[int, int, str]] = []
    out = np.zeros(300)
    gt.run_in_bands(_recorder(seen), 300, out)
    assert np.all(out == 1)
    assert sorted(s[:2] for s in seen) == [(0, 150), (150, 300)]
    assert {name for *_, name in seen} == {threading.current_thread().name}


def test_small_grids_and_limited_processes_run_whole(two_cores: None,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    seen: list[tuple[int, int, str]] = []
    gt.run_in_bands(_recorder(seen), gt.MIN_ROWS - 1, np.zeros(gt.MIN_ROWS - 1))
    assert [s[:2] for s in seen] == [(0, gt.MIN_ROWS - 1)]
    monkeypatch.setattr(parallel, "_thread_limit", 1)  # what a Dask worker's hook sets
    assert gt.threads() == 1
    seen.clear()
    gt.run_in_bands(_recorder(seen), 481, np.zeros(481))
    assert [s[:2] for s in seen] == [(0, 481)]


def test_the_likelihood_in_two_bands_is_one_threads_to_the_bit(
        two_cores: None, monkeypatch: pytest.MonkeyPatch) -> None:
    """Three sphere sizes with the material's spread and Woodbury's correction in the banded
    pass: every array the same as the pass over the whole grid on one thread."""
    table = ModelTable.load(bundled.default_table())
    items = []
    for k, d in enumerate((4.76e-3, 9.53e-3, 19.05e-3)):
        tof, arr = predict(table, d, 3.3e-3, 0.02)
        items.append(FeatureSummary(d, tof * (1 + 1e-3 * k), arr * 0.98, 3e-7, 0.004, 5))
    spread = spread_of(table)
    banded = lk.deviance(table, items, None, spread)
    assert gt.threads() == 2 and banded.m_det is not None
    monkeypatch.setattr(parallel, "_thread_limit", 1)
    whole = lk.deviance(table, items, None, spread)
    for name in ("misfit", "logdet", "det", "m_sum", "ur_sum", "chi2", "row_min"):
        assert np.array_equal(getattr(banded, name), getattr(whole, name)), name
    assert banded.best_at == whole.best_at == int(np.argmin(whole.total()))


def _child(queue: multiprocessing.Queue) -> None:  # type: ignore[type-arg]
    seen: list[tuple[int, int, str]] = []
    out = np.zeros(300)
    gt.run_in_bands(_recorder(seen, wait_for_helper=True), 300, out)
    queue.put((float(out.sum()), sorted(name.startswith("solitonde-grid") for *_, name in seen)))


@pytest.mark.skipif(sys.platform != "linux", reason="fork is Linux's start method here")
def test_a_forked_child_makes_its_own_helper(two_cores: None) -> None:
    """The parent's helper thread exists (a fork copies the pool, not its thread): the child's
    pass still finishes, on a helper of its own."""
    gt.run_in_bands(_recorder([], wait_for_helper=True), 300, np.zeros(300))
    ctx = multiprocessing.get_context("fork")
    queue = ctx.Queue()
    child = ctx.Process(target=_child, args=(queue,))
    child.start()
    child.join(30)
    if child.is_alive():
        child.kill()
        pytest.fail("the forked child's pass hung on the parent's helper")
    assert child.exitcode == 0
    assert queue.get(timeout=5) == (300.0, [False, True])


def test_inversions_from_many_threads_at_once_are_each_ones_alone(two_cores: None) -> None:
    """The service's request threads invert at once, their bands queued on one helper: each
    answer is the one the same inputs give alone."""
    from concurrent.futures import ThreadPoolExecutor

    from solitonde.instrument.inference.inversion import invert

    table = ModelTable.load(bundled.default_table())
    cases = []
    for k, (t, at) in enumerate(((2.6e-3, 0.3), (3.3e-3, 0.02), (4.4e-3, 0.1), (5.2e-3, 0.2))):
        items = []
        for d in (4.76e-3, 9.53e-3, 19.05e-3):
            tof, arr = predict(table, d, t, at)
            items.append(FeatureSummary(d, tof, arr * (1 - 0.01 * k), 3e-7, 0.004, 5))
        cases.append(items)
    alone = [invert(table, items).to_dict() for items in cases]
    with ThreadPoolExecutor(8) as pool:
        together = list(pool.map(lambda i: invert(table, cases[i % 4]).to_dict(), range(32)))
    assert together == [alone[i % 4] for i in range(32)]
