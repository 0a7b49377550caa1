"""Many scenes at once, in parallel over the cores (for the model table and parameter studies).

Scenes are independent, so they are spread over worker processes (each runs the compiled chain
single-threaded; numba's on-disk cache means a worker compiles nothing that was compiled before).
Scenes travel as plain dicts and come back as :class:`SimulationResult`; small chunks keep the
cores busy when run times differ by orders of magnitude (D/t and N change the cost).
"""

from __future__ import annotations

import itertools
import multiprocessing
import os
from collections.abc import Iterable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any

from .errors import SceneError, SimulationError
from .scene import Scene, scene_from_dict
from .simulate import SimulationResult, simulate


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


def _run_chunk(
    payload: list[tuple[dict[str, Any], dict[str, Any]]],
) -> list[SimulationResult | Exception]:
    out: list[SimulationResult | Exception] = []
    for scene_dict, options in payload:
        try:
            out.append(simulate(scene_from_dict(scene_dict), **options))
        except (SceneError, SimulationError) as exc:
            out.append(exc)
    return out


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
    **options: Any,
) -> list[SimulationResult | Exception]:
    """Simulate many scenes in parallel; results come back in input order.

    Parameters
    ----------
    scenes: the scenes (e.g. from :func:`scene_grid`).
    workers: worker processes (default: the usable cores); 1 runs in this process.
    chunk_size: scenes per task (default: about 8 tasks per worker).
    raise_errors: raise the first SceneError/SimulationError; if False, the failed scene's slot
        holds the exception instead and the other scenes still run.
    options: passed to :func:`~solitonde.model.simulate.simulate` (``max_steps`` etc.).
    """
    scene_list = list(scenes)
    workers = default_workers() if workers is None else int(workers)
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    payload = [(s.to_dict_explicit(), options) for s in scene_list]
    if not payload:
        return []
    if workers == 1 or len(payload) == 1:
        results = _run_chunk(payload)
    else:
        size = chunk_size or max(1, len(payload) // (8 * workers))
        chunks = [payload[i:i + size] for i in range(0, len(payload), size)]
        # fork: workers inherit the imported, compiled modules (no per-worker start-up import).
        context = multiprocessing.get_context("fork")
        with ProcessPoolExecutor(max_workers=min(workers, len(chunks)), mp_context=context) as pool:
            results = [r for chunk in pool.map(_run_chunk, chunks) for r in chunk]
    if raise_errors:
        for r in results:
            if isinstance(r, Exception):
                raise r
    return results
