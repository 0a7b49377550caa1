"""Table builder: resume after interruption, Dask scheduler vs serial, atomic finish, sharing of
Green's functions across sphere sizes, features as the signal package measures them."""

from __future__ import annotations

import json
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from solitonde.instrument.inference.inversion import invert
from solitonde.instrument.inference.inversion_inputs import FeatureSummary
from solitonde.instrument.tables.measured import as_measured, detect_options
from solitonde.instrument.tables.plate_task import run_plate
from solitonde.instrument.tables.table import (
    SCALAR_FEATURES,
    SECONDARY_FEATURES,
    STATUS_OK,
    ModelTable,
    TableError,
)
from solitonde.instrument.tables.table_build import (
    BuildPlan,
    Sweep,
    build_table,
    partial_path,
)
from solitonde.model.scene import scene_from_dict
from solitonde.model.simulate import simulate
from solitonde.signal.features import EXTRACTOR_VERSION, extract

# A coarse spectral-element plate keeps a Green's function to a fraction of a second.
FAST = {"sem": {"elements": [6, 6, 1], "order": [2, 2, 2]}}


def tiny_sweep(**kw: object) -> Sweep:
    return Sweep([4.76e-3, 9.53e-3], [3e-3, 5e-3], [0.0, 0.02, 0.3], scene=FAST, **kw)


DATASETS = ("status", "done", "flags", "plate_model", "messages")


def same_table(a: Path, b: Path, rtol: float = 0.0) -> None:
    """Every feature and per-point dataset equal (NaN == NaN); provenance may differ."""
    ta, tb = ModelTable.load(a), ModelTable.load(b)
    assert ta.sweep == tb.sweep
    for k in (*SCALAR_FEATURES, *SECONDARY_FEATURES):
        np.testing.assert_allclose(ta.features[k], tb.features[k], rtol=rtol, atol=0,
                                   equal_nan=True, err_msg=k)
    with h5py.File(a) as fa, h5py.File(b) as fb:
        for k in DATASETS:
            np.testing.assert_array_equal(fa[k][...], fb[k][...], err_msg=k)


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An uninterrupted serial build."""
    out = tmp_path_factory.mktemp("ref") / "table.h5"
    report = build_table(tiny_sweep(), out, workers=1)
    assert report.complete and report.points_written == 12 and report.plates_written == 6
    return out


def test_reference_table_is_complete_and_sane(reference: Path) -> None:
    """All points computed; near the support the finite plate (auto: the Mindlin plate's Green's
    function) was used; provenance recorded."""
    t = ModelTable.load(reference)
    assert t.complete and (t.status == STATUS_OK).all()
    names = {t.plate_model_names[int(m)] for m in np.unique(t.plate_model)}
    assert names == {"mindlin_greens", "infinite"}
    s = t.summary()
    assert s["shape"] == [2, 2, 3]
    prov = s["provenance"]
    for key in ("solitonde_version", "scene_defaults", "tiers", "mesh", "step_s", "build_wall_s",
                "machine", "git_revision"):
        assert key in prov
    json.dumps(s)  # JSON-ready for the service
    assert t.reading_version == s["reading_version"] == EXTRACTOR_VERSION
    # at the support the plate barely moves: ARR close to 1 for both sizes, far from it lower
    assert (t.features["arr"][:, :, 0] > 0.9).all()
    assert (t.features["arr"][:, :, 2] < t.features["arr"][:, :, 0]).all()


def test_interrupted_build_resumes_to_the_same_table(reference: Path, tmp_path: Path) -> None:
    """Stopping after two plates leaves only <out>.partial; the rerun finishes the same table."""
    out = tmp_path / "table.h5"
    first = build_table(tiny_sweep(), out, workers=1, max_plates=2)
    assert not first.complete and not out.exists() and partial_path(out).exists()
    with h5py.File(partial_path(out)) as fh:
        assert fh["done"][...].sum() == 4
    second = build_table(tiny_sweep(), out, workers=1)
    assert second.complete and second.points_written == 8  # only what was missing
    assert out.exists() and not partial_path(out).exists()
    same_table(reference, out)


def test_build_through_a_separate_dask_cluster_matches_serial(reference: Path,
                                                              tmp_path: Path) -> None:
    """A LocalCluster started apart from the builder, addressed by --scheduler, gives the same
    table (up to the last bit of the fits' BLAS reductions, hence rtol 1e-12)."""
    distributed = pytest.importorskip("dask.distributed")
    cluster = distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                       dashboard_address=":0")
    try:
        out = tmp_path / "dask.h5"
        report = build_table(tiny_sweep(), out, scheduler=cluster.scheduler_address)
        assert report.complete and report.runner.startswith("dask scheduler")
    finally:
        cluster.close()
    same_table(reference, out, rtol=1e-12)


