"""From the likelihood on the fine grid to an answer: the check that some table point explains the
measurement, the posterior (the likelihood times the prior mass of each cell, uniform in log t
and in L), each parameter's summary (:mod:`.marginals`) checked against the thickness-distance
ridge (:mod:`.ridge`), and what the adequacy check reads of the posterior."""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy.stats import chi2 as chi2_dist

from solitonde.instrument.inference import ridge
from solitonde.instrument.inference.calibration import Calibration, calibration_along
from solitonde.instrument.inference.estimate import Estimate, out_of_range, second_reading
from solitonde.instrument.inference.fine_grid import FineGrid
from solitonde.instrument.inference.inversion_inputs import FeatureSummary
from solitonde.instrument.inference.likelihood import Deviance, per_distance, use_compiled
from solitonde.instrument.inference.marginals import summarise_marginal
from solitonde.instrument.inference.woodbury import material_shift, weighted_sum

OUT_OF_RANGE_TAIL = 1e-6
"""Tail probability of the best chi^2 beyond which no table point explains the data."""
MIN_FLOOR_MASS = 0.1
"""Posterior mean weight on floor nodes above which the adequacy check asks whether a size's
features are explained without the floor's looseness (instrument.inference.adequacy)."""


@functools.lru_cache(maxsize=8)
def _chi2_limit_at(n_terms: int, tail: float) -> float:
    return float(chi2_dist.isf(tail, n_terms))


@functools.lru_cache(maxsize=64)
def _chi2_limit(n_terms: int) -> float:
    """The chi^2 beyond which no table point explains ``n_terms`` terms (scipy's isf costs a
    quarter of a millisecond, an eighth of an inversion)."""
    return float(chi2_dist.isf(OUT_OF_RANGE_TAIL, n_terms))


