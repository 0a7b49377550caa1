"""Many scenes at once, in parallel over the cores (for the model table and parameter studies).

Scenes are independent. Two ways to spread them over the cores, picked per call:

``threads``
    For scenes whose plate model runs in a compiled driver that releases the GIL (``rigid``,
    ``halfspace``, ``infinite``): a thread pool in this process. The Python part of a run (scene
    set-up, result assembly, tens of microseconds) takes the GIL, the integration (milliseconds)
    runs in parallel. Nothing is pickled, nothing is started, nothing is compiled twice.
``processes``
    For everything else (``sem``, ``greens``, whose runs do Python and BLAS work per plate): a
    forked process pool. The parent compiles (or loads from numba's cache) the chain kernels
    before forking so that workers inherit them warm, workers run single-threaded (numba and
    BLAS threads capped at 1: one run per core), scenes travel as plain dicts in chunks and
    results come back without their scene (the parent re-attaches its own).

``backend="auto"`` picks threads when every scene resolves to a GIL-free plate model.
"""

from __future__ import annotations

import contextlib
import itertools
import multiprocessing
import os
from collections.abc import Iterable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from dataclasses import replace
from typing import Any, Literal

from .errors import SceneError, SimulationError
from .scene import Scene, scene_from_dict
from .simulate import SimulationResult, simulate
from .tiers import resolve_plate_model

#: Plate models whose compiled driver releases the GIL (``nogil``), so that threads run in parallel.
GIL_FREE_PLATE_MODELS = frozenset({"rigid", "halfspace", "infinite"})


def scene_grid(
    base: Scene | Mapping[str, Any] | None, axes: Mapping[str, Sequence[Any]]
) -> list[Scene]:
    """Every combination of the dotted-key values in ``axes`` applied to ``base``.

    ``scene_grid(None, {"chain.diameter": [4.76e-3, 9.53e-3], "plate.thickness": [2.29e-3]})``
    gives two scenes; the last key varies fastest.
    """
    start = base if isinstance(base, Scene) else scene_from_dict(dict(base or {}))
    keys = list(axes)
    for key in keys:
        if isinstance(axes[key], str | bytes) or not isinstance(axes[key], Iterable):
            raise SceneError(key, "a grid axis needs a list of values", allowed="e.g. [1e-3, 2e-3]")
    return [start.with_overrides(dict(zip(keys, combo, strict=True)))
            for combo in itertools.product(*(list(axes[k]) for k in keys))]


def _run_one(scene: Scene, options: dict[str, Any]) -> SimulationResult | Exception:
    try:
        return simulate(scene, **options)
    except (SceneError, SimulationError) as exc:
        return exc


def _run_chunk(
    payload: list[tuple[dict[str, Any], dict[str, Any]]],
) -> list[SimulationResult | Exception]:
    """Worker side of the process backend: results without their scene (the parent has it)."""
    out: list[SimulationResult | Exception] = []
    for scene_dict, options in payload:
        r = _run_one(scene_from_dict(scene_dict), options)
        # the parent puts the scene back (it holds it): only this crossing carries None
        out.append(replace(r, scene=None) if isinstance(r, SimulationResult)  # type: ignore[arg-type]
                   else r)
    return out


def _single_threaded_worker() -> None:
    """Process-pool initializer: one run per core, so no thread pools inside a worker."""
    try:
        import numba

        numba.set_num_threads(1)
    except (ImportError, ValueError):  # pragma: no cover - numba always present in practice
        pass
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(1)
    except ImportError:  # pragma: no cover
        pass


def _warm_up(scene: Scene) -> None:
    """Compile (or load from cache) the chain kernels once, in this process, with a tiny run.

    A plate model with set-up work of its own (sem, greens) is swapped for the infinite plate:
    only the compiled chain is warmed here.
    """
    overrides: dict[str, Any] = {"output.duration": 1e-6, "output.traces": False}
    if resolve_plate_model(scene)[0] not in GIL_FREE_PLATE_MODELS:
        overrides["effects.plate_model"] = "infinite"
    with contextlib.suppress(SceneError, SimulationError):
        simulate(scene.with_overrides(overrides))


def default_workers() -> int:
    """Cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def simulate_many(
    scenes: Iterable[Scene],
    workers: int | None = None,
    *,
    chunk_size: int | None = None,
    raise_errors: bool = True,
    backend: Literal["auto", "threads", "processes"] = "auto",
    **options: Any,
) -> list[SimulationResult | Exception]:
    """Simulate many scenes in parallel; results come back in input order.

    Parameters
    ----------
    scenes: the scenes (e.g. from :func:`scene_grid`).
    workers: threads or processes (default: the usable cores); 1 runs in this thread.
    chunk_size: scenes per process-pool task (default: about 8 tasks per worker).
    raise_errors: raise the first SceneError/SimulationError; if False, the failed scene's slot
        holds the exception instead and the other scenes still run.
    backend: ``threads``, ``processes`` or ``auto`` (threads when every scene's plate model is in
        :data:`GIL_FREE_PLATE_MODELS`); see the module docstring.
    options: passed to :func:`~solitonde.model.simulate.simulate` (``max_steps`` etc.).
    """
    scene_list = list(scenes)
    workers = default_workers() if workers is None else int(workers)
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if chunk_size is not None and int(chunk_size) < 1:
        raise ValueError(f"chunk_size must be >= 1 or None, got {chunk_size}")
    if backend not in ("auto", "threads", "processes"):
        raise ValueError(f"backend must be 'auto', 'threads' or 'processes', got {backend!r}")
    if not scene_list:
        return []
    if workers == 1 or len(scene_list) == 1:
        results = [_run_one(s, options) for s in scene_list]
    else:
        if backend == "auto":
            gil_free = all(resolve_plate_model(s)[0] in GIL_FREE_PLATE_MODELS for s in scene_list)
            backend = "threads" if gil_free else "processes"
        _warm_up(scene_list[0])
        if backend == "threads":
            with ThreadPoolExecutor(max_workers=min(workers, len(scene_list))) as pool:
                results = list(pool.map(lambda s: _run_one(s, options), scene_list))
        else:
            results = _run_processes(scene_list, workers, chunk_size, options)
    if raise_errors:
        for r in results:
            if isinstance(r, Exception):
                raise r
    return results


def _run_processes(
    scene_list: list[Scene], workers: int, chunk_size: int | None, options: dict[str, Any]
) -> list[SimulationResult | Exception]:
    payload = [(s.to_dict_explicit(), options) for s in scene_list]
    size = chunk_size or max(1, len(payload) // (8 * workers))
    chunks = [payload[i:i + size] for i in range(0, len(payload), size)]
    # fork: workers inherit the imported modules and the kernels _warm_up compiled.
    context = multiprocessing.get_context("fork")
    with ProcessPoolExecutor(max_workers=min(workers, len(chunks)), mp_context=context,
                             initializer=_single_threaded_worker) as pool:
        flat = [r for chunk in pool.map(_run_chunk, chunks) for r in chunk]
    return [replace(r, scene=scene) if isinstance(r, SimulationResult) else r
            for scene, r in zip(scene_list, flat, strict=True)]
