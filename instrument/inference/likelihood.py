"""The inversion's likelihood over the fine (t, L) grid, for exactly the sphere sizes given.

Per cell, -2 log likelihood = chi^2 + log det C (+ the hidden sizes' bound terms), with C the
terms' covariance: diagonal (shot scatter, the table's interpolation error, the calibration) plus,
when the plate material has a spread, the rank-2 covariance ``U U^T`` it induces across every
term (instrument.inference.material_spread), applied with Woodbury's identity (:mod:`.woodbury`).

With a shared calibration (:func:`cell_likelihood`'s ``shared_calibration``) the calibration's
stated TOF offset uncertainty is left out of C and kept instead as the exact dependence of the
deviance on the offsets' errors ``eta`` (an error adds to the model TOF: the residual moves
linearly), ``chi^2(eta) = chi^2(0) - 2 b.eta + eta^T Q eta`` per cell, so that a plate's joint map
can draw one offset error for all its positions (instrument.inference.joint_map). The ARR
factor's uncertainty stays in C, per position.
"""

from __future__ import annotations

import functools
import math
import sys
import threading
from collections import OrderedDict
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, TypedDict

import numpy as np
from scipy.special import ndtr

from solitonde.instrument.inference.calibration import (
    Calibration,
    calibrated_table,
    calibration_along,
)
from solitonde.instrument.inference.fine_grid import FineGrid, fine_grid
from solitonde.instrument.inference.grid_threads import run_in_bands
from solitonde.instrument.inference.inversion_inputs import MIN_TOF_STD_S, FeatureSummary
from solitonde.instrument.inference.model_error import FLOOR_ARR_MAX, REFLECTION_D_OVER_T
from solitonde.instrument.inference.woodbury import UPPER, bilinear2, solve2
from solitonde.instrument.tables.table import ModelTable

LOG_BATCH = 8
"""Variances multiplied before one log. A variance lies between about 1e-19 s^2 (the TOF floor
over 1e5 shots) and 1e2 (an ARR scatter of 10, the most an input may state): a product of 8
stays between 1e-152 and 1e16, far from underflow and overflow."""


Term = tuple[np.ndarray, np.ndarray, Any, Any, Any, Any, "np.ndarray | None"]
"""One Gaussian term: the model and its variance per cell, the measured value, the calibration's
scale, the variance added (scatter, calibration), a relative variance on the model, and the
material's columns (None without a spread); the four middle ones numbers or rows over distance."""
# Placeholders the kernel neither reads nor writes: the material's arrays where there is no
# spread, Woodbury's determinant before the last terms.
_NO_U = np.zeros((2, 1, 1))
_NO_M = np.zeros((3, 1, 1))
_ONE = np.ones((1, 1))


@functools.lru_cache(maxsize=4)
def _zeros(shape: tuple[int, ...]) -> np.ndarray:
    """Zeros of ``shape``, shared: the hidden sizes' bound terms where there are none (never
    written: :meth:`Deviance.add_bound` makes a new sum)."""
    return np.zeros(shape)


def use_compiled() -> bool:
    """Whether the likelihood and the posterior take their compiled passes
    (:mod:`.likelihood_kernel`, :mod:`.posterior_kernel`): where numba is loaded already (the
    service, ``analyze``, the studies), they take a half to a third of an inversion's time. A
    process that would import numba for its one inversion (``solitonde invert``) spends half a
    second on the import, more than it saves, so there the numpy expressions run. Both give the
    same numbers to the bit (tests/instrument/test_likelihood_kernel.py)."""
    return "numba" in sys.modules


def per_distance(x: Any, n_l: int) -> np.ndarray:
    """A number, or a row over the grid's distance axis as :func:`calibration_along` gives it,
    as one contiguous value per distance column (what the compiled kernels take)."""
    out = np.empty(n_l)
    out[...] = x  # a row (1, n_l) fills it as it is, a number everywhere
    return out


def per_distance_rows(values: Sequence[Any], n_l: int) -> np.ndarray:
    """:func:`per_distance` of each of ``values``, stacked (one row per value)."""
    out = np.empty((len(values), n_l))
    for row, x in zip(out, values, strict=True):
        row[...] = x
    return out


