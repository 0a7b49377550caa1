"""The Green's-function tier: the plate seen from the chain as one linear response, convolved.

The spectral-element plate is linear and starts at rest, and central differences are a linear
time-invariant recurrence, so the deflection under the chain after n steps of dt is a discrete
convolution of the contact force history with the plate's response to a unit force impulse:

    w_n = sum_{k < n} c_k g[n - k] (F_k - F_static),   c_0 = 1/2, c_k = 1 otherwise

where g[j] is the contact node's deflection j steps after a unit force acted for one step (the
first velocity-Verlet half kick weighs F_0 by one half). With the same mesh and the same dt this
reproduces the coupled ``sem`` run to round-off; the plate run behind g is done once per plate,
mesh, position, supports, material and step and then cached under a key of those.

The model layer does no file I/O: the cache is any object with ``load(key)`` and
``store(key, array)``, passed down from ``simulate(scene, greens_cache=...)``; without one,
:data:`PROCESS_CACHE` (a :class:`MemoryCache`) keeps responses for the process. The instrument
layer passes its disk cache or a per-task cache explicitly.
"""

from __future__ import annotations

import hashlib
import json
import threading
import time
from collections import OrderedDict
from functools import lru_cache
from typing import Protocol

import numpy as np
from numba import njit

from .chain import PK_BOT_F, chain_energy, record_into
from .jit_cache import source_digest
from .mindlin import MindlinPlate
from .record import ChainRecord
from .sem import ElasticPlate
from .sem_kernels import chain_start, chain_substeps
from .status import RUN_NONFINITE, RUN_OK, RUN_SHORT_RESPONSE

#: Bump when the meaning of a stored response changes (invalidates every cache entry).
#: 2: the force acts through a contact patch and g is the patch-weighted deflection; the key
#: holds the patch radius and the element edges (local refinement).
#: 3: the key holds the model's source digest (:func:`model_digest`): a response computed by
#: other code, even one that differs in the last bit, is never taken for this code's.
GREENS_VERSION = 3


@lru_cache(maxsize=1)
def model_digest() -> str:
    """The hash of the model package's source (:func:`.jit_cache.source_digest`): what computes a
    response. An update or an edit of the model makes every stored response another key."""
    return source_digest(("solitonde.model",))


class GreensCache(Protocol):
    """Where computed responses are kept."""

    def load(self, key: str) -> np.ndarray | None:
        """The stored response for ``key``, or None."""

    def store(self, key: str, response: np.ndarray) -> None:
        """Keep ``response`` under ``key`` (replacing a shorter one)."""


#: Default bound of a :class:`MemoryCache`: a long-running service sees a new response per plate,
#: position and step (up to tens of MB each), which an unbounded cache would keep forever.
MEMORY_CACHE_BYTES = 512 * 1024 * 1024


class MemoryCache:
    """In-memory cache (:data:`PROCESS_CACHE` is one), least recently used first out once its
    responses exceed ``max_bytes``; safe to share between threads."""

    def __init__(self, max_bytes: int = MEMORY_CACHE_BYTES) -> None:
        self._items: OrderedDict[str, np.ndarray] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()
        self.max_bytes = max_bytes

    def load(self, key: str) -> np.ndarray | None:
        with self._lock:
            found = self._items.get(key)
            if found is not None:
                self._items.move_to_end(key)
            return found

    def store(self, key: str, response: np.ndarray) -> None:
        array = np.array(response, dtype=float)
        with self._lock:
            kept = self._items.get(key)
            if kept is not None and kept.size >= array.size:  # a longer one serves both
                self._items.move_to_end(key)
                return
            old = self._items.pop(key, None)
            if old is not None:
                self._bytes -= old.nbytes
            self._items[key] = array
            self._bytes += array.nbytes
            while self._bytes > self.max_bytes and len(self._items) > 1:
                _, dropped = self._items.popitem(last=False)
                self._bytes -= dropped.nbytes

    def clear(self) -> None:
        with self._lock:
            self._items.clear()
            self._bytes = 0

    def __len__(self) -> int:
        """Responses held."""
        with self._lock:
            return len(self._items)


PROCESS_CACHE: GreensCache = MemoryCache()
"""The cache of a run that is given none: responses kept for the process. Never replaced; a
caller that wants another cache (a disk cache, one per table-build task) passes it."""


