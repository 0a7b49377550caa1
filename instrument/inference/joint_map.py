"""A plate's scan inverted as one unknown: its clamped edges and every position's thickness.

A map inverts each position alone and then fits an edge to the positions' distance answers
(:mod:`.support`). Near a clamped edge, thickness and distance trade off in a single position's
TOF and ARR, so its thickness comes back loose or as a bound; yet the positions together locate
the edge, and once the edge is known each position's distance is known too. Here the scan is one
unknown:

* **The supports as the family declares them.** The paper's plate has two opposite clamped
  edges a plate length ``a`` apart (the table family's ``plate_size_m[0]``, the length along
  which ``distance_to_support`` runs); in the scan's own frame they are the lines
  ``x cos(theta) + y sin(theta) = offset`` and ``... = offset + a``, angle and offset unknown (a
  prior uniform in both). The reported edge is the one nearer the scan's centroid, so each pair
  of lines is counted once. A position at signed distance ``d`` from it stands ``min(d, a - d)``
  from the nearer support, and on the plate only for ``0 <= d <= a``. A family whose plate size
  is not recorded has one edge (``line``): ``d >= 0``, distance ``d``.
* **Each position's own likelihood.** Every position's per-size TOF/ARR summaries are inverted
  as :func:`~.inversion.invert` does and its likelihood over the fine (t, L) grid is kept
  (:func:`~.inversion.cell_likelihood`: the same terms, not a second likelihood). Positions the
  table's family does not explain (``inconsistent``, ``out_of_range``) are left out, named.
* **One posterior.** ``p(edge, t_1..t_n | data) ~ p(edge) prod_i L_i(t_i, L_i(edge)) p(t_i)``.
  With thickness free per position (the default; ``p(t_i)`` uniform in log t as in a single
  inversion) each position enters the edge's posterior through its marginal over t. With
  ``common`` the positions share a mean ``mu`` (uniform in log) around which each ``log t_i``
  scatters with a stated relative spread (``N(log mu, s^2)``); ``mu`` is integrated on a grid.
  The edge's posterior lives on cells in (angle, the centroid's distance from the edge), refined
  where it carries weight until it is smooth across each cell; each position's distance follows
  from its coordinates on every cell, and its thickness is the mixture over the cells of its
  own conditional posterior at that distance, summarised by the rules of a single inversion
  (status, intervals, one-sided bounds).
* **Do the positions agree with one straight edge?** ``fit = {chi2, dof, p_value}``: the misfit
  of every position at the joint best answer, against ``n_terms - p_D`` degrees of freedom (p_D
  the joint posterior's effective number of parameters: the posterior mean of the misfit over
  its value at the answer, which is the parameter count for a linear-Gaussian model; unlike a
  single inversion's (:mod:`.adequacy`) it leaves out the deviance's log-determinant, which
  varies across the posterior with the model's stated error and summed over a scan's positions
  took p_D to 18.5 for 10 positions of a 1.93 mm plate (12 parameters): five of the map study's
  30 right-family scans were flagged so, none now; docs/explanation/joint-map.md). A single
  position near a support fits any edge and leaves no degree of freedom; together they test the
  edge. Below ``p = 0.001`` the joint answers are marked ``inconsistent`` and the warning names
  the positions that disagree most.

* **One calibration, one plate (optional).** A scan's positions share one calibration, and the
  part of its TOF offset that does not transfer from the reference plates (the dissipation's
  delay, which depends on the plate's thickness) is, to first order, one error for the whole
  plate. Counted per position, as a single inversion must count it, it lets each position's TOF
  wander by its own ~12 us (TOF changes by 0.5-4 us per mm near a clamp, thick plates least:
  3-25 mm of distance each), so the positions seem to disagree about the edge's direction more
  than they can. ``posterior(..., shared_calibration=True)`` draws it once
  (:func:`calibration_nodes`): each position's deviance is quadratic in the offset's error
  (exactly), and the joint posterior is integrated over nodes of it (a hyper value, as the
  common mean is). It is not the default: in the map study it narrowed the edge and the
  near-edge thickness intervals but left the free thickness answers covering 0.90, because the
  simulated delay is not one number for a plate (next to the clamp it differs from far away by
  a few us); counted per position, the offset's 12 us also covers that. The ARR factor's
  uncertainty stays per position (the study's calibration states 0.4 %, a fifth of the table's
  own ARR error next to a clamp), and so does the plate material's spread (E +- 0.8 %: it does
  not change a near-edge position's thickness interval at two decimals,
  docs/explanation/joint-map.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from solitonde.instrument.inference.inversion import invert
from solitonde.instrument.inference.inversion_inputs import InversionError
from solitonde.instrument.inference.joint_answers import (
    PositionAnswer,
    median_edge,
    position_answer,
    weighted_quantiles,
)
from solitonde.instrument.inference.joint_calibration import calibration_nodes
from solitonde.instrument.inference.joint_likelihood import (
    PositionLikelihood,
    RawLikelihood,
    at_nodes,
)
from solitonde.instrument.inference.joint_model import (
    DEFAULT_SPREAD,
    EDGE_MODELS,
    THICKNESS_PRIORS,
    EdgeModel,
    JointMapError,
    ScanPosition,
    ThicknessPrior,
    edge_model,
)
from solitonde.instrument.inference.joint_posterior import JointPosterior, edge_posterior
from solitonde.instrument.inference.joint_summary import shared_calibration, summary
from solitonde.instrument.inference.likelihood import cell_likelihood
from solitonde.instrument.tables.table import ModelTable, TableError


def raw_likelihood(table: ModelTable, position: ScanPosition, shared: bool
                   ) -> tuple[RawLikelihood | None, str | None]:
    """The position's raw likelihood, or None and why it is left out of the joint posterior."""
    inputs = list(position.inputs)
    if not inputs:
        return None, "no sphere size with an inversion input"
    try:
        est = invert(table, inputs, position.calibration,
                     material_spread=position.material_spread)
    except (InversionError, TableError) as exc:  # e.g. a sphere size the table lacks
        return None, f"not inverted: {exc}"
    if est.inconsistent:
        return None, ("its own answer is " + est.thickness_m.status + " (the table's family "
                      "does not explain it): " + (est.warnings[0] if est.warnings else
                                                   str(est.reason)))
    excluded = set(est.extra.get("excluded_diameters_m", []))
    used = [i for i in inputs if i.diameter_m not in excluded]
    keep = cell_likelihood(table, used, position.calibration,
                           material_spread=est.material_spread, shared_calibration=shared)
    if not np.isfinite(keep["deviance"]).any():
        return None, "the model detects no reflection anywhere for its sphere sizes"
    cal = position.calibration
    keys = []
    for d, kind, sd in keep["shared"]:
        # the key names the calibration entry (the size's values over all its references); a
        # distance-dependent offset shares one error, scaled to its sd at each distance
        factor, offset = (1.0, 0.0) if cal is None else cal.for_diameter(d)
        keys.append((round(d * 1e6), kind, factor if kind == "arr_factor" else offset, sd))
    return RawLikelihood(position, est, keep, keys), None


