"""Whether the table's family explains a measurement, and what an answer should be read with.

Every estimate carries ``fit = {chi2, dof, p_value}`` and ``warnings``. A recording is
*inconsistent* with the table's family (thickness and distance then carry the status
``inconsistent``, with a warning naming the likely causes) when

* its best fit is improbable: ``p_value`` below :data:`P_INCONSISTENT`. ``chi2`` is the misfit
  (residuals against the full covariance: shot scatter, the table's interpolation error, the
  calibration and the plate material's spread) at the most probable cell; ``dof`` is the number
  of terms (TOF and ARR per sphere size with a reflection) less the parameters the data
  actually fix, Spiegelhalter et al.'s p_D (the posterior mean of the deviance over its
  minimum: about 1 far from a support, where TOF and ARR do not depend on L, about 2 near one),
  and at least 1: one sphere size near a support leaves no degree of freedom, and a test with
  one is then conservative;
* no table point explains it at all (``out_of_range``, a TOF/ARR pair the family cannot reach);
* or a sphere size had to be left out to answer at all (with every size no table point explains
  the data) where the answer puts that size's reflection clear (D/t below 5 over the whole 95 %
  interval, an "at most" one running down to the table's thinnest plate): the known reason to
  leave a size out is a large sphere on a thin plate, whose "reflection" beyond D/t = 5 is a
  train at the detection floor; anything else is the family disagreeing with the sizes
  together (a steel plate read against the aluminium table shows it most often this way: each
  size alone maps onto some aluminium thickness, not all at once);
* or its reflection is unlike the family's where the answer lies: the answer leans on cells
  whose features come in part from floor nodes (D/t beyond 5, where the family's reflection is
  a train at the detection floor, ARR below 0.3, so the table states it loosely: 10 % in TOF,
  the whole ARR), the measured ARR of that size is a clear reflection (above that floor by
  three standard errors), and less than 5 % of the posterior lies on cells that explain the
  size's TOF and ARR with the table's interpolation error alone (chi^2 of its two terms within
  the 1e-3 tail). A right-family plate between a floor node and a clear one is explained by
  the interpolation there; a plate of another material is not: a 4 mm steel plate read as
  1.83 mm of aluminium 12 mm from the support, through those loose cells alone.

An estimate made without a calibration says so: the model's ARR runs above measured ones (the
paper's Figs. 5 and 7: the experiment loses energy the model does not), so an uncalibrated
thickness comes out low.
"""

from __future__ import annotations

import math
from typing import Any

from scipy.special import chdtrc

from solitonde.instrument.inference.calibration import answer_distance
from solitonde.signal.features import EXTRACTOR_VERSION

# The inversion calls this module on every estimate, so this module does not import it back:
# an estimate (``Estimate``) and its parameters are used through their attributes, and the
# floor level comes with the call.

P_INCONSISTENT = 1e-3
"""A best fit less probable than this under the table's family flags the recording."""
STRICT_EXPLAINED = 0.05
"""A clear reflection is unlike the family's when less than this posterior probability lies on
cells that explain it without the floor nodes' looseness."""
FLOOR_Z = 3.0
"""Standard errors by which a measured ARR must exceed the floor level to be a clear one."""
CAUSES = ("the plate's material is not the table's (check the plate, or give "
          "--plate-material / plate_material to pick the right table)",
          "the table's family (sphere size and material, plate size, supports, striker) is not "
          "the set-up measured",
          "no calibration, or one made on another set-up (solitonde calibrate on a reference "
          "plate)",
          "the units or the sensor's calibration of the recording (N, V, N/V)")
MATERIAL_EDGE_SD = 1.0
"""The material term's posterior mean, in its spread's sd of E', at which the answer says the data
sit at the edge of the material's range. The data barely move it on a plate of the grade (over
validate's right-family plates, drawn from the spread, D 9.53 mm: sd 0.15 and none of 178 at 1 or
beyond on the aluminium table; sd 0.39 and 1 of 100 on the steel table); a steel plate of E 210
GPa, nu 0.30 read against a table of E 200 GPa, nu 0.26 (E' 2.4 sd out) moves it by 1.0-1.16."""
NO_CALIBRATION = ("no calibration on a reference plate: the model's ARR runs above measured ones "
                  "(the paper's Figs. 5 and 7), so thickness comes out low; run `solitonde "
                  "calibrate` on a reference plate and give its file")


def _chi2_sf(x: float, dof: float) -> float:
    """``scipy.stats.chi2.sf(x, dof)`` of a finite ``x``, to the bit: the function it calls
    (``chdtrc``; 1 at and below 0, the support's edge) without its argument handling, which
    cost 20 us an inversion."""
    return 1.0 if x <= 0.0 else float(chdtrc(dof, x))


def _dof(est: Any) -> float:
    p_d = float(est.extra.get("p_d", 0.0))
    return max(est.n_terms - min(max(p_d, 0.0), est.n_terms), 1.0)


