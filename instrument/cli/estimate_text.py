"""Estimates as the command line prints them: where each was made, and each parameter's answer
(median and interval, a bound, or its status) with its readings and warnings, for `invert`,
`analyze --invert` and the commands that show estimates."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any


def where_estimated(row: Mapping[str, Any]) -> str:
    """Where an `analyze --invert` estimate was made, in words (a missing plate id or position
    is said so, never printed as None)."""
    plate = row.get("plate_id")
    position = row.get("position")
    return (f"estimate for plate {plate if plate is not None else '(no plate id)'}, position "
            f"{position if position is not None else '(no position)'}")


def _fmt_mm(v: float | None) -> str:
    return "-" if v is None else f"{v * 1e3:.3f}"


def _parameter_text(p: Mapping[str, Any], full: bool) -> str:
    """One parameter's answer in words (``full``: with the MAP and the 68 % interval)."""
    status, ci95 = p["status"], p.get("ci95") or [None, None]
    if status == "constrained":
        if full:
            return (f"{_fmt_mm(p['median'])} mm (MAP {_fmt_mm(p['map'])}; 68 % "
                    f"{_fmt_mm(p['ci68'][0])}..{_fmt_mm(p['ci68'][1])}; 95 % "
                    f"{_fmt_mm(ci95[0])}..{_fmt_mm(ci95[1])} mm)")
        return f"{_fmt_mm(p['median'])} mm (95 % {_fmt_mm(ci95[0])}..{_fmt_mm(ci95[1])} mm)"
    if status == "lower_bound_only":
        return f"at least {_fmt_mm(ci95[0])} mm (95 %)" + (
            "; the data do not bound it from above" if full else "")
    if status == "upper_bound_only":
        return f"at most {_fmt_mm(ci95[1])} mm (95 %)" + (
            "; the data do not bound it from below" if full else "")
    if status == "ambiguous":
        lo, hi = ci95
        span = (f"{_fmt_mm(lo)}..{_fmt_mm(hi)} mm" if lo is not None and hi is not None else
                f"from {_fmt_mm(lo)} mm" if lo is not None else
                f"up to {_fmt_mm(hi)} mm" if hi is not None else "unbounded")
        return f"AMBIGUOUS: the data fit the readings below, {span} over them all (95 %)"
    if status == "inconsistent":
        return "INCONSISTENT with the table's family (no estimate)"
    return "unconstrained by these data" if full else status


def estimate_lines(est: Mapping[str, Any], full: bool = True, indent: str = "") -> list[str]:
    """An estimate (``Estimate.to_dict()``) in words: each parameter, an ambiguous answer's
    readings, the fit, the warnings last."""
    lines = []
    for key, name in (("thickness_m", "thickness"), ("distance_m", "distance to support")):
        lines.append(f"{indent}{name}: {_parameter_text(est[key], full)}")
    for k, r in enumerate(est.get("readings") or [], 1):
        lines.append(f"{indent}  reading {k} (weight {r['weight']:.2g}): thickness "
                     f"{_parameter_text(r['thickness_m'], False)}, distance to support "
                     f"{_parameter_text(r['distance_m'], False)}")
    fit = est.get("fit") or {}
    if fit.get("p_value") is not None:
        lines.append(f"{indent}fit: chi^2 {fit['chi2']:.3g} for {fit['dof']:.2g} degrees of "
                     f"freedom, p = {fit['p_value']:.2g}")
    lines += [f"{indent}warning: {w}" for w in est.get("warnings", [])]
    return lines


def describe_row(row: Mapping[str, Any]) -> str:
    """One `analyze --invert` estimate as text."""
    head = where_estimated(row)
    if row.get("x_m") is not None and row.get("y_m") is not None:
        head += f" (x {row['x_m']:g} m, y {row['y_m']:g} m)"
    head += ":"
    est = row.get("estimate")
    if est is None:
        why = row.get("error") or "; ".join(s["reason"] for s in row.get("skipped", [])) or "-"
        return f"{head} none ({why})"
    lines = [head, *estimate_lines(est, full=False, indent="  ")]
    return "\n".join(lines)