class CellLikelihood(TypedDict):
    """The likelihood on every fine cell (:func:`cell_likelihood`)."""

    deviance: np.ndarray
    n_terms: int
    grid: FineGrid
    misfit: np.ndarray
    shared: list[tuple[float, str, float]]
    shared_b: np.ndarray
    shared_q: np.ndarray


@dataclass
class SharedError:
    """A calibration error kept out of C: its size's diameter, what it offsets, its sd, and per
    cell the linear (``b``) and quadratic (``q``) coefficients of the deviance in it, before the
    material's correction (``u_e``: ``U^T D^-1 e``, None without a material spread)."""

    diameter_m: float
    kind: str
    sd: float
    b: np.ndarray
    q: np.ndarray
    u_e: np.ndarray | None


@dataclass
class Deviance:
    """The likelihood's parts per cell, summed term by term over the sphere sizes.

    The log-variances are kept as one log of a running product, taken every :data:`LOG_BATCH`
    terms (a log over the grid costs as much as the rest of a term). ``penalty`` (the cells
    without features: inf) and, without hidden sizes, ``bound_terms`` are shared with other
    inversions and never written in place."""

    grids: list[FineGrid]
    n_terms: int
    misfit: np.ndarray
    bound_terms: np.ndarray
    logdet: np.ndarray
    det: np.ndarray
    penalty: np.ndarray
    bound_list: list[np.ndarray] = field(default_factory=list)
    terms: int = 0
    ur_sum: np.ndarray | None = None
    m_sum: np.ndarray | None = None
    """The three distinct entries of ``U^T D^-1 U`` (:data:`.woodbury.UPPER`) and ``U^T D^-1 r``,
    where the material has a spread."""
    shared: list[SharedError] = field(default_factory=list)
    shared_b: np.ndarray = field(default_factory=lambda: np.zeros(0))
    shared_q: np.ndarray = field(default_factory=lambda: np.zeros(0))
    pristine: bool = False
    """``misfit`` and ``det`` not yet filled: the compiled pass starts their sums itself."""
    m_det: np.ndarray | None = None
    """Where the compiled pass has applied Woodbury's correction: ``log det (I + M)`` per cell
    (already added to ``logdet``; the pass holds ``det (I + M)`` there until it takes the log)."""
    logged: int = 0
    """Terms whose variances' log is in ``logdet``."""
    chi2: np.ndarray | None = None
    """-2 log L per cell (:meth:`total`'s numbers), where the compiled pass added the last terms
    with ``total``; ``row_min`` each thickness row's least value, ``best_at`` the least cell's
    flat index, as ``np.argmin`` gives it."""
    row_min: np.ndarray | None = None
    best_at: int = -1

    @classmethod
    def empty(cls, grids: list[FineGrid], n_terms: int, penalty: np.ndarray,
              compiled: bool = False) -> Deviance:
        """No term added yet; ``penalty`` the seen sizes' summed penalty (:class:`StackCache`:
        shared, never written); ``compiled``: for :meth:`add_terms_compiled`, which fills the
        sums and the first log as it adds the first terms (:meth:`settle` fills them if it adds
        none)."""
        shape = grids[0].tof_s.shape
        new = np.empty if compiled else np.zeros
        return cls(grids, n_terms, misfit=new(shape), bound_terms=_zeros(shape),
                   logdet=new(shape), det=np.empty(shape) if compiled else np.ones(shape),
                   penalty=penalty, pristine=compiled)

    def settle(self) -> None:
        """Fill ``misfit`` (0), ``logdet`` (0) and ``det`` (1) if no compiled pass has started
        them yet, so that they hold the sums of the terms added so far: none."""
        if self.pristine:
            self.misfit.fill(0.0)
            self.logdet.fill(0.0)
            self.det.fill(1.0)
            self.pristine = False

    @property
    def shape(self) -> tuple[int, ...]:
        return self.misfit.shape

    def add_bound(self, term: np.ndarray) -> None:
        """A hidden size's bound term (a new sum: the empty one is shared)."""
        self.bound_terms = self.bound_terms + term
        self.bound_list.append(term)

    def add_term(self, r: np.ndarray, var: np.ndarray) -> None:
        """One Gaussian term: residual ``r`` (squared in place) over variance ``var`` (times its
        reciprocal, as the compiled pass divides once per cell and term)."""
        self.settle()
        r *= r
        r *= np.divide(1.0, var)
        self.misfit += r
        self.det *= var
        self._counted()

    def add_term_numpy(self, term: Term) -> None:
        """One Gaussian term with numpy operations (what :meth:`add_terms_compiled` does for
        every term in one pass)."""
        model, model_var, obs, scale, s2, rel2, u = term
        var, r = np.empty(self.shape), np.empty(self.shape)
        unscaled = _variance_residual(model, obs, scale, s2, model_var, rel2, var, r)
        if u is not None:
            self.add_material(u if unscaled else u * scale, var, r)
        self.add_term(r, var)

    def add_terms_compiled(self, terms: Sequence[Term], stacks: StackCache,
                           total: bool = False) -> None:
        """Gaussian terms, each batch of the variances' product in one compiled pass
        (:func:`.likelihood_kernel.add_terms`): what :meth:`add_term_numpy` does term by term,
        to the bit, without the residual and variance arrays (which only the shared errors
        need), in bands of thickness rows on two threads (:mod:`.grid_threads`). Each band
        takes its rows' logs too (numpy's, as :meth:`close_logs` takes them). With a material
        spread, the pass that adds the last terms applies Woodbury's correction too (``m_det``):
        ``terms`` are all the seen sizes' terms, and ``penalty`` is complete. With ``total``
        (``penalty`` and the hidden sizes' bounds complete too), that pass also sums each row's
        deviance into ``chi2`` and finds its least cell (``best_at``), while the row is still
        in the cache. ``stacks`` keeps each set of terms' arrays stacked, so a set asked for
        again is not copied again."""
        n_l = self.shape[1]
        while terms:
            room = LOG_BATCH - self.terms % LOG_BATCH  # the chunk ends at a log's batch
            chunk, terms = terms[:room], terms[room:]
            has_u = chunk[0][6] is not None  # a material spread gives every term its columns
            assert all((t[6] is not None) == has_u for t in chunk)
            fresh = self.pristine
            new = np.empty if fresh else np.zeros  # a fresh pass starts every sum itself
            if has_u and self.m_sum is None:
                self.m_sum = new((3, *self.shape))
            if has_u and self.ur_sum is None:
                self.ur_sum = new((2, *self.shape))
            models, model_vars, us = stacks.get(chunk)
            obs, scale, s2, rel2 = (per_distance_rows([t[k] for t in chunk], n_l)
                                    for k in (2, 3, 4, 5))
            unscaled = np.array([bool(np.ndim(t[3]) == 0 and t[3] == 1.0) for t in chunk])
            has_rel = np.array([bool(np.any(t[5])) for t in chunk])
            finish = has_u and not terms  # the last terms: Woodbury's correction follows
            if finish:
                self.m_det = np.empty(self.shape)
            counted = self.terms + len(chunk)
            log_now = counted % LOG_BATCH == 0 or not terms
            summed = total and not terms
            if summed:
                self.chi2, self.row_min = np.empty(self.shape), np.empty(self.shape[0])
            args = (models, model_vars, us, obs, scale, s2, rel2, unscaled, has_rel, has_u,
                    fresh, self.misfit, self.det, _NO_M if self.m_sum is None else self.m_sum,
                    _NO_U if self.ur_sum is None else self.ur_sum, self.penalty,
                    _ONE if self.m_det is None else self.m_det, finish)
            bests: dict[int, int] = {}
            run_in_bands(self._band, self.shape[0], args, log_now, counted, finish, summed,
                         bests)
            self.pristine = False
            self.terms = counted
            if log_now:
                self.logged = counted
            if counted % LOG_BATCH == 0:
                self.det.fill(1.0)
            if summed:
                assert self.chi2 is not None
                self.best_at = _first_least(self.chi2, [bests[k] for k in sorted(bests)])

    def _band(self, args: tuple[Any, ...], log_now: bool, counted: int, finish: bool,
              summed: bool, bests: dict[int, int], start: int, stop: int) -> None:
        """One band of :meth:`add_terms_compiled`'s pass, rows ``start..stop-1``: the terms
        (``args``: the kernel's), then with ``log_now`` the log of the variances' product
        (``counted`` terms in it), with ``finish`` Woodbury's log-determinant, and with
        ``summed`` the deviance and its least cell (into ``bests``, by the band's first row)."""
        from solitonde.instrument.inference.likelihood_kernel import add_terms
        from solitonde.instrument.inference.posterior_kernel import total_and_best

        kernel: Callable[..., None] = add_terms  # the kernel's arguments, then the band's rows
        kernel(*args, start, stop)
        if log_now:
            self._log_rows(start, stop, counted)
        if finish:
            assert self.m_det is not None
            m_det = self.m_det[start:stop]
            self.logdet[start:stop] += np.log(m_det, out=m_det)
        if summed:
            assert self.chi2 is not None and self.row_min is not None
            bests[start] = total_and_best(self.misfit, self.logdet, self.penalty,
                                          self.bound_terms, self.chi2, self.row_min, start, stop)

    def _counted(self) -> None:
        """One more term in the variances' product: its log taken every :data:`LOG_BATCH`."""
        self.terms += 1
        if self.terms % LOG_BATCH == 0:
            self._log_rows(0, self.shape[0], self.terms)
            self.logged = self.terms
            self.det.fill(1.0)

    def _log_rows(self, start: int, stop: int, terms: int) -> None:
        """The log of the variances' product (``terms`` counted) added to ``logdet`` on rows
        ``start..stop-1``; the first one written in its place (0 + x is x: one pass over the
        grid less)."""
        rows = slice(start, stop)
        if terms > LOG_BATCH:
            self.logdet[rows] += np.log(self.det[rows])
        else:
            np.log(self.det[rows], out=self.logdet[rows])

    def add_material(self, u: np.ndarray, var: np.ndarray, r: np.ndarray) -> np.ndarray:
        """One term's share of ``U^T D^-1 r`` and ``U^T D^-1 U``; returns ``U^T D^-1`` (per
        component) for the shared errors."""
        u_over = u * np.divide(1.0, var)
        ur = u_over * r
        self.ur_sum = ur if self.ur_sum is None else self.ur_sum + ur
        if self.m_sum is None:
            self.m_sum = np.zeros((3, *self.shape))
        for n_e, (a, b) in enumerate(UPPER):
            self.m_sum[n_e] += u_over[a] * u[b]
        return u_over

    def close_logs(self) -> None:
        """The log of the product left over from the last batch."""
        if self.terms % LOG_BATCH and self.logged < self.terms:
            self._log_rows(0, self.shape[0], self.terms)
            self.logged = self.terms

    def total(self) -> np.ndarray:
        """-2 log L per cell: misfit, log-determinant, the cells without features (inf), and the
        hidden sizes' bounds."""
        return self.misfit + self.logdet + self.penalty + self.bound_terms

    def bound_misfit(self, at: tuple[Any, ...] | None = None) -> Any:
        """The hidden sizes' misfit: -2 log of each one's likelihood against an ARR at the bound
        itself (1/2), about z^2 once the model's reflection clearly exceeds the bound, 0 below it;
        over the grid, or at the cell ``at``."""
        if at is None:
            return sum((np.maximum(b - 2.0 * math.log(2.0), 0.0) for b in self.bound_list),
                       np.zeros(self.shape))
        return sum(max(0.0, float(b[at]) - 2.0 * math.log(2.0)) for b in self.bound_list)


