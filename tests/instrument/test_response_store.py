"""The plate-response store: a table's dissipation layer and a rebuild read the responses the
first build computed and give the same points to the bit; the store holds its size cap, keeps
whole files under concurrent writers, and `solitonde cache` reports and clears it. A build on a
Dask cluster of separate scheduler and worker processes, sharing the store's folder, gives the
serial build's table."""

from __future__ import annotations

import dataclasses
import os
import shutil
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app
from solitonde.instrument.tables import greens_cache, table_build
from solitonde.instrument.tables.greens_cache import DiskGreensCache
from solitonde.instrument.tables.sweep import damped_scene
from solitonde.instrument.tables.table import SCALAR_FEATURES, SECONDARY_FEATURES, ModelTable
from solitonde.instrument.tables.table_build import Sweep, build_table

FAST = {"sem": {"elements": [6, 6, 1], "order": [2, 2, 2]}}


def _sweep() -> Sweep:
    # both sizes near the support (the meshed plate) and one far (the dashpot)
    return Sweep([4.76e-3, 9.53e-3], [3e-3, 5e-3], [0.0, 0.02, 0.3], scene=FAST)


def _build(sweep: Sweep, out: Path, responses: Path | bool, **kw: object) -> int:
    """Build; returns how many plate responses the build computed."""
    computed: list[int] = []
    report = build_table(sweep, out, workers=1, responses=responses,
                         on_plate=lambda r: computed.append(r["greens_computed"]), **kw)
    assert report.complete
    return sum(computed)


def _same_points(a: Path, b: Path) -> None:
    """Every feature, status and flag equal to the bit (NaN == NaN)."""
    ta, tb = ModelTable.load(a), ModelTable.load(b)
    for k in (*SCALAR_FEATURES, *SECONDARY_FEATURES):
        np.testing.assert_array_equal(ta.features[k], tb.features[k], err_msg=k)
    with h5py.File(a) as fa, h5py.File(b) as fb:
        for k in ("status", "flags", "plate_model", "messages"):
            np.testing.assert_array_equal(fa[k][...], fb[k][...], err_msg=k)


def test_a_layer_and_a_rebuild_compute_no_response_again(tmp_path: Path) -> None:
    """The damping acts in the chain, not the plate: the damped sweep's plates are the elastic
    sweep's, so a layer (and the same table built again) reads every response from the store,
    and its points are those of a build that computed them itself."""
    store = tmp_path / "store"
    elastic = _build(_sweep(), tmp_path / "a.h5", store)
    assert elastic > 0
    assert _build(_sweep(), tmp_path / "again.h5", store) == 0
    damped = dataclasses.replace(_sweep(), scene=damped_scene(FAST, 1e-6))
    assert _build(damped, tmp_path / "layer.h5", store) == 0
    assert _build(damped, tmp_path / "layer-alone.h5", False) == elastic
    _same_points(tmp_path / "a.h5", tmp_path / "again.h5")
    _same_points(tmp_path / "layer.h5", tmp_path / "layer-alone.h5")


def test_the_workers_time_the_pilot_plate_as_the_pilot_timed_it(tmp_path: Path,
                                                                monkeypatch) -> None:
    """The plan's slowdown compares a worker's time for a pilot plate with the pilot's own: in
    a rebuild the pilot read the plate's responses from the store, so the workers read them
    too (computing them instead made every rebuild's plan 4 times too slow, the clamp); in a
    first build both compute them."""
    sweep = Sweep([4.76e-3], [3e-3], [0.0], scene=FAST)
    store = str(tmp_path / "store")

    def warm_plate(name: str) -> table_build.WarmPlate:
        with h5py.File(tmp_path / name, "w") as fh:
            table_build.create(fh, sweep)
            return table_build._pilot(fh, sweep, sweep.to_dict(), 2, None, store, 0, False)[3]

    first = warm_plate("first.h5")
    assert first.store is None and first.seconds > 0
    rebuild = warm_plate("rebuild.h5")
    assert rebuild.store == store and rebuild.task == first.task
    computed: list[int] = []
    run_plate = table_build.run_plate  # the name the pilot and the workers' timing call

    def counted(*args: object) -> dict:
        result = run_plate(*args)  # type: ignore[arg-type]
        computed.append(result["greens_computed"])
        return result  # type: ignore[return-value]

    monkeypatch.setattr(table_build, "run_plate", counted)
    for _ in range(2):
        table_build._timed_plate(sweep.to_dict(), *rebuild.task, rebuild.store)
    assert computed == [0, 0]  # both runs read the stored responses, as the rebuild's pilot did
    assert table_build._timed_plate(sweep.to_dict(), *first.task, first.store) > 0
    assert computed[2:] == [1]  # and a first build's computes them, as its pilot did