def reading_mismatch(table_version: int) -> str | None:
    """The warning for a table whose points were read another way than shots are now
    (:data:`solitonde.signal.features.EXTRACTOR_VERSION`), or None."""
    if table_version == EXTRACTOR_VERSION:
        return None
    return (f"the table's points were read with the extractor's reading {table_version}, shots "
            f"are read with reading {EXTRACTOR_VERSION} (the trend under the reflection now ends "
            "2.5 FWHM after it, so a record reads the same however long it runs on): on the "
            "bundled table's points the two differ in ARR by up to 0.3 % where the reflection "
            "is clear (ARR above 0.3) and by percents where it is weak beyond D/t 5; rebuild "
            "the table (`solitonde table build`) before acting on this answer")


def judge(est: Any, floor_arr_max: float, floor_d_over_t: float, thinnest_m: float) -> None:
    """Fill ``est.fit`` and ``est.warnings`` of an inversion's ``Estimate``; mark the answer
    ``inconsistent`` when the family does not explain the data (see the module doc);
    ``floor_arr_max`` and ``floor_d_over_t`` are the inversion's floor level of ARR and the D/t
    beyond which the family's reflection is at the floor (``FLOOR_ARR_MAX``,
    ``REFLECTION_D_OVER_T``); ``thinnest_m`` is the table's thinnest plate, where an "at most"
    answer's interval ends."""
    warnings: list[str] = []
    why: str | None = None
    if est.n_terms:
        dof = float(est.n_terms) if est.out_of_range else _dof(est)
        chi2 = float(est.chi2_min)
        p = _chi2_sf(chi2, dof) if math.isfinite(chi2) else 0.0
        est.fit = {"chi2": chi2 if math.isfinite(chi2) else None, "dof": dof, "p_value": p}
        if not est.out_of_range and p < P_INCONSISTENT:
            why = (f"the best fit is improbable under the table's family (chi^2 {chi2:.3g} for "
                   f"{dof:.2g} degrees of freedom, p = {p:.2g} < {P_INCONSISTENT:g})")
    else:
        est.fit = {"chi2": None, "dof": None, "p_value": None}
    if why is None and not est.out_of_range:
        why = _floor_mismatch(est, floor_arr_max)
    if why is None and not est.out_of_range:
        why = _unexplained_exclusion(est, floor_d_over_t, thinnest_m)
    if est.out_of_range:
        warnings.append(f"inconsistent: {est.reason}; likely causes: " + "; ".join(CAUSES))
    elif why is not None:
        warnings.append(f"inconsistent: {why}; the numbers are the table's best reading, not an "
                        "estimate to use. Likely causes: " + "; ".join(CAUSES))
        for name in ("thickness_m", "distance_m"):
            getattr(est, name).status = "inconsistent"
        est.reason = (est.reason + "; " if est.reason else "") + f"inconsistent: {why}"
    readings = getattr(est, "readings", [])
    widened = est.extra.get("ridge_widened")
    if readings and why is None and not est.out_of_range:
        warnings.append(_readings_warning(readings))
    elif widened is not None and why is None and not est.out_of_range:
        warnings.append(
            f"another reading fits as well: the 95 % interval reaches over "
            f"{_interval_mm(widened['ci95'])}, thicknesses that fit as well at some distance to a "
            f"support, beyond the {_interval_mm(widened['marginal_ci95'])} that weighing the "
            "distances by how much of the table's range fits each would give. Near a support "
            "a thinner plate nearer to it can mimic a thicker one farther out; a known distance "
            "(a scan's edge: solitonde map --joint) or another sphere size tells them apart")
    hidden = [i for i in est.inputs if i.hidden]
    for i in hidden:
        within = ("" if i.tof_window_s is None else
                  f" within {i.tof_window_s * 1e6:.4g} us of the incident (the records' end)")
        later = ("" if i.tof_window_s is None else
                 "; a later one, which the records could not show, is not excluded")
        warnings.append(f"no reflection with D = {i.diameter_m * 1e3:.3g} mm{within}: its ARR "
                        f"bound {i.arr_upper_bound:.3g} enters as an upper bound on the "
                        f"reflection{later}")
    edge = _material_edge(est)
    if edge is not None and not est.out_of_range:
        warnings.append(edge)
    spread_note = default_spread_note(est.material_spread)
    if spread_note is not None:
        warnings.append(spread_note)
    if est.calibration is None:
        warnings.append(NO_CALIBRATION)
    est.warnings = warnings + [w for w in est.warnings if w not in warnings]


def _interval_mm(ci: Any) -> str:
    """A 95 % interval in mm, an open side said in words."""
    lo, hi = ci if ci is not None else (None, None)
    if lo is None and hi is None:
        return "unbounded"
    if hi is None:
        assert lo is not None
        return f"at least {lo * 1e3:.3g} mm"
    if lo is None:
        return f"at most {hi * 1e3:.3g} mm"
    return f"{lo * 1e3:.3g}-{hi * 1e3:.3g} mm"