def _first_least(values: np.ndarray, candidates: list[int]) -> int:
    """Of the bands' least cells (flat indices, in row order), the one ``np.argmin`` of the
    whole ``values`` gives: the first NaN, else the first of the least values."""
    at, best = -1, math.inf
    for k in candidates:
        v = values.flat[k]
        if at < 0 or v < best or (v != v and best == best):
            at, best = k, v
    return at


def _single(values: np.ndarray) -> np.ndarray:
    """``values`` as float32, which must hold them exactly (they were rounded where made)."""
    out = values.astype(np.float32)
    if not np.array_equal(out, values, equal_nan=True):
        raise ValueError("a term's variances or material columns are not single-precision "
                         "values: round them where they are made (model_error.single_precision)")
    return out


STACKS_KEPT = 4
"""Sets of terms whose stacked arrays a table keeps (:class:`StackCache`)."""
_Stacked = tuple[list[np.ndarray], tuple[np.ndarray, ...]]
"""A :class:`StackCache` entry: the terms' own arrays (held, so their ids stay theirs) and the
stacks."""


class StackCache:
    """Terms' per-cell arrays stacked along a first axis, as :meth:`Deviance.add_terms_compiled`
    passes them, kept for the last :data:`STACKS_KEPT` sets of terms of one table (the service
    inverts the same sizes again and again; a stack of three sizes' terms is about 14 MB), and
    likewise each set of sizes' summed penalty. A set is known by the identity of its arrays,
    which the entry holds, so an id is never reused while its entry lives. Safe for the
    service's threads."""

    def __init__(self) -> None:
        self.kept: OrderedDict[tuple[int, ...], _Stacked] = OrderedDict()
        self.sums: OrderedDict[tuple[Any, ...], tuple[list[np.ndarray], np.ndarray]] = (
            OrderedDict())
        self.lock = threading.Lock()

    def get(self, terms: Sequence[Term]) -> tuple[np.ndarray, ...]:
        """(models, model variances, material columns) of ``terms``, each stacked; the columns
        a placeholder without a material spread."""
        arrays = [a for t in terms for a in (t[0], t[1], t[6]) if a is not None]
        key = tuple(id(a) for a in arrays)
        with self.lock:
            hit = self.kept.get(key)
            if hit is not None:
                self.kept.move_to_end(key)  # the newest last
        if hit is None:
            # the variances and columns hold single-precision values (model_error's
            # single_precision): as float32 the pass streams a third fewer bytes, the same numbers
            columns = [t[6] for t in terms if t[6] is not None]
            us = (_single(np.stack(columns)) if columns
                  else np.zeros((len(terms), 2, 1, 1), dtype=np.float32))
            hit = (arrays, (np.stack([t[0] for t in terms]),
                            _single(np.stack([t[1] for t in terms])), us))
            with self.lock:
                self.kept[key] = hit
                while len(self.kept) > STACKS_KEPT:
                    self.kept.popitem(last=False)
        return hit[1]

    def penalty(self, grids: Sequence[FineGrid], shape: tuple[int, ...]) -> np.ndarray:
        """The sum of ``grids``' penalties (inf on a cell where a size has no features), added
        in their order to zeros of ``shape``; shared: never written."""
        arrays = [g.penalty for g in grids]
        key = (shape, *(id(a) for a in arrays))
        with self.lock:
            hit = self.sums.get(key)
            if hit is not None:
                self.sums.move_to_end(key)
                return hit[1]
        total = np.zeros(shape)
        for a in arrays:
            total += a
        with self.lock:
            self.sums[key] = (arrays, total)
            while len(self.sums) > STACKS_KEPT:
                self.sums.popitem(last=False)
        return total

    @staticmethod
    def of(table: ModelTable) -> StackCache:
        """The table's own cache."""
        cache: StackCache = table._cache.setdefault("term_stacks", StackCache())
        return cache


