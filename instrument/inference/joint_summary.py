"""The joint answer as JSON: the located support, each position's answer, the joint fit, the
warnings, the thickness prior and the shared calibration errors."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TypedDict

import numpy as np
from scipy.stats import chi2 as chi2_dist

from solitonde.instrument.inference.joint_answers import (
    PositionAnswer,
    best_fit,
    median_edge,
    position_answer,
    weighted_quantiles,
)
from solitonde.instrument.inference.joint_model import EdgeModelRow, ThicknessPriorRow
from solitonde.instrument.inference.joint_posterior import JointPosterior
from solitonde.instrument.inference.marginals import ParameterDict, ParameterEstimate

P_INCONSISTENT = 1e-3
DISAGREE_CHI2 = 9.0
"""A position whose misfit at the joint answer exceeds its own best by this disagrees."""
WIDE_ANGLE_DEG = 20.0


class SharedError(TypedDict):
    """One calibration error the scan shares: its entry (sphere size, quantity, stated value
    and sd) and where the positions together put it (posterior mean and sd)."""

    diameter_m: float
    quantity: str
    stated: float
    stated_sd: float
    error_mean: float
    error_sd: float


class JointSupport(TypedDict):
    """The located clamped edge (the posterior median line) with its 95 % intervals."""

    normal_angle_deg: float
    offset_m: float
    ci95_offset_m: list[float]
    n_positions: int
    residual_m: float | None
    ci95_normal_angle_deg: list[float]
    model: str
    second_offset_m: float | None
    status: str


class JointPositionRow(TypedDict):
    """One position's joint answer; its estimates as :meth:`ParameterEstimate.to_dict`
    writes them."""

    position: str | None
    x_m: float
    y_m: float
    thickness_m: ParameterDict
    distance_m: ParameterDict
    distance_to_located_support_m: float


class JointFit(TypedDict):
    """The misfit at the joint best answer against its degrees of freedom."""

    chi2: float
    dof: float
    p_value: float


class ExcludedPosition(TypedDict):
    """A position left out of the joint answer, and why."""

    position: str | None
    reason: str


class JointAnswer(TypedDict):
    """The joint answer (:func:`summary`)."""

    support: JointSupport
    positions: list[JointPositionRow]
    fit: JointFit
    warnings: list[str]
    thickness_prior: ThicknessPriorRow
    edges: EdgeModelRow
    shared_calibration: list[SharedError]
    excluded: list[ExcludedPosition]


def shared_calibration(post: JointPosterior) -> list[SharedError]:
    """The calibration errors the scan shares (one draw for every position measured with the
    calibration): per error its sphere size, quantity, stated value and sd, and where the
    positions together put it (posterior mean and sd of the error)."""
    node_w, _ = post.hyper_weights()
    node_w = node_w / node_w.sum()
    out: list[SharedError] = []
    for a, (d_um, kind, value, sd) in enumerate(post.keys):
        e = post.eta[:, a]
        mean = float(node_w @ e)
        out.append({"diameter_m": d_um * 1e-6, "quantity": kind, "stated": value,
                    "stated_sd": sd, "error_mean": mean,
                    "error_sd": float(np.sqrt(node_w @ (e - mean) ** 2))})
    return out


def _fit(post: JointPosterior, answers: Sequence[PositionAnswer]
         ) -> tuple[JointFit, list[float]]:
    """The joint fit and each position's misfit at the joint best answer."""
    misfits, n_terms, z_node = best_fit(post)
    chi2 = float(sum(misfits)) + z_node
    node_w, _ = post.hyper_weights()
    # the misfit's own drop from the posterior's mean to the answer: the deviance's other
    # terms (the log-determinant of a covariance that grows next to the clamp) vary across the
    # posterior without being a parameter the data fix
    p_d = max(sum(a.expected_misfit for a in answers) + float(node_w @ post.node_z2) - chi2,
              0.0)
    dof = max(n_terms - min(p_d, n_terms), 1.0)
    p_value = float(chi2_dist.sf(chi2, dof))
    return {"chi2": chi2, "dof": dof, "p_value": p_value}, misfits


def _warnings(post: JointPosterior, fit: JointFit, misfits: Sequence[float],
              angle_width: float) -> list[str]:
    """What the joint answer warns of: positions that disagree with one edge, a direction the
    positions do not fix, positions left out, a missing calibration."""
    warnings: list[str] = []
    chi2, dof, p_value = fit["chi2"], fit["dof"], fit["p_value"]
    excess = [(lk.position.name, f - float(lk.estimate.chi2_min))
              for lk, f in zip(post.likes, misfits, strict=True)]
    if p_value < P_INCONSISTENT:
        worst = sorted((e for e in excess if e[1] > DISAGREE_CHI2), key=lambda e: -e[1])
        named = ", ".join(f"{n} (chi^2 {e:+.3g} over its own best)" for n, e in worst[:5])
        warnings.append(
            "inconsistent: the positions do not agree with one straight clamped edge"
            + (f" and the plate's length {post.model.width * 1e3:.0f} mm"
               if post.model.kind == "opposite_edges" else "")
            + f" (chi^2 {chi2:.3g} for {dof:.3g} degrees of freedom, p = {p_value:.2g} < "
            f"{P_INCONSISTENT:g})" + (f"; disagreeing most: {named}" if named else "")
            + "; check their coordinates, the frame, or whether the support is straight")
    if angle_width > WIDE_ANGLE_DEG:
        warnings.append(f"the positions do not fix the edge's direction (95 % of its angle "
                        f"spans {angle_width:.0f} deg): add positions near the edge, spread "
                        "along it")
    for pos, why in post.excluded:
        warnings.append(f"position {pos.name} left out of the joint answer: {why}")
    if any(lk.position.calibration is None for lk in post.likes):
        from solitonde.instrument.inference.adequacy import NO_CALIBRATION

        warnings.append(NO_CALIBRATION)
    return warnings