def test_a_small_build_runs_here_without_starting_workers(reference: Path,
                                                          tmp_path: Path) -> None:
    """Twelve points of a coarse plate take about a second here, less than two workers' start:
    with two workers asked for and no plan, every plate runs in this process, and the report
    and the provenance say so; with a plan, the plan says one worker and no start, and that
    its dissipation layers run here too."""
    out = tmp_path / "small.h5"
    report = build_table(tiny_sweep(), out, workers=2)
    assert report.complete and report.runner == "serial"
    assert ModelTable.load(out).provenance["runner"] == "serial"
    same_table(reference, out)
    plans: list[BuildPlan] = []
    again = build_table(tiny_sweep(), tmp_path / "planned.h5", workers=2, plan=plans.append,
                        layers=3)
    assert again.runner == "serial" and plans[0].workers == 1 and plans[0].start_s == 0.0
    assert plans[0].eta_s == plans[0].serial_s
    assert plans[0].layers_here and plans[0].layers_eta_s == plans[0].layers_serial_s > 0


def test_a_batch_starts_workers_once_its_rest_is_worth_their_start(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Tasks run here first; once the rest at the slowest task's pace would take longer here
    than on the workers with their start counted, the workers take the rest."""
    from solitonde.instrument import parallel

    cheap = parallel.Runs()
    assert list(parallel.run_tasks(abs, [(-k,) for k in range(5)], 2, None, here_first=True,
                                   runs=cheap)) == [0, 1, 2, 3, 4]
    assert (cheap.here, cheap.workers) == (5, 0)
    monkeypatch.setattr(parallel, "LOCAL_START_S", 0.01)  # a start cheaper than one task
    dear = parallel.Runs()
    list(parallel.run_tasks(time.sleep, [(0.05,)] * 4, 2, None, here_first=True, runs=dear))
    assert (dear.here, dear.workers) == (1, 3)


def _worker_state() -> tuple[int, int, int, bool, int]:
    """In a worker: numba's threads, BLAS's most threads, the inversion's grid threads, whether
    the model's plate kernels were imported before the worker ran anything of its own, and a
    kernel compiled there (numba re-reads the environment before a compile, and refuses a
    thread count that differs from its pool's)."""
    import sys

    import numba
    from threadpoolctl import threadpool_info

    from solitonde.instrument.inference import grid_threads

    blas = max((p["num_threads"] for p in threadpool_info()), default=1)
    fresh = numba.njit(lambda x: x + 1)(1)
    return (numba.get_num_threads(), blas, grid_threads.threads(),
            "solitonde.model.sem_kernels" in sys.modules, fresh)


@pytest.mark.skipif(__import__("sys").platform != "linux", reason="workers fork only on Linux")
def test_local_workers_are_forked_with_the_model_loaded_and_one_thread_each() -> None:
    """A local cluster's workers start from this process (the model's modules already there),
    run single-threaded whatever pools this process had, and compile what this process had
    not."""
    from dask.distributed import Client

    import solitonde.model.sem_kernels  # noqa: F401  (this process has the model loaded)
    from solitonde.instrument.parallel import local_cluster

    with local_cluster(2) as cluster, Client(cluster) as client:
        states = client.run(_worker_state)
    assert len(states) == 2
    assert set(states.values()) == {(1, 1, 1, True, 2)}


def test_a_build_on_local_workers_matches_serial(reference: Path, tmp_path: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """With the workers' start made free the tiny sweep runs on two forked local workers, and
    gives the serial table (up to the last bit of the fits' BLAS reductions)."""
    from solitonde.instrument import parallel

    monkeypatch.setattr(parallel, "LOCAL_START_S", 0.0)
    runs = parallel.Runs()
    out = tmp_path / "local.h5"
    tasks = [(k,) for k in range(3)]
    assert sorted(parallel.run_tasks(abs, tasks, 2, None, runs=runs)) == [0, 1, 2]
    assert runs.workers == 3
    report = build_table(tiny_sweep(), out, workers=2)
    assert report.complete and report.runner.startswith("dask LocalCluster")
    same_table(reference, out, rtol=1e-12)


def test_file_appears_only_when_complete(tmp_path: Path) -> None:
    """While plates are being written the output name does not exist."""
    out = tmp_path / "t.h5"
    seen = []
    build_table(Sweep([4.76e-3], [3e-3], [0.2, 0.3], scene=FAST), out, workers=1,
                on_plate=lambda r: seen.append(out.exists()))
    assert seen == [False, False] and out.exists()


def test_partial_of_another_sweep_is_refused(tmp_path: Path) -> None:
    out = tmp_path / "t.h5"
    build_table(tiny_sweep(), out, workers=1, max_plates=1)
    with pytest.raises(TableError, match="sweep"):
        build_table(Sweep([4.76e-3], [3e-3], [0.3], scene=FAST), out, workers=1)


def test_partial_read_another_way_is_refused(tmp_path: Path) -> None:
    """A build started under another reading of the extractor is not resumed: one table holds
    one reading."""
    out = tmp_path / "t.h5"
    build_table(tiny_sweep(), out, workers=1, max_plates=1)
    with h5py.File(partial_path(out), "r+") as fh:
        fh.attrs["reading_version"] = EXTRACTOR_VERSION - 1
    with pytest.raises(TableError, match=f"reading {EXTRACTOR_VERSION - 1}, this solitonde reads "
                                         f"with {EXTRACTOR_VERSION}") as info:
        build_table(tiny_sweep(), out, workers=1)
    assert info.value.field == "partial" and partial_path(out).exists()


def test_an_answer_from_a_table_read_another_way_says_so(reference: Path,
                                                         tmp_path: Path) -> None:
    """A table that records no reading (built before tables did) was read with reading 1:
    its answers carry a warning to rebuild it; the table's own reading gives none."""
    table = ModelTable.load(reference)
    node = FeatureSummary(4.76e-3, float(table.features["tof_s"][0, 1, 2]),
                          float(table.features["arr"][0, 1, 2]), None, None, 5)
    assert not any("reading" in w for w in invert(table, [node]).warnings)
    old = tmp_path / "old.h5"
    old.write_bytes(reference.read_bytes())
    with h5py.File(old, "r+") as fh:
        del fh.attrs["reading_version"]
    warned = [w for w in invert(ModelTable.load(old), [node]).warnings if "reading" in w]
    assert len(warned) == 1 and "read with the extractor's reading 1" in warned[0]
    assert "rebuild the table" in warned[0]


def test_one_greens_function_serves_every_sphere_size() -> None:
    """Near the support all sizes use the finite plate; on the 3-D plate (one mesh for every
    size) the task computes one response."""
    sweep = Sweep([4.76e-3, 9.53e-3], [3e-3, 5e-3], [0.0, 0.02, 0.3],
                  scene={**FAST, "sem": {**FAST["sem"], "plate_theory": "3d"}})
    result = run_plate(sweep.to_dict(), 0, 1)
    assert {p["plate_model"] for p in result["points"].values()} == {"greens"}
    assert result["greens_computed"] == 1
    assert len(result["points"]) == 2


def test_the_mindlin_plate_computes_one_response_per_mesh() -> None:
    """The Mindlin plate's mesh follows each size's flexural wavelength: a response per distinct
    mesh, none computed twice."""
    from solitonde.model.tiers.meshed import mindlin_elements

    sweep = tiny_sweep()
    result = run_plate(sweep.to_dict(), 0, 1)
    assert {p["plate_model"] for p in result["points"].values()} == {"mindlin_greens"}
    meshes = {mindlin_elements(sweep.scene_at(i, 0, 1)) for i in range(2)}
    assert result["greens_computed"] == len(meshes)


def test_point_features_are_the_signal_packages(reference: Path) -> None:
    """A table point holds what extract() reads from the simulated trace with its pre-trigger
    and its chain's options (the travel gate: a measured shot of that size gets the same)."""
    t = ModelTable.load(reference)
    scene = tiny_sweep().scene_at(1, 1, 2)
    f = extract(as_measured(simulate(scene)), **detect_options(scene))
    assert t.features["tof_s"][1, 1, 2] == f.tof_s
    assert t.features["arr"][1, 1, 2] == f.arr
    # and the extractor agrees with the model's own peak times within a sample
    truth = simulate(scene_from_dict(scene.to_dict())).truth
    assert abs(f.tof_s - truth["tof_s"]) < 0.5e-6


def test_sweep_validation_names_the_field() -> None:
    with pytest.raises(TableError, match="thicknesses_m"):
        Sweep([4.76e-3], [3e-3, 3e-3], [0.1])
    with pytest.raises(Exception, match=r"plate\.material"):
        Sweep([4.76e-3], [3e-3], [0.1], scene={"plate": {"material": "cheese"}})


def test_load_rejects_other_files(tmp_path: Path) -> None:
    p = tmp_path / "x.h5"
    with h5py.File(p, "w") as fh:
        fh["a"] = 1
    with pytest.raises(TableError, match="not a solitonde model table"):
        ModelTable.load(p)
    with pytest.raises(TableError, match="no such file"):
        ModelTable.load(tmp_path / "missing.h5")


DEFAULT_TABLE = Path(__file__).resolve().parents[2] / "data_samples" / "default_table.h5"


def _reverse(fh: h5py.File, name: str) -> None:
    fh[name][...] = fh[name][...][::-1]


def _replace(fh: h5py.File, name: str, value: object) -> None:
    del fh[name]
    fh[name] = value


CORRUPTIONS = [
    ("features/arr_upper_bound", lambda fh: fh.__delitem__("features/arr_upper_bound")),
    ("features/secondary_ratios", lambda fh: fh.__delitem__("features/secondary_ratios")),
    ("status", lambda fh: fh.__delitem__("status")),
    ("axes/distance_m", lambda fh: fh.__delitem__("axes/distance_m")),
    ("sweep", lambda fh: fh.attrs.__delitem__("sweep")),
    ("sweep", lambda fh: fh.attrs.__setitem__("sweep", "{not json")),
    ("provenance", lambda fh: fh.attrs.__setitem__("provenance", "[1]")),
    ("format_version", lambda fh: fh.attrs.__setitem__("format_version", "abc")),
    # an axis whose length does not match the features
    ("features/tof_s", lambda fh: _replace(fh, "axes/thickness_m",
                                           fh["axes/thickness_m"][...][:5])),
    ("axes/distance_m", lambda fh: _reverse(fh, "axes/distance_m")),
    ("axes/thickness_m", lambda fh: _replace(fh, "axes/thickness_m",
                                             np.r_[fh["axes/thickness_m"][...][:-1], np.nan])),
    ("axes/diameter_m", lambda fh: _replace(fh, "axes/diameter_m", [0.00476, 0.00476, 0.01905])),
    ("axes/diameter_m", lambda fh: _replace(fh, "axes/diameter_m", [-0.00476, 0.00953, 0.01905])),
    ("axes/distance_m", lambda fh: _replace(fh, "axes/distance_m", np.zeros((14, 1)))),
    ("features/arr", lambda fh: _replace(fh, "features/arr", np.zeros((3, 8)))),
    ("diagnostics/wall_s", lambda fh: _replace(fh, "diagnostics/wall_s", np.zeros(3))),
    ("flags", lambda fh: _replace(fh, "flags", np.full(fh["flags"].shape, b"x", dtype="S1"))),
]


@pytest.mark.parametrize(("field", "corrupt"), CORRUPTIONS,
                         ids=[f"{c[0]}:{i}" for i, c in enumerate(CORRUPTIONS)])
def test_load_checks_datasets_attributes_shapes_and_axes(tmp_path: Path, field: str,
                                                         corrupt: object) -> None:
    """A damaged table is a TableError naming the dataset or attribute at load, never a
    KeyError there or a wrong answer later."""
    p = tmp_path / "t.h5"
    p.write_bytes(DEFAULT_TABLE.read_bytes())
    ModelTable.load(p)  # the intact copy loads
    with h5py.File(p, "a") as fh:
        corrupt(fh)  # type: ignore[operator]
    with pytest.raises(TableError) as info:
        ModelTable.load(p)
    assert info.value.field == field


@pytest.mark.parametrize("content", [b"", b"garbage, not HDF5\n" * 10, b"\x89HDF\r\n\x1a\n"])
def test_partial_that_is_not_a_build_is_refused_and_kept(tmp_path: Path, content: bytes) -> None:
    out = tmp_path / "t.h5"
    part = tmp_path / "t.h5.partial"
    part.write_bytes(content)
    with pytest.raises(TableError) as info:
        build_table(Sweep([4.76e-3], [3e-3], [0.3], scene=FAST), out, workers=1)
    assert info.value.field == "partial" and "delete it" in str(info.value)
    assert part.read_bytes() == content and not out.exists()


def test_partial_hdf5_of_something_else_is_refused_and_kept(tmp_path: Path) -> None:
    out = tmp_path / "t.h5"
    part = tmp_path / "t.h5.partial"
    with h5py.File(part, "w") as fh:
        fh["x"] = 1
    with pytest.raises(TableError, match="delete it") as info:
        build_table(Sweep([4.76e-3], [3e-3], [0.3], scene=FAST), out, workers=1)
    assert info.value.field == "partial"
    with h5py.File(part, "r") as fh:
        assert list(fh) == ["x"]


def test_out_a_folder_is_refused_before_any_work(tmp_path: Path) -> None:
    """The finished table could not be renamed onto a folder: refused first, not after the build."""
    out = tmp_path / "t.h5"
    out.mkdir()
    with pytest.raises(TableError, match=r"out: .* is a folder"):
        build_table(Sweep([4.76e-3], [3e-3], [0.3], scene=FAST), out, workers=1)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.h5"]


def test_a_bad_grid_point_leaves_no_partial_that_refuses_the_corrected_sweep(
        tmp_path: Path) -> None:
    """A distance beyond the plate fails before the partial file exists; the fix then builds."""
    from solitonde.model.errors import SceneError

    out = tmp_path / "t.h5"
    with pytest.raises(SceneError, match="distance_to_support"):
        build_table(Sweep([4.76e-3], [3e-3], [0.3, 5.0], scene=FAST), out, workers=1)
    assert not partial_path(out).exists()
    report = build_table(Sweep([4.76e-3], [3e-3], [0.3], scene=FAST), out, workers=1)
    assert report.complete and out.exists()