def _hidden_term(item: FeatureSummary, g: FineGrid, cal: Calibration | None) -> np.ndarray:
    """-2 log likelihood of a size without a reflection: the model's ARR (where it has a
    reflection) must lie under the bound; cells where the model itself detects none agree."""
    factor, offset, f_std, o_std = calibration_along(cal, g.diameter_m, g.distance_m[None, :])
    sd = np.sqrt(item.bound_sigma() ** 2 + factor**2 * g.model_arr_var
                 + (f_std * g.arr_reflecting) ** 2)
    z = (item.arr_upper_bound - factor * g.arr_reflecting) / sd
    under = ndtr(z)
    if item.tof_window_s is not None:
        # a reflection later than the records' window would not have been seen: the bound holds
        # only with the probability that the model's arrives within it
        tof_sd = np.sqrt(g.model_tof_var + o_std**2 + MIN_TOF_STD_S**2)
        p_in = ndtr((item.tof_window_s - offset - np.nan_to_num(g.tof_s)) / tof_sd)
        under = p_in * under + (1.0 - p_in)
    like = (1.0 - g.reflect_weight) + g.reflect_weight * under
    return -2.0 * np.log(np.maximum(like, 1e-300))


def _variance_residual(model: np.ndarray, obs: Any, scale: Any, s2: Any, model_var: np.ndarray,
                       rel2: Any, var: np.ndarray, r: np.ndarray) -> bool:
    """A term's variance and residual, into ``var`` and ``r``: the calibration's own uncertainty
    with them (the offset adds, the factor scales the model ARR). Whether the model is unscaled."""
    unscaled = bool(np.ndim(scale) == 0 and scale == 1.0)
    if unscaled:
        np.add(model_var, s2, out=var)
        np.subtract(obs, model, out=r)
    else:
        np.multiply(model_var, scale * scale, out=var)
        var += s2
        np.multiply(model, -scale, out=r)
        r += obs
    if np.any(rel2):
        rel = np.multiply(model, model)
        rel *= rel2
        var += rel
    return unscaled


