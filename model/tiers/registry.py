"""The plate models ("tiers") by name, what each can do, and which one a scene runs with.

Every tier is listed here once, from the module that holds it (:mod:`.dashpot`, :mod:`.meshed`),
with its capabilities as attributes (:class:`~.base.Tier`); the name lists other modules need
(the tiers the adaptive integrator can run, the meshed ones, the convolved ones) are asked of
the registry (:func:`names_with`), never written out. ``auto`` is decided in one place,
:func:`resolve_plate_model`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..errors import SceneError
from ..scene import PLATE_MODELS, Scene
from . import dashpot, meshed
from .base import BottomBoundary, Tier

if TYPE_CHECKING:
    from ..greens import GreensCache

TIERS: dict[str, Tier] = {t.name: t for t in (*dashpot.TIERS, *meshed.TIERS)}
"""Every plate model, by its ``effects.plate_model`` name."""

if set(TIERS) != set(PLATE_MODELS) - {"auto"}:  # the scene's schema lists the names it accepts
    raise RuntimeError(f"plate models registered {sorted(TIERS)} differ from the scene's "
                       f"{sorted(PLATE_MODELS)}")


def names_with(**capabilities: bool) -> tuple[str, ...]:
    """The tiers whose capabilities (:class:`~.base.Tier` attributes: ``static``, ``dopri5``,
    ``meshed``, ``convolved``) have the values given, in registry order."""
    return tuple(name for name, tier in TIERS.items()
                 if all(getattr(tier, key) == value for key, value in capabilities.items()))


#: Plate models whose plate never moves: their auto duration uses lambda = 0.
STATIC_PLATE_MODELS = names_with(static=True)
#: Plate models that ``solver.integrator = "dopri5"`` can run (the ODE tiers).
DOPRI5_PLATE_MODELS = names_with(dopri5=True)
#: Plate models on a mesh: 3-D spectral elements or Mindlin, stepped or convolved.
MESHED_PLATE_MODELS = names_with(meshed=True)
#: The meshed models that convolve a cached contact response.
CONVOLVED_PLATE_MODELS = names_with(convolved=True)


#: The smallest sphere-diameter-to-thickness ratio at which the Mindlin plate was measured within
#: the table budget (1 % TOF, 5 % ARR) of the 3-D plate on the same mesh (``solitonde bench
#: plates``: D 4.76-19.05 mm, t 1.5-9.53 mm, so D/t 0.5-12.7, L 0-457 mm, aluminium, steel and
#: titanium). Below it (a plate thick against the sphere) ``auto`` keeps the 3-D plate: not known
#: to fail there, but not measured. There is no upper end: a larger D/t is a plate thinner
#: against the flexural waves the contact drives (k t ~ sqrt(f t), and f falls as D grows), where
#: a plate theory only gets better.
MINDLIN_MIN_D_OVER_T = 0.5


def resolve_plate_model(scene: Scene) -> tuple[str, str]:
    """The plate model a scene runs with and why (the one place where ``auto`` is decided).

    ``auto``: the infinite plate (Zener dashpot) when the chain is farther from the nearest plate
    edge than ``sem.auto_margin`` times the critical distance L_c (Eq. 18, k = 0.57), since no
    guided wave then returns during contact; otherwise a finite plate's Green's function, of the
    Mindlin plate (``mindlin_greens``) or of the 3-D plate (``greens``), as ``sem.plate_theory``
    says (its ``auto``: Mindlin from :data:`MINDLIN_MIN_D_OVER_T` up).
    """
    requested = scene.effects.plate_model
    if requested != "auto":
        return requested, f"requested by effects.plate_model={requested}"
    from ..zener import critical_distance

    l_c = critical_distance(scene, k=0.57)
    limit = scene.sem.auto_margin * l_c
    edge = nearest_edge_distance(scene)
    if edge > limit:
        return "infinite", (
            f"auto: the nearest plate edge is {edge * 1e3:.1f} mm away, beyond "
            f"{scene.sem.auto_margin:g} x L_c = {limit * 1e3:.1f} mm (Eq. 18, k = 0.57): "
            "no reflection returns during contact, so the infinite plate (Zener dashpot) applies"
        )
    near = (f"auto: the nearest plate edge is {edge * 1e3:.1f} mm away, within "
            f"{scene.sem.auto_margin:g} x L_c = {limit * 1e3:.1f} mm (Eq. 18, k = 0.57): guided "
            "waves return during contact, so a finite plate's Green's function is used")
    theory = scene.sem.plate_theory
    if theory != "auto":
        name = "mindlin_greens" if theory == "mindlin" else "greens"
        return name, f"{near}; {name} as sem.plate_theory={theory} asks"
    ratio = scene.chain.diameter / scene.plate.thickness
    if ratio >= MINDLIN_MIN_D_OVER_T * (1.0 - 1e-9):
        return "mindlin_greens", (
            f"{near}; the Mindlin plate (mindlin_greens): D/t = {ratio:.2f} is at least "
            f"{MINDLIN_MIN_D_OVER_T:g}, where it was measured within 1 % TOF and 5 % ARR of the "
            "3-D plate")
    return "greens", (
        f"{near}; the 3-D plate (greens): D/t = {ratio:.2f} is below {MINDLIN_MIN_D_OVER_T:g}, "
        "the smallest at which the Mindlin plate was measured against it")


def nearest_edge_distance(scene: Scene) -> float:
    """Distance from the chain (x = L on the centre line y = Ly/2) to the nearest plate edge, m.

    Every edge reflects, clamped or free, so all four count whatever ``plate.supports`` says.
    """
    lx, ly = scene.plate.size
    x = scene.plate.distance_to_support
    return float(min(x, lx - x, ly / 2.0))


def make_boundary(scene: Scene, resolved: tuple[str, str] | None = None,
                  greens_cache: GreensCache | None = None) -> BottomBoundary:
    """Build the bottom boundary of a scene, resolving ``auto`` (unless ``resolved`` already
    holds :func:`resolve_plate_model`'s answer); ``greens_cache`` serves the ``greens`` tier."""
    name, reason = resolved if resolved is not None else resolve_plate_model(scene)
    tier = TIERS.get(name)
    if tier is None:
        raise SceneError(
            "effects.plate_model",
            f"plate model {name!r} is not available in this build",
            allowed=", ".join([*sorted(TIERS), "auto"]),
        )
    return tier.build(scene, reason, greens_cache)