def test_a_kinds_first_damped_chain_is_not_timed(tmp_path: Path, monkeypatch) -> None:
    """The first damped chain of each plate kind compiles its kernels on a fresh install (a
    second on the dashpot, against a few milliseconds): the pilot runs it once untimed, so the
    layers' estimate counts the chains' time, not the compiler's (it had planned 82 s for a
    28 s build). Here a kind's first damped run takes 5 s, every other run 10 ms."""
    sweep = _sweep()
    run = table_build._timed_plate
    slow: set[str] = set()

    def timed(spec: dict, i_t: int, i_l: int, todo: list[int], store: str | None = None
              ) -> float:
        run(spec, i_t, i_l, todo, store)
        kind = table_build._kind(sweep, i_t, i_l)
        if spec["scene"].get("effects", {}).get("dissipation") and kind not in slow:
            slow.add(kind)
            return 5.0
        return 0.01

    monkeypatch.setattr(table_build, "_timed_plate", timed)
    with h5py.File(tmp_path / "t.h5", "w") as fh:
        table_build.create(fh, sweep)
        plan = table_build._pilot(fh, sweep, sweep.to_dict(), 1, None, str(tmp_path / "store"),
                                  1, False)[0]
    assert slow == {"meshed", "dashpot"}  # both kinds' first damped runs happened
    assert plan.damped_factor == 1.0


def test_busy_workers_are_never_counted_faster_than_the_pilot() -> None:
    """The plan scales its estimate by the workers' time over the pilot's: a ratio under 1 is
    the timing disturbed (it made plans a third short), one over 4 too; in between it counts."""
    assert table_build.parallel_slowdown(0.62, 1.0) == 1.0
    assert table_build.parallel_slowdown(1.3, 1.0) == pytest.approx(1.3)
    assert table_build.parallel_slowdown(9.0, 1.0) == 4.0
    assert table_build.parallel_slowdown(1.0, 0.0) == 1.0