def _shared_offset(g: FineGrid, o_std: Any, r: np.ndarray, var: np.ndarray,
                   u_over: np.ndarray | None) -> SharedError:
    """The TOF offset's error kept out of C: the TOF residual moves by -1 per unit error (where
    the offset's sd follows distance: one error, scaled to each distance's sd)."""
    shape = r.shape
    sd = float(np.max(o_std))
    e = np.ones(shape) if np.ndim(o_std) == 0 else np.broadcast_to(o_std / sd, shape)
    return SharedError(g.diameter_m, "tof_offset_s", sd, e * r / var, e * e / var,
                       None if u_over is None else u_over * e)


def _seen_terms(table: ModelTable, item: FeatureSummary, g: FineGrid, cal: Calibration | None,
                spread: Mapping[str, float] | None, share: bool) -> list[Term]:
    """A seen size's TOF and ARR terms (with ``share``, the TOF offset's uncertainty left out)."""
    from solitonde.instrument.inference.material_spread import sensitivity

    # numbers, or rows over the grid's distance axis where the calibration follows distance
    factor, offset, f_std, o_std = calibration_along(cal, g.diameter_m, g.distance_m[None, :])
    s_tof, s_arr = item.sigmas()
    u_pair = (sensitivity(table, g, spread, (REFLECTION_D_OVER_T, FLOOR_ARR_MAX)) if spread
              else None)
    assert item.tof_s is not None  # seen
    return [(g.tof_s, g.model_tof_var, item.tof_s - offset, 1.0,
             s_tof**2 + (0.0 if share else o_std**2), 0.0, None if u_pair is None else u_pair[0]),
            (g.arr, g.model_arr_var, item.arr, factor, s_arr**2, f_std**2,
             None if u_pair is None else u_pair[1])]