def response_key(plate: ElasticPlate | MindlinPlate, dt: float) -> str:
    """Hash of everything the response depends on: plate theory, mesh, position, patch, supports,
    material, dt."""
    mesh, mat = plate.mesh, plate.material
    edges = hashlib.sha256(
        np.concatenate((mesh.x_edges, mesh.y_edges, mesh.z_edges)).astype("<f8").tobytes()
    ).hexdigest()[:16]
    desc = {
        "contact_radius_m": float(mesh.contact_radius),
        "edges": edges,
        "version": GREENS_VERSION,
        "thickness_m": float(mesh.z_edges[-1]),
        "size_m": [float(mesh.x_edges[-1]), float(mesh.full_width)],
        "distance_to_support_m": float(mesh.contact_xy[0]),
        "elements": list(mesh.elements),
        "order": list(mesh.order),
        "symmetry": bool(mesh.symmetry),
        "supports": plate.supports,
        "material": [mat.youngs_modulus, mat.poisson_ratio, mat.density],
        "dt_s": float(dt),
        "code": model_digest(),
    }
    if isinstance(plate, MindlinPlate):  # named only for Mindlin: 3-D keys stay what they were
        desc["plate_theory"] = "mindlin"
    text = json.dumps(desc, sort_keys=True, separators=(",", ":"), default=repr)
    return hashlib.sha256(text.encode()).hexdigest()[:32]


def compute_response(plate: ElasticPlate | MindlinPlate, dt: float, n_steps: int) -> np.ndarray:
    """g[0..n_steps]: deflection under the chain (down, m) after a unit downward force for one step.

    Equivalently the patch-weighted vertical displacement (z up, :meth:`ElasticPlate.
    run_contact_load`) under a unit +z contact force (on a half model the mesh carries half).
    """
    if n_steps == 0:  # no step after the load: the plate is at rest
        return np.zeros(1)
    force = np.zeros(n_steps)
    force[0] = 1.0
    return plate.run_contact_load(force, dt)[0].copy()


def contact_response(
    plate: ElasticPlate | MindlinPlate, dt: float, n_steps: int,
    cache: GreensCache | None = None, spare: int = 0,
) -> tuple[np.ndarray, bool, float]:
    """The response g of at least ``n_steps + 1`` samples, from the cache when it holds one;
    computed, it runs ``spare`` steps longer (and is kept so), for runs that need a little
    more of the same plate's response.

    Returns (g, came from cache, seconds spent computing).
    """
    cache = PROCESS_CACHE if cache is None else cache
    key = response_key(plate, dt)
    stored = cache.load(key)
    if stored is not None and stored.size >= n_steps + 1:
        return np.ascontiguousarray(stored[: n_steps + 1]), True, 0.0
    start = time.perf_counter()
    g = compute_response(plate, dt, n_steps + spare)
    spent = time.perf_counter() - start
    cache.store(key, g)
    return g, False, spent


def stored_response(plate: ElasticPlate | MindlinPlate, dt: float,
                    cache: GreensCache | None = None) -> np.ndarray | None:
    """The response the cache holds for ``plate`` at step ``dt`` (whatever its length), or
    None: a run can start on it before it knows how much it needs (:func:`integrate_greens`
    says when it is too short)."""
    cache = PROCESS_CACHE if cache is None else cache
    stored = cache.load(response_key(plate, dt))
    return None if stored is None else np.ascontiguousarray(stored, dtype=float)


@njit(cache=True)
def first_load_step(rec: ChainRecord, h: float, r: int, n_sub: int, n_samples: int) -> int:
    """The first plate step at which the chain loads the plate: its bottom force departs from
    the static load beyond :func:`integrate_greens`' round-off tolerance (-1 if it never does
    within the run). Until then the plate stays at rest and the chain moves alone, so this
    runs the chain alone, on copies of its state, exactly as :func:`integrate_greens` does up
    to that step: the response is needed only for the steps after it."""
    u, v, pk = rec.u.copy(), rec.v.copy(), rec.pk.copy()
    n = u.size - 1
    inv_m, inv_m0 = 1.0 / rec.m, 1.0 / rec.m0
    dt = h / r
    f = np.empty(n)
    acc = np.empty(n + 1)
    vpc = np.empty(n + 1)
    tol = 1e-12 * rec.f_static
    f_bottom, power = chain_start(u, v, 0.0, rec.a_s, rec.a_0, rec.a_b, inv_m, inv_m0, rec.g,
                                  rec.tau, f, acc, vpc)
    if abs(0.5 * (f_bottom - rec.f_static)) > tol:
        return 0
    for step in range(n_sub * (n_samples - 1)):
        f_bottom, power, _ = chain_substeps(
            u, v, acc, f, vpc, 0.0, 0.0, r, dt, rec.a_s, rec.a_0, rec.a_b, inv_m, inv_m0, rec.g,
            rec.tau, rec.sensor, power, step * h, pk)
        if abs(f_bottom - rec.f_static) > tol:
            return step + 1
        if not np.isfinite(f_bottom):
            return step + 1  # the run itself stops here
    return -1


