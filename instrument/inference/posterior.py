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
from solitonde.instrument.inference.cell_posterior import (
    CellPosterior,
    from_deviance,
    from_deviance_compiled,
)
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


def _estimate(cp: CellPosterior, g0: FineGrid, items: list[FeatureSummary],
              cal: Calibration | None, fit: float, n_terms: int) -> Estimate:
    """Each parameter's summary of the posterior, the thickness's checked against the ridge."""
    lower_physical = bool(g0.distance_m[0] <= 0.0)
    thickness = summarise_marginal(np.log(g0.thickness_m), cp.mass_t, g0.weight_t,
                                   lower_physical=False, transform=np.exp, profile=cp.profile_t)
    distance = summarise_marginal(g0.distance_m, cp.mass_l, g0.weight_l,
                                  lower_physical=lower_physical, profile=cp.profile_l)
    marginal = thickness
    thickness, distance, readings = ridge.resolve(
        thickness, distance, g0.thickness_m, g0.distance_m, lambda: cp.density, g0.weight_t,
        g0.weight_l, cp.profile_t, lower_physical=lower_physical)
    est = Estimate(thickness, distance, items, cal, fit, n_terms, readings=readings)
    if thickness.status == marginal.status and thickness.ci95 != marginal.ci95:
        est.extra["ridge_widened"] = {"marginal_ci95": list(marginal.ci95 or ()),
                                      "ci95": list(thickness.ci95 or ())}
    if len(readings) > 1:
        est.extra["other_reading"] = second_reading(readings, g0.thickness_m)
    return est


def _strict_explained(floor_mass: dict[float, float], dev: Deviance, cp: CellPosterior,
                      items: list[FeatureSummary], cal: Calibration | None) -> dict[float, float]:
    """Per seen size resting on floor cells (``floor_mass`` at least :data:`MIN_FLOOR_MASS`):
    the posterior probability that its TOF and ARR are explained without the floor nodes'
    looseness (their chi^2 within the 1e-3 tail), over the cells that carry the posterior
    (:attr:`~.cell_posterior.CellPosterior.carrying`)."""
    out: dict[float, float] = {}
    limit = _chi2_limit_at(2, 1e-3)
    cells, cols, weight = cp.carrying
    for item, g in zip(items, dev.grids, strict=True):
        if item.hidden or floor_mass[item.diameter_m] < MIN_FLOOR_MASS:
            continue
        factor, offset, f_std, o_std = calibration_along(cal, g.diameter_m, g.distance_m[None, :])
        s_tof, s_arr = item.sigmas()
        assert item.tof_s is not None and item.arr is not None  # seen
        if use_compiled():
            from solitonde.instrument.inference.posterior_kernel import strict_cells

            n_l = g.distance_m.size
            explained = strict_cells(
                g.tof_s, g.arr, g.model_tof_var_strict, g.model_arr_var_strict,
                per_distance(item.tof_s - offset, n_l), per_distance(s_tof**2 + o_std**2, n_l),
                item.arr, per_distance(factor, n_l), per_distance(f_std, n_l), s_arr**2, limit,
                cells, cols)
        else:
            strict = ((item.tof_s - offset - g.tof_s) ** 2
                      / (s_tof**2 + o_std**2 + g.model_tof_var_strict)
                      + (item.arr - factor * g.arr) ** 2
                      / (s_arr**2 + factor**2 * g.model_arr_var_strict + (f_std * g.arr) ** 2))
            explained = np.take(strict, cells) <= limit
        out[item.diameter_m] = float(np.sum(weight[explained]))
    return out


def _adequacy_inputs(est: Estimate, dev: Deviance, cp: CellPosterior,
                     items: list[FeatureSummary], cal: Calibration | None) -> None:
    """What the adequacy check reads, into ``est.extra``: the effective number of parameters
    the data fix (the posterior mean of the deviance over its minimum, Spiegelhalter et al.'s
    p_D), the material's shift and, per seen size, the posterior's weight on floor cells and
    the share its strict model error explains (these two over the cells that carry it)."""
    # the cells that carry weight have a finite deviance (or NaN: then every weight is NaN)
    est.extra["p_d"] = float(np.sum(cp.weight * cp.over_best))
    if dev.m_sum is not None and dev.ur_sum is not None:
        est.extra["material_shift_sd"] = material_shift(dev.m_sum, dev.ur_sum, cp.cells,
                                                        cp.weight)
    carrying = cp.carrying
    floor_mass = {i.diameter_m: (weighted_sum(carrying.weight,
                                              np.take(g.floor_weight, carrying.cells))
                                 if g.has_floor else 0.0)
                  for i, g in zip(items, dev.grids, strict=True) if not i.hidden}
    est.extra["floor_mass"] = floor_mass
    est.extra["strict_explained"] = _strict_explained(floor_mass, dev, cp, items, cal)


def answer(dev: Deviance, items: list[FeatureSummary], cal: Calibration | None,
           return_posterior: bool) -> Estimate:
    """The estimate from the likelihood ``dev`` of exactly ``items``; ``out_of_range`` where no
    table point explains them."""
    compiled = use_compiled()
    row_min: np.ndarray | None = None
    if compiled and dev.chi2 is not None and dev.row_min is not None:  # the likelihood's pass
        chi2, row_min, at = dev.chi2, dev.row_min, dev.best_at
    elif compiled:
        from solitonde.instrument.inference.posterior_kernel import total_and_best

        chi2, row_min = np.empty(dev.shape), np.empty(dev.shape[0])
        at = total_and_best(dev.misfit, dev.logdet, dev.penalty, dev.bound_terms, chi2, row_min,
                            0, dev.shape[0])
    else:
        chi2 = dev.total()
        at = int(np.argmin(chi2))
    best = float(chi2.flat[at])
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
    cp = (from_deviance(chi2, best, g0) if row_min is None
          else from_deviance_compiled(chi2, best, row_min, g0))
    est = _estimate(cp, g0, items, cal, fit, dev.n_terms)
    _adequacy_inputs(est, dev, cp, items, cal)
    if return_posterior:
        est.posterior = {"thickness_m": g0.thickness_m, "distance_m": g0.distance_m,
                         "density": cp.density}
    return est
