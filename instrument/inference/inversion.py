"""Invert measured TOF and ARR against a model table: thickness and distance to the support.

Bayesian grid inversion. The table's features are interpolated (linear in log t and in L, the
axes along which TOF and ARR vary smoothly) onto a fine (log t, L) grid once per table and
sphere size; a prior uniform in log t (thickness is a scale) and in L over the table's range;
independent Gaussian errors on the mean TOF and mean ARR of each sphere size:

    sigma_tof^2 = s_tof^2 / n + sigma_model_tof(t, L)^2,   likewise for ARR

with s the shot scatter (where not given: the rig's, measured on the calibration's reference
shots (:mod:`.shot_scatter`), else the assumed :data:`DEFAULT_TOF_REL_STD`,
:data:`DEFAULT_ARR_STD`; floored at :data:`MIN_TOF_STD_S`, :data:`MIN_ARR_STD`) and
sigma_model the table's own interpolation error where the cell lies (leave-one-out at each node
along both axes, scaled to the grid spacing, interpolated like the features): large where TOF and
ARR oscillate with L near a support, small where they are smooth; plus, at nodes simulated on the
2-D plate (next to a support), that plate's own error against the 3-D plate
(:data:`PLATE_THEORY_TOF_REL_STD`, :data:`PLATE_THEORY_ARR_REL_STD`). A calibration fitted
against a table with a dissipation layer first reads the table at the chain's fitted contact
damping (instrument.tables.dissipation; its uncertainty adds to the model error); it multiplies the
model ARR by ``arr_factor`` (experiments lose energy the model does not) and adds ``tof_offset_s``
to the model TOF; its stated uncertainties (``arr_factor_std``, ``tof_offset_std_s``) enter the
variances. Beyond D/t = 5, where the paper finds ARR near 0 and the model's "reflection" is a
train at the detection floor whose features wander between table positions (table nodes with ARR
below :data:`FLOOR_ARR_MAX`; near a support the reflection is whole), the model error also holds
10 % of TOF and the whole ARR (:data:`FLOOR_TOF_REL_STD`, :data:`FLOOR_ARR_REL_STD`),
so such a size weighs little there. Where the model detects no reflection in that regime, the
reflection is below the detector's floor (the table's ``arr_upper_bound``, ~0.02), and a noisy
shot can still pick a floor-level "reflection" out of the noise: such a node is a floor node too,
its ARR that bound and its TOF that of the nearest reflection in its thickness row (far from a
support TOF hardly depends on L), so cells next to it explain a weak measured reflection instead
of being ruled out (which pinned thin plates far from a support to the few cells near it that
had one). Elsewhere, grid points where the model detects no reflection cannot explain a measured
one and get zero posterior. Sphere sizes multiply their likelihoods.

Per parameter the marginal posterior gives MAP, median, 68 % and 95 % central intervals, and a
status (:mod:`.marginals`): when the posterior still carries at least a fifth of its peak density
at an end of the table that is not a physical limit, the data do not bound the parameter on that
side (``lower_bound_only``: e.g. L beyond the critical distance, where TOF and ARR no longer depend
on L; ``upper_bound_only``; ``unconstrained`` on both sides). A one-sided result reports only the
bound (``ci95 = [lower, null]``), no MAP or median: the table's end is not an estimate; the bound
is where the density falls to the level of a likelihood-ratio interval (``marginals.LR_LEVELS``),
since a quantile of a density flat out to the table's end would follow the table's extent. A
measurement no table point explains (chi^2 beyond the 1e-6 tail) is ``out_of_range`` with no
numbers at all. With several sphere sizes, when all together are out of range but the others are
not once one size is left out, that answer is given, with the size left out named
(``excluded_diameters_m``, ``reason``): one disagreeing channel does not void the others. Unless
the size left out is a large sphere beyond D/t = 5 at the answer (its floor-level train), the
answer is then marked ``inconsistent`` (:mod:`.adequacy`): its numbers are the other sizes', but
the family does not explain the sizes together.

Near a support the likelihood is a ridge in (t, L), and the marginal weighs its parts by the
prior's volume in L, not by how well they fit. The thickness answer is therefore checked against
the profile likelihood (:mod:`.ridge`): its intervals reach over the thicknesses the profile
holds at their level, and where those fall into separate groups the answer is ``ambiguous``,
with one reading per group (``Estimate.readings``: thickness, distance, weight).

The plate material's spread (the library's for the table's plate material, or the one a
property mapping states) adds a rank-2 covariance shared by every term, from Zener's exchange
rates between material, thickness and distance (:mod:`.material_spread`), applied exactly per
cell with Woodbury's identity. A sphere size whose shots show no reflection enters with its ARR
upper bound: a cell weighs ``Phi((bound - ARR_model) / sigma)`` where the model has a reflection
and 1 where it has none, so such shots alone answer ``upper_bound_only``. Every estimate carries
``fit`` and ``warnings`` and may be marked ``inconsistent`` (:mod:`.adequacy`).

The modules: the inputs (:mod:`.inversion_inputs`), the model error (:mod:`.model_error`), the
fine grid (:mod:`.fine_grid`), the likelihood (:mod:`.likelihood`, :mod:`.woodbury`), the answer
(:mod:`.posterior`, :mod:`.estimate`); this one holds :func:`invert` and its leave-one-out.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from scipy.stats import chi2 as chi2_dist

from solitonde.instrument.inference.calibration import Calibration
from solitonde.instrument.inference.estimate import Estimate
from solitonde.instrument.inference.inversion_inputs import FeatureSummary, InversionError
from solitonde.instrument.inference.likelihood import deviance
from solitonde.instrument.inference.model_error import FLOOR_ARR_MAX, REFLECTION_D_OVER_T
from solitonde.instrument.inference.posterior import answer
from solitonde.instrument.inference.shot_scatter import fill as fill_scatter
from solitonde.instrument.inference.shot_scatter import none_stated
from solitonde.instrument.tables.table import ModelTable


def invert(
    table: ModelTable,
    inputs: Sequence[FeatureSummary | Mapping[str, Any]],
    calibration: Calibration | Mapping[str, Any] | None = None,
    *,
    return_posterior: bool = False,
    material_spread: Mapping[str, float] | None = None,
) -> Estimate:
    """Posterior estimate of plate thickness and distance to the support.

    Parameters
    ----------
    table: the model table.
    inputs: one summary per sphere size (:class:`FeatureSummary` or a mapping with its fields).
    calibration: ARR factor and TOF offset (:class:`Calibration` or its dict).
    return_posterior: keep the 2-D posterior (``Estimate.posterior``: axes and density).
    material_spread: the plate material's spread (``youngs_modulus_rel_sd``,
        ``poisson_ratio_sd``, ``density_rel_sd``); None takes the library's for the table's
        plate material (instrument.inference.material_spread), zeros turn it off.

    Raises
    ------
    InversionError, TableError
        Bad input, or a sphere size the table does not hold.
    """
    from solitonde.instrument.inference import adequacy
    from solitonde.instrument.inference.material_spread import spread_of

    if isinstance(inputs, Mapping | FeatureSummary) or not inputs:
        raise InversionError("inputs", "give a non-empty list of per-sphere-size summaries")
    cal = Calibration.from_any(calibration)
    items, scatter_notes = fill_scatter([FeatureSummary.from_any(i) for i in inputs],
                                        cal.shot_scatter if cal else none_stated)
    spread = dict(spread_of(table) if material_spread is None else material_spread)
    est = _invert_items(table, items, cal, return_posterior, spread)
    if est.out_of_range and len(items) >= 2:
        est = _leave_one_out(table, items, cal, return_posterior, spread, est)
    est.material_spread = spread
    adequacy.judge(est, FLOOR_ARR_MAX, REFLECTION_D_OVER_T,
                   float(np.min(table.axes["thickness_m"])))
    stale = adequacy.reading_mismatch(table.reading_version)
    if stale is not None:
        est.warnings.append(stale)
    est.warnings.extend(scatter_notes)
    return est


def _leave_one_out(table: ModelTable, items: list[FeatureSummary], cal: Calibration | None,
                   return_posterior: bool, spread: Mapping[str, float], est: Estimate
                   ) -> Estimate:
    """One sphere size may disagree with the others and the table (e.g. a large sphere on a thin
    plate whose "reflection" is a train at the detection floor): leave each out in turn and keep
    the best in-range answer of the others, saying which size was left out and why; ``est``
    (all sizes, out of range) where none is in range."""
    kept: list[tuple[float, int, Estimate]] = []
    for skip in range(len(items)):
        rest = items[:skip] + items[skip + 1:]
        if all(i.hidden for i in rest):
            continue
        trial = _invert_items(table, rest, cal, return_posterior, spread)
        if not trial.out_of_range:
            tail = float(chi2_dist.sf(trial.chi2_min, max(trial.n_terms, 1)))
            kept.append((tail, skip, trial))
    if not kept:
        return est
    _, skip, best = max(kept, key=lambda k: k[0])
    left_out = items[skip]
    best.reason = (f"sphere size D = {left_out.diameter_m * 1e3:.2f} mm left out: with "
                   f"it no table point explains the measurement ({est.reason}); the "
                   "other sizes agree with the table")
    best.extra["excluded_diameters_m"] = [left_out.diameter_m]
    best.inputs = items
    return best


def _invert_items(table: ModelTable, items: list[FeatureSummary], cal: Calibration | None,
                  return_posterior: bool, spread: Mapping[str, float] | None) -> Estimate:
    """The grid posterior of :func:`invert` for exactly these sphere sizes."""
    return answer(deviance(table, items, cal, spread), items, cal, return_posterior)