def _add_shared(dev: Deviance, terms: list[Term], g: FineGrid, cal: Calibration | None
                ) -> None:
    """A seen size's two terms term by term, keeping the TOF offset's error out of C as a shared
    error."""
    o_std = calibration_along(cal, g.diameter_m, g.distance_m[None, :])[3]
    var, r = np.empty(dev.shape), np.empty(dev.shape)
    for k, (model, model_var, obs, scale, s2, rel2, u) in enumerate(terms):
        unscaled = _variance_residual(model, obs, scale, s2, model_var, rel2, var, r)
        u_over = None
        if u is not None:
            u_over = dev.add_material(u if unscaled else u * scale, var, r)
        if k == 0 and np.any(o_std > 0):
            dev.shared.append(_shared_offset(g, o_std, r, var, u_over))
        dev.add_term(r, var)


def _apply_woodbury(dev: Deviance) -> None:
    """The material's rank-2 covariance and the shared errors' coefficients.

    Woodbury: C = D + U U^T  ->  chi^2 -= b^T M^-1 b, log det C += log det M, with
    M = I + U^T D^-1 U and b = U^T D^-1 r (2 x 2 per cell, solved in closed form); the shared
    errors' coefficients go through the same C^-1 (D^-1 - D^-1 U M^-1 U^T D^-1)."""
    shared = dev.shared
    dev.shared_b = np.array([e.b for e in shared]).reshape(len(shared), *dev.shape)
    dev.shared_q = np.zeros((len(shared), len(shared), *dev.shape))
    for n_e, err in enumerate(shared):
        dev.shared_q[n_e, n_e] = err.q
    if dev.m_sum is None or dev.ur_sum is None:
        return
    if dev.m_det is not None:  # the compiled pass applied it; the numbers are the same
        return
    quad, logdet_m = solve2(dev.m_sum, dev.ur_sum)
    ok = np.isfinite(dev.penalty)
    dev.misfit[ok] -= quad[ok]
    dev.logdet[ok] += logdet_m[ok]
    u_es = [e.u_e for e in shared]  # every term carries the material's columns here
    for n_e, u_e in enumerate(u_es):
        assert u_e is not None
        dev.shared_b[n_e] -= bilinear2(dev.m_sum, u_e, dev.ur_sum)
        for n_f, u_f in enumerate(u_es):
            assert u_f is not None
            dev.shared_q[n_e, n_f] -= bilinear2(dev.m_sum, u_e, u_f)


