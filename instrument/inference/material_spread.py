"""The plate material's spread in the features: a linearised term from Zener's scaling.

A table holds the features of one plate material, but a user knows their plate's E, nu and rho
only to the spread of its grade (:data:`solitonde.model.materials.SPREAD_KEYS`). Rebuilding
tables over material axes would multiply their cost; instead the features' sensitivity to the
material is taken from the table's own slopes, through how the physics trades material against
thickness and distance (the paper's Sec. 4.1, Zener's sphere-on-plate impact):

* The plate meets the last sphere as Zener's dashpot of impedance ``Z = 8 sqrt(rho t D_p)`` with
  ``D_p = E t^3 / (12 (1 - nu^2))``, behind the Hertz spring ``A_p`` whose effective modulus
  mixes sphere and plate (``1/E* = (1 - nu_s^2)/E_s + (1 - nu_p^2)/E_p``). ARR and the contact
  part of TOF follow the inelasticity ``lambda = A_p^(2/5) m^(3/5) v^(1/5) / Z`` (Eq. 6), which
  goes as ``t^-2``: a material change ``d ln lambda`` acts as a thickness change
  ``d ln t = -d ln lambda / 2``, read off the table's slope along ln t.
* The contact time also scales with ``T_0 ~ A_p^(-2/5)`` (Eq. 7) at fixed lambda: TOF moves by
  ``-0.4 T_c d ln A_p``, with ``T_c`` Zener's contact time for the table's chain.
* Near a support the guided waves return after a time ~ L / c with
  ``c ~ sqrt(E / (rho (1 - nu^2)))``: a material change acts as a distance change
  ``d ln L = -d ln c``, read off the table's slope along L.

E and nu act only through ``E' = E / (1 - nu^2)``, so each feature gets a row
``J = dF / d(ln E', ln rho)`` per fine cell; times the spread it is a low-rank (2) covariance
shared by every feature and sphere size of a measurement (one plate, one material), which the
inversion adds to its per-term variances exactly (Woodbury), not as independent terms (that
would count the one material error once per feature and shrink it as sizes are added). Linear
is enough: a grade's spread is a few percent, over which the table's features are smooth in
ln t and L.

Where the table carries its simulated slopes (:mod:`solitonde.instrument.tables.material_slopes`,
written by ``table build`` and ``table slopes``), the contact's share far from the supports is
taken from them instead: the chain's reflection also depends on the plate's contact stiffness
against the chain's own, which lambda leaves out, and the exchange rates fell short by up to
24 % in TOF and 15 % in ARR against an independent solve of the chain at 1.98-6.0 mm on steel
(the simulated slopes: within 1.5 % and 3 %; tests/instrument/test_material_slopes.py). Near a
support the distance's share stays the exchange rates' (within 20 mm of the clamp they overstate
the slopes, by up to 2.5 times in ARR: the intervals there are wider than they need be, not
narrower). Why not a material axis or a marginal over nearby families: a material axis
multiplies a build's cost by its points near the supports (the meshed plate, about a second a
point), and a marginal over the grade's box does not cover a plate at its corner either (the
data do not tell the material from the thickness: docs/explanation/inversion.md); far from the
supports the slopes cost 4 runs a node.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, TypedDict

import numpy as np

from solitonde.instrument.inference.model_error import single_precision
from solitonde.instrument.tables.table import ModelTable

SPREAD_ORDER = ("youngs_modulus_rel_sd", "poisson_ratio_sd", "density_rel_sd")
"""The three spread components, in the order of J's columns (d ln E, d nu, d ln rho)."""


def _plane_compliance(props: Mapping[str, Any]) -> float:
    return (1.0 - float(props["poisson_ratio"]) ** 2) / float(props["youngs_modulus"])