def position_likelihood(table: ModelTable, position: ScanPosition
                        ) -> tuple[PositionLikelihood | None, str | None]:
    """The position's likelihood alone (its calibration's uncertainty marginalised for it
    alone, as a single inversion does), or None and why it is left out."""
    raw, why = raw_likelihood(table, position, False)
    if raw is None:
        return None, why
    return at_nodes(raw, [], np.zeros((1, 0))), None


def posterior(table: ModelTable, positions: Sequence[ScanPosition],
              prior: ThicknessPrior | None = None, *,
              shared_calibration: bool = False) -> JointPosterior:
    """The joint posterior of a scan (see the module doc).

    ``shared_calibration``: the calibration's TOF offset error is drawn once for the scan and
    integrated over once (one calibration, one plate); by default it is taken per position, as
    each position's own inversion takes it, which the map study found keeps the thickness
    answers' coverage (sharing it narrows them too far: the offset's error is not one number
    for a plate, docs/explanation/joint-map.md).

    Raises JointMapError (``positions``) when no position can enter it, or (``joint``) for a
    family whose supports are not a line's angle and offset."""
    prior = prior or ThicknessPrior()
    model = edge_model(table)
    raws, excluded = [], []
    for pos in positions:
        for name, v in (("x_m", pos.x_m), ("y_m", pos.y_m)):
            if v is None or not math.isfinite(float(v)):
                raise JointMapError(name, f"position {pos.name!r}: {v!r} (allowed: a finite "
                                    "coordinate in metres)")
        raw, why = raw_likelihood(table, pos, shared_calibration)
        if raw is None:
            excluded.append((pos, why or "left out"))
        else:
            raws.append(raw)
    keys, eta, node_z2 = calibration_nodes(raws)
    likes = [at_nodes(raw, keys, eta) for raw in raws]
    if not likes:
        raise JointMapError("positions", "no position with coordinates whose measurement the "
                            "table's family explains: " + "; ".join(
                                f"{p.name}: {w}" for p, w in excluded) if excluded
                            else "no position with coordinates")
    cells, anchor, p, log_mu, log_m, _ = edge_posterior(likes, model, prior, node_z2)
    top = cells.lp.max()
    area = cells.h_theta * cells.h_c
    mass = np.exp(cells.lp - top) * area
    total = mass.sum()
    mass_hyper = np.exp(cells.lp_hyper - top) * area[None, :] / total
    return JointPosterior(table, model, prior, likes, anchor, cells, mass / total, mass_hyper, p,
                          log_mu, log_m, likes[0].distance_m, excluded, keys, eta, node_z2)


__all__ = ["DEFAULT_SPREAD", "EDGE_MODELS", "THICKNESS_PRIORS", "EdgeModel", "JointMapError",
           "JointPosterior", "PositionAnswer", "ScanPosition", "ThicknessPrior",
           "calibration_nodes", "edge_model", "median_edge", "position_answer",
           "position_likelihood", "posterior", "shared_calibration", "summary",
           "weighted_quantiles"]