def deviance(table: ModelTable, items: list[FeatureSummary], cal: Calibration | None,
             spread: Mapping[str, float] | None, shared_calibration: bool = False) -> Deviance:
    """The likelihood's parts on the fine grid of the table read at the chain's calibration
    (its fitted damping, if it has one), for exactly ``items``."""
    table = calibrated_table(table, cal)
    grids = [fine_grid(table, table.diameter_index(i.diameter_m)) for i in items]
    n_terms = 2 * sum(not i.hidden for i in items) + sum(i.hidden for i in items)
    compiled = use_compiled() and not shared_calibration
    stacks = StackCache.of(table)
    penalty = stacks.penalty([g for i, g in zip(items, grids, strict=True) if not i.hidden],
                             grids[0].tof_s.shape)
    dev = Deviance.empty(grids, n_terms, penalty, compiled)
    seen: list[Term] = []
    for item, g in zip(items, grids, strict=True):
        if item.hidden:
            dev.add_bound(_hidden_term(item, g, cal))
            continue
        terms = _seen_terms(table, item, g, cal, spread, shared_calibration)
        if shared_calibration:
            _add_shared(dev, terms, g, cal)
        elif compiled:
            seen += terms
        else:
            for term in terms:
                dev.add_term_numpy(term)
    if seen:  # every size's terms in one pass, the deviance summed as it ends
        dev.add_terms_compiled(seen, stacks, total=True)
    dev.settle()
    dev.close_logs()
    _apply_woodbury(dev)
    return dev


def cell_likelihood(table: ModelTable, inputs: Sequence[FeatureSummary | Mapping[str, Any]],
                    calibration: Calibration | Mapping[str, Any] | None = None, *,
                    material_spread: Mapping[str, float] | None = None,
                    shared_calibration: bool = False) -> CellLikelihood:
    """The likelihood :func:`~.inversion.invert` puts on every fine (t, L) cell for exactly these
    sphere sizes (no size left out), for a plate's joint map (instrument.inference.joint_map): one
    likelihood, not a second one. ``deviance`` is -2 log L (inf where the model has no
    reflection), ``misfit`` the chi^2 that ``fit`` reports, ``grid`` the first size's
    :class:`~.fine_grid.FineGrid` (axes and prior weights), ``n_terms`` the terms counted.

    ``shared_calibration``: the TOF offsets' uncertainty is not in ``deviance`` and ``misfit``
    (they hold at the stated offsets); instead ``shared`` lists the errors
    ``(diameter_m, "tof_offset_s", sd)`` with a stated sd, and
    ``shared_b`` (errors, t, L) and ``shared_q`` (errors, errors, t, L) give the deviance at
    errors ``eta``: ``deviance - 2 b.eta + eta^T Q eta`` (likewise ``misfit``)."""
    from solitonde.instrument.inference.material_spread import spread_of
    from solitonde.instrument.inference.shot_scatter import fill as fill_scatter
    from solitonde.instrument.inference.shot_scatter import none_stated

    spread = dict(spread_of(table) if material_spread is None else material_spread)
    cal = Calibration.from_any(calibration)
    items, _ = fill_scatter([FeatureSummary.from_any(i) for i in inputs],
                            cal.shot_scatter if cal else none_stated)
    dev = deviance(table, items, cal, spread, shared_calibration)
    return CellLikelihood(
        deviance=dev.total(), n_terms=dev.n_terms, grid=dev.grids[0],
        misfit=dev.misfit + dev.bound_misfit(),
        shared=[(float(e.diameter_m), str(e.kind), float(e.sd)) for e in dev.shared],
        shared_b=dev.shared_b, shared_q=dev.shared_q)