def _readings_warning(readings: Any) -> str:
    """The warning of an ``ambiguous`` answer: each reading's thickness, distance and weight."""
    parts = [f"{_interval_mm(r.thickness_m.ci95)} with the support "
             f"{_interval_mm(r.distance_m.ci95)} away (weight {r.weight:.2g})" for r in readings]
    return ("another reading fits as well: the data fit separate readings along the "
            "thickness-distance ridge, " + "; ".join(parts) + " (95 %). Near a support a thinner "
            "plate nearer to it can mimic a thicker one farther out, and the weights count how "
            "much of the table's distance range fits each, not how well; a known distance (a "
            "scan's edge: solitonde map --joint) or another sphere size tells them apart")


def _material_edge(est: Any) -> str | None:
    """The warning that the data lean to the edge of the plate material's range, or None: the
    posterior mean of the material term (``material_shift_sd``, in the spread's standard
    deviations of E' = E / (1 - nu^2)) at :data:`MATERIAL_EDGE_SD` or beyond."""
    shift = est.extra.get("material_shift_sd")
    if not shift or abs(shift[0]) < MATERIAL_EDGE_SD:
        return None
    side = "stiffer" if shift[0] > 0 else "more compliant"
    return (f"the data sit at the edge of the material's range: they fit best with a plate "
            f"{side} than the table's (E' = E / (1 - nu^2) {abs(shift[0]):.2g} sd from it, on "
            "average over the answer), where the material's spread holds the answer only in "
            "part. Check the plate's grade; a table built for its material (solitonde table "
            "build --scene) or a calibration on a reference plate of it reads it exactly")


def default_spread_note(spread: Any) -> str | None:
    """The warning that a material given by its properties carries the default spread, or
    None (:data:`solitonde.model.materials.DEFAULT_PROPERTY_SPREAD`)."""
    from solitonde.model.materials import DEFAULT_PROPERTY_SPREAD, is_default_spread

    if spread is None or not is_default_spread(spread):
        return None
    e, nu, rho = (DEFAULT_PROPERTY_SPREAD[k] for k in ("youngs_modulus_rel_sd",
                                                        "poisson_ratio_sd", "density_rel_sd"))
    return (f"the plate material is given by its properties without their spread: the answer "
            f"carries the default spread of E +- {100 * e:.3g} %, nu +- {nu:.3g}, rho +- "
            f"{100 * rho:.3g} % (1 sd); state youngs_modulus_rel_sd, poisson_ratio_sd and "
            "density_rel_sd with the properties (0 where they are measured exactly)")


def _floor_mismatch(est: Any, floor_arr_max: float) -> str | None:
    """Why a clear measured reflection is unlike the family's floor-level one where the answer
    lies, or None."""
    explained = est.extra.get("strict_explained") or {}
    floor_mass = est.extra.get("floor_mass") or {}
    for item in est.inputs:
        if item.hidden or item.diameter_m not in explained:
            continue
        # the factor where the answer puts the chain (distance-dependent calibrations)
        where = answer_distance(est.distance_m)
        factor = (1.0 if est.calibration is None
                  else est.calibration.for_diameter(item.diameter_m)[0] if where is None
                  else float(est.calibration.along(item.diameter_m, where)[0]))
        _, s_arr = item.sigmas()
        level = factor * floor_arr_max
        if item.arr > level + FLOOR_Z * s_arr and explained[item.diameter_m] < STRICT_EXPLAINED:
            return (f"the reflection with D = {item.diameter_m * 1e3:.3g} mm is a clear one "
                    f"(ARR {item.arr:.3g}) but the answer rests on cells where the table's "
                    f"family has one at the detection floor (ARR below {level:.2g}; "
                    f"{100 * floor_mass[item.diameter_m]:.0f} % of the posterior's weight), and "
                    "without the looseness the table allows there no cell of the answer "
                    "explains it")
    return None


def _unexplained_exclusion(est: Any, floor_d_over_t: float, thinnest_m: float) -> str | None:
    """Why a sphere size the inversion left out (all sizes together were out of range, the
    others agree) is not the known case, or None. The known case is a large sphere on a thin
    plate, beyond D/t = ``floor_d_over_t``, whose "reflection" is a train at the detection floor;
    a size left out where the answer puts its reflection clear (D / t below that over the whole
    95 % interval) disagrees with the family itself. An interval with no lower end ("at most")
    runs down to the table's thinnest plate ``thinnest_m``: a 2.3 mm steel plate read against
    the aluminium table answered "at most 1.86 mm" with the 4.76 mm sphere left out, whose D/t
    stays below 3.2 over the whole table."""
    low = (est.thickness_m.ci95 or (None, None))[0]
    if low is None:
        low = thinnest_m
    for d in est.extra.get("excluded_diameters_m", []):
        if d / low <= floor_d_over_t:
            return (f"with the sphere size D = {d * 1e3:.3g} mm no table point explains the "
                    f"measurement, and the other sizes' answer (t >= {low * 1e3:.3g} mm, D/t <= "
                    f"{d / low:.2g}) is where that size's reflection is a clear one, not the "
                    "detection-floor train that may disagree")
    return None