def test_the_store_keeps_under_its_cap_dropping_the_least_recently_used(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Past the cap, the responses used longest ago go first; a load counts as a use."""
    one = np.arange(1000, dtype=float)  # about 8 kB on disk
    size = len(np.lib.format.header_data_from_array_1_0(one)) + one.nbytes
    store = DiskGreensCache(tmp_path, cap_bytes=int(3.5 * (size + 300)))
    for i, key in enumerate(("a", "b", "c")):
        store.store(key, one + i)
        os.utime(store.path(key), (1000.0 + i, 1000.0 + i))  # a, then b, then c
    assert store.load("a") is not None  # a is now the most recently used
    # a process checks the cap at its first store in a folder and every PRUNE_EVERY after
    monkeypatch.setattr(greens_cache, "PRUNE_EVERY", 1)
    store.store("d", one)
    kept = {p.stem for p in tmp_path.glob("*.npz")}
    assert "b" not in kept and {"a", "d"} <= kept
    assert store.info().bytes <= store.cap_bytes


def _write_often(folder: Path, a: np.ndarray) -> None:
    store = DiskGreensCache(folder)
    for _ in range(15):
        store.store("k", a)


def test_concurrent_writers_of_one_response_leave_a_whole_file(tmp_path: Path) -> None:
    """Writer processes (as Dask workers are) race on one key while a reader loads it: every
    load is whole or None, never a torn file, and the last file is one writer's array. (Writers
    as threads of one process would race CPython 3.11's parser instead: numpy reads a file's
    header with ``ast.literal_eval``, which two threads at once can fail with a SystemError.)"""
    import multiprocessing

    store = DiskGreensCache(tmp_path)
    arrays = [np.full(20_000, float(i)) for i in range(4)]
    seen: list[np.ndarray | None] = []
    done = threading.Event()

    def read() -> None:
        while not done.is_set():
            seen.append(store.load("k"))

    reader = threading.Thread(target=read)
    reader.start()
    ctx = multiprocessing.get_context("fork" if sys.platform == "linux" else "spawn")
    writers = [ctx.Process(target=_write_often, args=(tmp_path, a)) for a in arrays]
    for w in writers:
        w.start()
    for w in writers:
        w.join(60)
    done.set()
    reader.join()
    assert [w.exitcode for w in writers] == [0, 0, 0, 0]
    final = store.load("k")
    assert final is not None and any(np.array_equal(final, a) for a in arrays)
    for got in seen:
        assert got is None or any(np.array_equal(got, a) for a in arrays)
    assert not [p for p in tmp_path.iterdir() if not p.name.endswith(".npz")]


def test_cache_info_and_clear_name_each_cache(tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SOLITONDE_CACHE", str(tmp_path))
    DiskGreensCache().store("abc", np.ones(10))
    runner = CliRunner()
    out = runner.invoke(build_app(), ["cache", "info", "--responses"])
    assert out.exit_code == 0, out.output
    assert out.output.startswith(f"responses: 1 in {tmp_path / 'greens'} (")
    assert "compiled" not in out.output
    both = runner.invoke(build_app(), ["cache", "info"])
    assert "responses: 1" in both.output and "compiled: " in both.output
    cleared = runner.invoke(build_app(), ["cache", "clear", "--responses"])
    assert cleared.output == f"responses: deleted 1 from {tmp_path / 'greens'}\n"
    assert DiskGreensCache().info().responses == 0


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_a_build_on_a_dask_cluster_of_separate_processes_is_the_serial_build(
        tmp_path: Path) -> None:
    """`dask scheduler` and two `dask worker` processes, as a lab would start them, with the
    response store on a folder every worker reads: the table is the serial one to the bit, and
    a layer on the cluster computes no response again."""
    dask = shutil.which("dask", path=str(Path(sys.executable).parent)) or shutil.which("dask")
    if dask is None:
        pytest.skip("the dask command line is not installed")
    serial = tmp_path / "serial.h5"
    _build(_sweep(), serial, False)
    store = tmp_path / "shared-store"
    address = f"tcp://127.0.0.1:{_free_port()}"
    env = {**os.environ, "SOLITONDE_CACHE": str(tmp_path / "own")}  # not the store's folder
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port",
                               address.rsplit(":", 1)[1], "--dashboard-address", ":0"],
                              env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        time.sleep(1.0)
        procs += [subprocess.Popen([dask, "worker", address, "--nthreads", "1",
                                    "--nworkers", "1", "--dashboard-address", ":0"],
                                   env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                  for _ in range(2)]
        from dask.distributed import Client

        with Client(address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=60)
        computed: list[int] = []
        report = build_table(_sweep(), tmp_path / "cluster.h5", scheduler=address,
                             responses=store,
                             on_plate=lambda r: computed.append(r["greens_computed"]))
        assert report.complete and report.runner.startswith("dask scheduler")
        assert sum(computed) > 0 and DiskGreensCache(store).info().responses == sum(computed)
        _same_points(serial, tmp_path / "cluster.h5")
        layer: list[int] = []
        damped = dataclasses.replace(_sweep(), scene=damped_scene(FAST, 1e-6))
        build_table(damped, tmp_path / "layer.h5", scheduler=address, responses=store,
                    on_plate=lambda r: layer.append(r["greens_computed"]))
        assert sum(layer) == 0
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()


def test_the_default_store_is_each_workers_own(tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """A task told "the default store" resolves it where it runs (its machine's folder), not a
    path the building machine chose."""
    from solitonde.instrument.tables.greens_cache import DEFAULT_STORE
    from solitonde.instrument.tables.plate_task import run_plate

    monkeypatch.setenv("SOLITONDE_CACHE", str(tmp_path / "this-worker"))
    result = run_plate(_sweep().to_dict(), 0, 0, None, DEFAULT_STORE)
    assert result["greens_computed"] > 0
    assert len(list((tmp_path / "this-worker" / "greens").glob("*.npz"))) == \
        result["greens_computed"]


def test_a_cap_that_is_no_size_warns_and_keeps_the_default(
        monkeypatch: pytest.MonkeyPatch) -> None:
    from solitonde.instrument.tables.greens_cache import DEFAULT_MAX_MB, max_bytes

    for bad in ("abc", "inf", "-5", "0"):
        monkeypatch.setenv("SOLITONDE_CACHE_MAX_MB", bad)
        with pytest.warns(UserWarning, match=f"SOLITONDE_CACHE_MAX_MB: '{bad}' is not a size"):
            assert max_bytes() == DEFAULT_MAX_MB * 1_000_000
    monkeypatch.setenv("SOLITONDE_CACHE_MAX_MB", "250")
    assert max_bytes() == 250_000_000