def _posterior(chi2: np.ndarray, best: float, g0: FineGrid
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The normalised posterior on the grid (in ``chi2``'s own memory), the profile likelihood
    of each parameter (the best over the other, before the prior), and the cells with one."""
    chi2 -= best
    finite = np.isfinite(chi2)
    chi2 *= -0.5
    post = np.exp(chi2, out=chi2)
    profile_t, profile_l = post.max(axis=1), post.max(axis=0)
    post *= g0.weight_t[:, None]  # prior mass of each cell: uniform in log t and in L
    post *= g0.weight_l[None, :]
    post /= post.sum()
    return post, profile_t, profile_l, finite


def _posterior_compiled(chi2: np.ndarray, best: float, g0: FineGrid
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_posterior` to the bit in three compiled passes (:mod:`.posterior_kernel`), exp
    taken only where it is not exactly 0; ``chi2`` is left holding the deviance over its
    minimum (what p_D averages) and the posterior gets its own memory."""
    from solitonde.instrument.inference.posterior_kernel import exponents, weigh

    finite = np.empty(chi2.shape, dtype=bool)
    cells, x = np.empty(chi2.size, dtype=np.intp), np.empty(chi2.size)
    count = exponents(chi2, best, finite, cells, x)
    like = np.exp(x[:count], out=x[:count])
    post = np.empty(chi2.shape)
    profile_t, profile_l = np.empty(chi2.shape[0]), np.empty(chi2.shape[1])
    weigh(cells[:count], like, g0.weight_t, g0.weight_l, post, profile_t, profile_l)
    post /= post.sum()
    return post, profile_t, profile_l, finite


def _estimate(post: np.ndarray, profile_t: np.ndarray, profile_l: np.ndarray, g0: FineGrid,
              items: list[FeatureSummary], cal: Calibration | None, fit: float, n_terms: int
              ) -> Estimate:
    """Each parameter's summary of the posterior, the thickness's checked against the ridge."""
    lower_physical = bool(g0.distance_m[0] <= 0.0)
    thickness = summarise_marginal(np.log(g0.thickness_m), post.sum(axis=1), g0.weight_t,
                                   lower_physical=False, transform=np.exp, profile=profile_t)
    distance = summarise_marginal(g0.distance_m, post.sum(axis=0), g0.weight_l,
                                  lower_physical=lower_physical, profile=profile_l)
    marginal = thickness
    thickness, distance, readings = ridge.resolve(
        thickness, distance, g0.thickness_m, g0.distance_m, post, g0.weight_t, g0.weight_l,
        profile_t, lower_physical=lower_physical)
    est = Estimate(thickness, distance, items, cal, fit, n_terms, readings=readings)
    if thickness.status == marginal.status and thickness.ci95 != marginal.ci95:
        est.extra["ridge_widened"] = {"marginal_ci95": list(marginal.ci95 or ()),
                                      "ci95": list(thickness.ci95 or ())}
    if len(readings) > 1:
        est.extra["other_reading"] = second_reading(readings, g0.thickness_m)
    return est


def _strict_explained(est: Estimate, dev: Deviance, post: np.ndarray,
                      items: list[FeatureSummary], cal: Calibration | None) -> dict[float, float]:
    """Per seen size resting on floor cells: the posterior probability that its TOF and ARR are
    explained without the floor nodes' looseness (their chi^2 within the 1e-3 tail)."""
    out: dict[float, float] = {}
    for item, g in zip(items, dev.grids, strict=True):
        if item.hidden or est.extra["floor_mass"][item.diameter_m] < MIN_FLOOR_MASS:
            continue
        factor, offset, f_std, o_std = calibration_along(cal, g.diameter_m, g.distance_m[None, :])
        s_tof, s_arr = item.sigmas()
        assert item.tof_s is not None and item.arr is not None  # seen
        if not use_compiled():
            strict = ((item.tof_s - offset - g.tof_s) ** 2
                      / (s_tof**2 + o_std**2 + g.model_tof_var_strict)
                      + (item.arr - factor * g.arr) ** 2
                      / (s_arr**2 + factor**2 * g.model_arr_var_strict + (f_std * g.arr) ** 2))
            out[item.diameter_m] = float(np.sum(post[strict <= _chi2_limit_at(2, 1e-3)]))
            continue
        from solitonde.instrument.inference.posterior_kernel import strict_mask

        n_l = g.distance_m.size
        explained = strict_mask(g.tof_s, g.arr, g.model_tof_var_strict, g.model_arr_var_strict,
                                per_distance(item.tof_s - offset, n_l),
                                per_distance(s_tof**2 + o_std**2, n_l), item.arr,
                                per_distance(factor, n_l), per_distance(f_std, n_l), s_arr**2,
                                _chi2_limit_at(2, 1e-3))
        out[item.diameter_m] = float(np.sum(post[explained]))
    return out


def _adequacy_inputs(est: Estimate, dev: Deviance, post: np.ndarray, finite: np.ndarray,
                     i_best: tuple[np.intp, ...], items: list[FeatureSummary],
                     cal: Calibration | None, over_best: np.ndarray | None = None) -> None:
    """What the adequacy check reads: the effective number of parameters the data fix (the
    posterior mean of the deviance over its minimum, Spiegelhalter et al.'s p_D), the material's
    shift and, per seen size, the posterior's weight on floor cells. ``over_best``: the
    deviance over its minimum per cell where the compiled posterior kept it (None: computed
    here)."""
    if over_best is not None:
        # the deviance over its minimum as the posterior left it: on the cells with features
        # (penalty 0) the same numbers as the expression below
        from solitonde.instrument.inference.posterior_kernel import weighted_excess

        excess = weighted_excess(post, over_best, finite, int(np.count_nonzero(finite)))
    else:
        d_best = float(dev.misfit[i_best] + dev.logdet[i_best] + dev.bound_terms[i_best])
        deviance = dev.misfit + dev.logdet + dev.bound_terms
        excess = post[finite] * (deviance[finite] - d_best)
    est.extra["p_d"] = float(np.sum(excess))
    if dev.m_sum is not None and dev.ur_sum is not None:
        est.extra["material_shift_sd"] = material_shift(dev.m_sum, dev.ur_sum, post)
    est.extra["floor_mass"] = {  # a sum of products: no grid-sized temporary
        i.diameter_m: weighted_sum(post, g.floor_weight)
        for i, g in zip(items, dev.grids, strict=True) if not i.hidden}
    est.extra["strict_explained"] = _strict_explained(est, dev, post, items, cal)


def answer(dev: Deviance, items: list[FeatureSummary], cal: Calibration | None,
           return_posterior: bool) -> Estimate:
    """The estimate from the likelihood ``dev`` of exactly ``items``; ``out_of_range`` where no
    table point explains them."""
    compiled = use_compiled()
    if compiled:
        from solitonde.instrument.inference.posterior_kernel import total_and_best

        chi2 = np.empty(dev.shape)
        at = total_and_best(dev.misfit, dev.logdet, dev.penalty, dev.bound_terms, chi2)
        best = float(chi2.flat[at])
    else:
        chi2 = dev.total()
        best = float(chi2.min())
        at = int(np.argmin(chi2))
    i_best = np.unravel_index(at, chi2.shape)
    if not math.isfinite(best):
        return out_of_range(items, cal, best, dev.n_terms,
                            "the model detects no reflection anywhere in the table for these "
                            "sphere sizes, but one was measured")
    fit = float(dev.misfit[i_best]) + dev.bound_misfit(i_best)
    if dev.n_terms:
        limit = _chi2_limit(dev.n_terms)
        if fit > limit:
            return out_of_range(items, cal, fit, dev.n_terms,
                                f"no table point explains the measurement (best chi^2 "
                                f"{fit:.3g} > {limit:.3g} for {dev.n_terms} terms): outside the "
                                "table's range or not this kind of plate; no extrapolated "
                                "number is given")
    g0 = dev.grids[0]
    post, profile_t, profile_l, finite = (_posterior_compiled if compiled else _posterior)(
        chi2, best, g0)
    est = _estimate(post, profile_t, profile_l, g0, items, cal, fit, dev.n_terms)
    _adequacy_inputs(est, dev, post, finite, i_best, items, cal, chi2 if compiled else None)
    if return_posterior:
        est.posterior = {"thickness_m": g0.thickness_m, "distance_m": g0.distance_m,
                         "density": post}
    return est