def _support(post: JointPosterior, angle_ci: Sequence[float], inconsistent: bool
             ) -> tuple[JointSupport, list[float]]:
    """The located edge (the posterior median line, :func:`~.joint_answers.median_edge`) and
    each position's distance from it."""
    a_lo, a_hi = angle_ci
    o_lo, o_hi = weighted_quantiles(post.offsets(), post.mass, (0.025, 0.975))
    theta_line, offset_line = median_edge(post)
    normal = math.degrees(theta_line) % 360.0
    line_n = np.array([math.cos(theta_line), math.sin(theta_line)])
    to_line = [float(post.model.distance(np.array([lk.position.x_m, lk.position.y_m]) @ line_n
                                         - offset_line)) for lk in post.likes]
    residuals = [d - median for lk, d in zip(post.likes, to_line, strict=True)
                 if lk.estimate.distance_m.status == "constrained"
                 and (median := lk.estimate.distance_m.median) is not None]
    support: JointSupport = {
        "normal_angle_deg": normal,
        "offset_m": offset_line,
        "ci95_offset_m": [o_lo, o_hi],
        "n_positions": len(post.likes),
        "residual_m": float(np.sqrt(np.mean(np.square(residuals)))) if residuals else None,
        "ci95_normal_angle_deg": [(normal + a_lo) % 360.0, (normal + a_hi) % 360.0],
        "model": post.model.kind,
        "second_offset_m": (offset_line + post.model.width
                            if post.model.kind == "opposite_edges" else None),
        "status": "inconsistent" if inconsistent else "located",
    }
    return support, to_line


def _positions(post: JointPosterior, answers: Sequence[PositionAnswer],
               to_line: Sequence[float], inconsistent: bool) -> list[JointPositionRow]:
    """Each position's joint answer (every status ``inconsistent`` where the fit says so)."""
    positions: list[JointPositionRow] = []
    for lk, ans, line_d in zip(post.likes, answers, to_line, strict=True):
        t, d = ans.thickness, ans.distance
        if inconsistent:
            t = ParameterEstimate(t.map, t.median, t.ci68, t.ci95, "inconsistent")
            d = ParameterEstimate(d.map, d.median, d.ci68, d.ci95, "inconsistent")
        positions.append({"position": lk.position.name, "x_m": lk.position.x_m,
                          "y_m": lk.position.y_m, "thickness_m": t.to_dict(),
                          "distance_m": d.to_dict(),
                          "distance_to_located_support_m": line_d})
    return positions


def _prior(post: JointPosterior) -> ThicknessPriorRow:
    """The thickness prior, with the common mean's posterior where the positions share one."""
    prior = post.prior.to_dict()
    if post.prior.kind == "common":
        _, mu_w = post.hyper_weights()
        q2, q50, q98 = weighted_quantiles(post.log_mu, mu_w, (0.025, 0.5, 0.975))
        prior["mean_m"] = {"median": math.exp(q50), "ci95": [math.exp(q2), math.exp(q98)]}
    return prior


def summary(post: JointPosterior) -> JointAnswer:
    """The joint answer: ``support``, per-position answers, ``fit``, ``warnings``,
    ``thickness_prior``."""
    theta_map = float(post.cells.theta[post.best])
    rel = (post.cells.theta - theta_map + math.pi) % (2 * math.pi) - math.pi
    a_lo, a_hi = weighted_quantiles(np.degrees(rel), post.mass, (0.025, 0.975))
    answers = [position_answer(post, i) for i in range(len(post.likes))]
    fit, misfits = _fit(post, answers)
    warnings = _warnings(post, fit, misfits, a_hi - a_lo)
    inconsistent = fit["p_value"] < P_INCONSISTENT
    support, to_line = _support(post, (a_lo, a_hi), inconsistent)
    return {"support": support, "positions": _positions(post, answers, to_line, inconsistent),
            "fit": fit, "warnings": warnings,
            "thickness_prior": _prior(post), "edges": post.model.to_dict(),
            "shared_calibration": shared_calibration(post),
            "excluded": [{"position": p.name, "reason": w} for p, w in post.excluded]}