def response_steps(first: int, steps: int) -> tuple[int, int]:
    """(steps of response needed, spare steps to compute) for a run of ``steps`` plate steps
    whose chain first loads the plate at step ``first`` (:func:`first_load_step`): the force
    acts from then on, so the response is read up to ``steps - first`` steps after a load.
    Computed, it runs a quarter of the steps before the load longer, so that a run of the same
    plate whose load comes earlier finds it in the cache: a damped chain's viscous force reaches
    the plate first (by 1-2 % of the lead at the tables' dampings, 7-11 % at 1e-6 s)."""
    if first < 0:
        return 0, 0
    return steps - first, first // 4


@njit(cache=True)
def integrate_greens(
    rec: ChainRecord, h: float, r: int, n_sub: int, n_samples: int, response: np.ndarray
) -> tuple[int, int, float, float, float]:
    """Chain on a plate given by its contact response; the contract of ``boundary.dashpot_run``.

    The same scheme as the coupled ``sem`` driver (plate step ``h``, ``r`` chain steps per plate
    step, ``n_sub`` plate steps per sample), the plate's drift to step s + 1 being the convolution
    of the force history up to step s with ``response``. Terms before the first change of the
    bottom force (beyond round-off of the static load) are zero and skipped, so ``response``
    needs ``steps + 1 - first`` samples (``first``: that step, :func:`first_load_step`; one
    sample when the plate is never loaded); a shorter one stops the run at that step with
    ``RUN_SHORT_RESPONSE``. A longer one is read only that far: the run is the same, to the
    bit, as on exactly those samples. Returns (status, samples recorded, final w, work done on
    the plate J, dissipated energy J).
    """
    u, v, u0, m, g, a_s, a_b = rec.u, rec.v, rec.u0, rec.m, rec.g, rec.a_s, rec.a_b
    f_static, tau, sensor, pk = rec.f_static, rec.tau, rec.sensor, rec.pk
    n = u.size - 1
    inv_m = 1.0 / m
    m0, a_0 = rec.m0, rec.a_0
    inv_m0 = 1.0 / m0
    dt = h / r
    f = np.empty(n)
    acc = np.empty(n + 1)
    vpc = np.empty(n + 1)
    steps = n_sub * (n_samples - 1)
    if response.size < 1:
        return RUN_SHORT_RESPONSE, 0, 0.0, 0.0, 0.0
    length = 0  # the samples read, steps + 1 - first, once the first loaded step is known
    rev = np.empty(0)  # then the first ``length`` samples reversed: rev[length - 1 - j] = g[j]
    fdyn = np.zeros(steps + 1)
    tol = 1e-12 * f_static

    w = 0.0
    f_bottom, power = chain_start(u, v, w, a_s, a_0, a_b, inv_m, inv_m0, g, tau, f, acc, vpc)
    fdyn[0] = 0.5 * (f_bottom - f_static)
    first = -1
    if abs(fdyn[0]) > tol:
        first = 0
        length = steps + 1
        if response.size < length:
            return RUN_SHORT_RESPONSE, 0, 0.0, 0.0, 0.0
        rev = response[:length][::-1].copy()

    dissipated = 0.0
    plate_work = 0.0
    step = 0
    for k in range(n_samples):
        record_into(rec, k, f, w)
        rec.energy[k] = (chain_energy(u, v, u0, w, m, g, a_s, a_b, m0, a_0) + plate_work
                         + dissipated)
        if not np.isfinite(rec.samples[k]) or not np.isfinite(rec.energy[k]):
            return RUN_NONFINITE, k + 1, w, plate_work, dissipated
        if k == n_samples - 1:
            break
        for _ in range(n_sub):
            w_old = w
            f_old = f_bottom
            w = 0.0
            if first >= 0:
                # w_{s+1} = sum_{j=first..s} response[s+1-j] fdyn[j]
                off = length - 2 - step
                w = np.dot(rev[off + first: off + step + 1], fdyn[first: step + 1])
            f_bottom, power, lost = chain_substeps(
                u, v, acc, f, vpc, w_old, w, r, dt, a_s, a_0, a_b, inv_m, inv_m0, g, tau, sensor,
                power, step * h, pk,
            )
            dissipated += lost
            plate_work += 0.5 * (f_old + f_bottom) * (w - w_old)
            step += 1
            fdyn[step] = f_bottom - f_static
            if first < 0 and abs(fdyn[step]) > tol:
                first = step
                length = steps + 1 - first
                if response.size < length:
                    return RUN_SHORT_RESPONSE, k + 1, w, plate_work, dissipated
                rev = response[:length][::-1].copy()
    if not pk[PK_BOT_F] >= 0.0:
        return RUN_NONFINITE, n_samples, w, plate_work, dissipated
    return RUN_OK, n_samples, w, plate_work, dissipated