def _contact_time(table: ModelTable, diameter_m: float, thickness_m: np.ndarray) -> np.ndarray:
    """Zener's contact time T_c (s) of the table's chain on its plate, per thickness."""
    from solitonde.model import zener
    from solitonde.model.scene import apply_overrides, scene_from_dict

    base = (table.provenance or {}).get("scene_defaults") or table.sweep.get("scene") or {}
    t_ref = float(thickness_m[len(thickness_m) // 2])
    scene = scene_from_dict(apply_overrides(dict(base), {"chain.diameter": diameter_m,
                                                         "plate.thickness": t_ref}))
    v_in = zener.incident_velocity(scene)
    lam_ref = zener.inelasticity(scene)
    _, tau_c = zener.restitution_and_contact_time_many(lam_ref * (t_ref / thickness_m) ** 2)
    return np.asarray(tau_c) * zener.time_scale(scene.sphere_mass, scene.a_p, v_in)


class ExchangeRates(TypedDict):
    """What a plate material change does (:func:`exchange_rates`); each pair is per
    ``(d ln E', d ln rho)``."""

    contact_share: float
    d_ln_lambda: tuple[float, float]
    d_ln_c: tuple[float, float]


def exchange_rates(plate: Mapping[str, Any], sphere: Mapping[str, Any]) -> ExchangeRates:
    """How a plate material change ``(d ln E', d ln rho)`` moves Zener's inelasticity
    (``d_ln_lambda``) and the guided waves' speed (``d_ln_c``), and the plate's share ``w`` of
    the contact compliance (``d ln A_p = w d ln E'``); E' = E / (1 - nu^2)."""
    c_p, c_s = _plane_compliance(plate), _plane_compliance(sphere)
    w = c_p / (c_p + c_s)
    # lambda ~ A_p^(2/5) / Z, Z ~ t^2 sqrt(rho E'): d ln lambda = 0.4 w d ln E' - 0.5 (d ln E' +
    # d ln rho); c ~ sqrt(E' / rho)
    return {"contact_share": w, "d_ln_lambda": (0.4 * w - 0.5, -0.5), "d_ln_c": (0.5, -0.5)}


def sensitivity(table: ModelTable, grid: Any, spread: Mapping[str, float],
                floor_rule: tuple[float, float] | None = None
                ) -> tuple[np.ndarray, np.ndarray] | None:
    """The material's covariance factors for one sphere size (``grid``, its
    :class:`~.inversion.FineGrid`; not imported, as the inversion imports this module):
    ``(U_tof, U_arr)``, each of shape (2, n_t, n_l) (component first, for fast arithmetic over
    the grid), ``U = J * sd`` over the two directions the material acts through, ``d ln E'`` (E'
    = E / (1 - nu^2), whose sd combines E's and nu's) and ``d ln rho``: the features' material
    covariance between two terms is ``U_a . U_b``. None when the spread is zero or the table
    records no family.

    ``floor_rule`` (the inversion's ``(REFLECTION_D_OVER_T, FLOOR_ARR_MAX)``): thickness nodes
    beyond that D/t whose far reflection is weaker than that ARR keep the exchange rates.

    Rounded to single precision (:func:`~.model_error.single_precision`); cached on the table
    per sphere size, spread and floor rule.
    """
    sd = np.array([float(spread.get(k) or 0.0) for k in SPREAD_ORDER])
    family = table.family
    if not sd.any() or not family:
        return None
    key = f"material:{grid.diameter_m}:{tuple(sd)}:{floor_rule}"
    cached = table._cache.get(key)
    if cached is not None:
        return cached
    plate, sphere = family["plate_material"], family["sphere_material"]
    nu = float(plate["poisson_ratio"])
    k_nu = 2.0 * nu / (1.0 - nu**2)  # d ln E' / d nu, E' = E / (1 - nu^2)
    # E and nu act only through E' = E / (1 - nu^2): two independent directions remain,
    # d ln E' (sd from E's and nu's spreads) and d ln rho
    sd2 = np.array([math.hypot(sd[0], k_nu * sd[1]), sd[2]])
    rates = exchange_rates(plate, sphere)
    w = rates["contact_share"]
    d_ln_e_prime = np.array([1.0, 0.0])  # per (d ln E', d ln rho)
    d_ln_lambda = np.array(rates["d_ln_lambda"])
    d_ln_c = np.array(rates["d_ln_c"])
    log_t = np.log(grid.thickness_m)
    ok = grid.valid
    near = ok.copy()  # a slope across a cell without features is not one
    near[1:] &= ok[:-1]
    near[:-1] &= ok[1:]
    near[:, 1:] &= ok[:, :-1]
    near[:, :-1] &= ok[:, 1:]
    out = []
    t_c = _contact_time(table, grid.diameter_m, grid.thickness_m)[:, None]
    simulated = table.material_slopes
    i_d = table.diameter_index(grid.diameter_m)
    floor = np.zeros(table.axes["thickness_m"].size, dtype=bool)
    if simulated is not None and floor_rule is not None:
        # a floor-level "reflection" (a train the detector picks differently run to run) has no
        # slope to speak of: there the exchange rates stand, and the inversion's floor looseness
        d_over_t, arr_max = floor_rule
        far_arr = table.features["arr"][i_d][:, -1]
        floor = (grid.diameter_m / table.axes["thickness_m"] > d_over_t) & ~(far_arr >= arr_max)
    for name, values, explicit in (("tof_s", grid.tof_s, True), ("arr", grid.arr, False)):
        slope_t = np.gradient(values, log_t, axis=0) if log_t.size > 1 else np.zeros_like(values)
        slope_l = (np.gradient(values, grid.distance_m, axis=1) if grid.distance_m.size > 1
                   else np.zeros_like(values))
        jac = (slope_t[..., None] * (-0.5 * d_ln_lambda)
               + (slope_l * grid.distance_m[None, :])[..., None] * (-d_ln_c))
        if explicit:
            jac += (-0.4 * w * t_c)[..., None] * d_ln_e_prime
        if simulated is not None:
            # the contact's share as simulated far from the supports, where the exchange rates
            # leave out the chain's own contact; near a support the distance's share stays
            jac += _far_correction(np.where(floor[:, None], np.nan, simulated[name][i_d]),
                                   table.axes["thickness_m"], log_t, jac[:, -1, :])[:, None, :]
        jac[~near] = 0.0
        out.append(single_precision(np.ascontiguousarray(np.moveaxis(jac * sd2, -1, 0))))
    result = (out[0], out[1])
    table._cache[key] = result
    return result


def _far_correction(nodes: np.ndarray, t_nodes: np.ndarray, log_t: np.ndarray,
                    rates_far: np.ndarray) -> np.ndarray:
    """Per fine thickness, the simulated slopes far from the supports (``nodes``, (t, 2), NaN
    where a run showed no reflection) less the exchange rates' there (``rates_far``): zero where
    no simulated slope brackets the thickness."""
    out = np.zeros_like(rates_far)
    for k in range(nodes.shape[1]):
        ok = np.isfinite(nodes[:, k])
        if ok.sum() < 2:
            continue
        x = np.log(t_nodes[ok])
        inside = (log_t >= x[0]) & (log_t <= x[-1]) & np.isfinite(rates_far[:, k])
        out[inside, k] = np.interp(log_t[inside], x, nodes[ok, k]) - rates_far[inside, k]
    return out


def spread_of(table: ModelTable, plate_material: Any = None) -> dict[str, float]:
    """The plate's spread for an inversion on ``table``: ``plate_material``'s where the caller
    names one (a library grade's, the one a property mapping states, or for properties alone
    the stated default: :data:`solitonde.model.materials.DEFAULT_PROPERTY_SPREAD`), else that of
    the table's plate material by the same rules."""
    from solitonde.model.materials import material_spread

    if plate_material is not None:
        return material_spread(plate_material)
    family = table.family
    if not family or not family["plate_material"]:
        return dict.fromkeys(SPREAD_ORDER, 0.0)
    return material_spread(family["plate_material"])


def spread_source(table: ModelTable) -> str:
    """Where the table's plate material spread comes from: ``library`` (a library grade's),
    ``stated`` (with the properties), ``default`` (properties alone: the stated default) or
    ``none`` (the table records no plate material)."""
    from solitonde.model.materials import is_default_spread

    plate = table.family["plate_material"] if table.family else None
    if not plate:
        return "none"
    if isinstance(plate, Mapping) and any(plate.get(k) is not None for k in SPREAD_ORDER):
        return "stated"
    return "default" if is_default_spread(spread_of(table)) else "library"


def describe_spread(spread: Mapping[str, float]) -> str:
    """The spread in words (for reasons and docs)."""
    e, nu, rho = (float(spread.get(k) or 0.0) for k in SPREAD_ORDER)
    return f"E +- {100 * e:.3g} %, nu +- {nu:.3g}, rho +- {100 * rho:.3g} % (1 sd)"


__all__ = ["SPREAD_ORDER", "describe_spread", "exchange_rates", "sensitivity", "spread_of",
           "spread_source"]
