"""The meshed plate models as bottom boundaries of the chain: ``sem``, ``greens``, ``mindlin``,
``mindlin_greens``.

``sem`` advances the chain and a 3-D spectral-element plate together, one velocity-Verlet step for
both (central differences for the plate); ``greens`` replaces the plate by the convolution with
its cached contact response (:mod:`solitonde.model.greens`). ``mindlin`` and ``mindlin_greens``
do the same with the Mindlin-Reissner plate (:mod:`solitonde.model.mindlin`) on the same in-plane
mesh machinery. All build their plate from the scene's ``plate`` and ``sem`` sections, and all
share the step: the chain's own step or the plate's stable step times ``sem.step_factor``,
whichever is smaller, on the sample grid.
"""

from __future__ import annotations

import math
import time
from functools import lru_cache

import numpy as np

from ..errors import SceneError
from ..greens import (
    GreensCache,
    contact_response,
    first_load_step,
    integrate_greens,
    response_steps,
    stored_response,
)
from ..materials import Material
from ..mesh import plate_mesh
from ..mindlin import MindlinPlate, build_mindlin_plate
from ..record import ChainRecord
from ..scene import Scene
from ..sem import ElasticPlate, build_plate, single_threaded_blas
from ..sem_kernels import SemPlate, integrate_sem
from ..status import RUN_SHORT_RESPONSE
from .base import BottomBoundary, ChainRun, StepPlan, Tier


@lru_cache(maxsize=8)
def _plate_cached(
    size: tuple[float, float], thickness: float, elements: tuple[int, int, int],
    order: tuple[int, int, int], contact_x: float, symmetry: bool, material: Material,
    supports: str, contact_radius: float = 0.0, contact_refinement: float = 0.0,
    theory: str = "3d",
) -> ElasticPlate | MindlinPlate:
    mesh = plate_mesh(size, thickness, elements, order, contact_x, symmetry, contact_radius,
                      contact_refinement)
    if theory == "mindlin":
        return build_mindlin_plate(mesh, material, supports)
    return build_plate(mesh, material, supports)


def forget_plates() -> None:
    """Drop the plates kept for reuse in this process (:func:`plate_for`), so that the next run
    of each builds its plate again, as a fresh worker process does (a pilot's timing)."""
    _plate_cached.cache_clear()


def contact_radius(scene: Scene) -> float:
    """The contact patch radius r_c of a scene, m (0 for the 'paper' preset).

    'auto' is the plate thickness t. Why: Hertz's A_p already holds the plate material's local
    (half-space) indentation, which is the 3D field within about t of the contact; beyond about
    t the plate answers as a plate. Loading a patch of radius t and reading the deflection as
    its weighted mean leaves the plate's bending and shear response (smooth on the scale of t,
    and t is far below the A0 wavelength of the contact, ~50 mm) while keeping only a small,
    mesh-independent share of the local half-space compliance that A_p counts already (about
    (1 - nu^2) / (E r_c); it grows as r_c shrinks: for D = 9.53 mm at the centre of a 3.18 mm
    plate ARR is 0.295, 0.282, 0.273 for r_c = t/4, t/2, t, and Zener's plate gives 0.273).
    """
    if scene.sem.preset == "paper":
        return 0.0
    rc = scene.sem.contact_radius
    radius = float(scene.plate.thickness) if rc == "auto" else float(rc)
    limit = 0.1 * min(float(v) for v in scene.plate.size)
    if radius > limit:
        raise SceneError("sem.contact_radius", f"{radius} m is too large for a "
                         f"{list(scene.plate.size)} m plate", f"0..{limit:g} m or 'auto'")
    return radius


def flexural_wavelength(scene: Scene) -> float:
    """The Kirchhoff A0 wavelength at the top of the incident pulse's band, m.

    The solitary wave is about 5 D long and passes at V_s (Eq. 12), so its force lasts about
    5 D / V_s; f = V_s / (2.5 D), twice the inverse of that, bounds the band the plate is driven
    in. Kirchhoff's A0 is a little faster than Mindlin's at these frequencies, so this wavelength
    is a little longer than the plate's own; ``sem.elements_per_wavelength`` (1 by default; its
    convergence is in the README, "Where a 2-D plate suffices") allows for it.
    """
    from ..lamb import kirchhoff_phase_velocity
    from ..zener import incident_velocity, solitary_wave_speed

    d = scene.chain.diameter
    v_s = solitary_wave_speed(d, scene.a_s, scene.sphere_mass, incident_velocity(scene))
    f = v_s / (2.5 * d)
    return float(kirchhoff_phase_velocity(f, scene.plate.thickness, scene.plate_material)) / f


def mindlin_elements(scene: Scene) -> tuple[int, int, int]:
    """The Mindlin plate's nominal element counts: ``sem.elements``, raised where the plate is
    thin enough that the flexural wavelength needs more (``sem.elements_per_wavelength``).

    A thin plate's reflections from the support travel as short flexural waves; on the 3-D
    plate's default 16 x 16 mesh (57 mm elements on the paper's plate) they are under-resolved
    below about 2 mm, in either plate theory. The 2-D plate can afford the elements.
    """
    s = scene.sem
    per = float(s.elements_per_wavelength)
    if per <= 0.0 or s.preset == "paper":
        return int(s.elements[0]), int(s.elements[1]), int(s.elements[2])
    size = per / flexural_wavelength(scene)
    return (max(int(s.elements[0]), math.ceil(scene.plate.size[0] * size)),
            max(int(s.elements[1]), math.ceil(scene.plate.size[1] * size)), int(s.elements[2]))


def coarse_3d_note(scene: Scene) -> str | None:
    """Why the 3-D plate of ``scene`` may be too coarse, or None: its ``sem.elements`` (taken as
    given) are fewer than the flexural-wavelength rule asks of the Mindlin plate
    (:func:`mindlin_elements`). On such a mesh a thin plate's reflection can be off by tens of
    percent: a 1.99 mm plate 47 mm from the clamp read ARR 0.110 on the default elements, 0.080
    on 51 x 25."""
    given = tuple(int(n) for n in scene.sem.elements[:2])
    wanted = mindlin_elements(scene)[:2]
    if all(w <= g for w, g in zip(wanted, given, strict=True)):
        return None
    return (f"the 3-D plate's sem.elements {given[0]} x {given[1]} are fewer than the "
            f"flexural-wavelength rule gives this plate ({wanted[0]} x {wanted[1]}, the Mindlin "
            "plate's count): its waves away from the chain may be under-resolved (a 1.99 mm "
            "plate 47 mm from the clamp read ARR 0.110 on 16 x 16, 0.080 resolved); "
            f"sem.elements [{wanted[0]}, {wanted[1]}, {int(scene.sem.elements[2])}] resolves "
            "them")


def plate_for(scene: Scene, theory: str = "3d") -> ElasticPlate | MindlinPlate:
    """The meshed plate of a scene, 3-D or Mindlin (kept for reuse within the process)."""
    p, s = scene.plate, scene.sem
    refinement: float = 0 if s.preset == "paper" else s.contact_refinement
    elements = tuple(s.elements)
    if theory == "mindlin":
        elements = mindlin_elements(scene)
        if s.preset != "paper":
            refinement = 2.0 / float(s.mindlin_element_size)
    try:
        return _plate_cached(
            (float(p.size[0]), float(p.size[1])), float(p.thickness), elements,
            tuple(s.order), float(p.distance_to_support), bool(s.symmetry), scene.plate_material,
            p.supports, contact_radius(scene), float(refinement), theory,
        )
    except ValueError as exc:  # the mesh cannot put a node under the chain (too coarse)
        raise SceneError("sem.elements", f"{exc} (plate.distance_to_support "
                         f"{p.distance_to_support} m, elements {list(s.elements)}, order "
                         f"{list(s.order)})", allowed="more elements or a higher order, so that "
                         "a GLL node can fall under the chain") from None


class _PlateTier(BottomBoundary):
    """Shared parts of the meshed tiers: the plate, its stable step, the reported diagnostics."""

    def __init__(self, name: str, scene: Scene, reason: str) -> None:
        self.name = name
        self.reason = reason
        self.a_bottom = scene.a_p
        theory = "mindlin" if name.startswith("mindlin") else "3d"
        self.plate = plate_for(scene, theory)
        self.coarse_note = coarse_3d_note(scene) if theory == "3d" else None
        self.step_factor = float(scene.sem.step_factor)
        # 2 / sqrt(max element eigenvalue) <= the true limit 2 / omega_max (element bound)
        self.dt_critical = 2.0 / np.sqrt(self.plate.element_bound)
        self.dt_plate = self.step_factor * self.dt_critical

    def steps(self, plan: StepPlan) -> tuple[float, int, int]:
        """(plate step h, chain steps per plate step r, plate steps per sample).

        The plate takes the largest step within ``step_factor`` of its stability limit that fits
        a whole number of times in a sample interval; the chain keeps at most the step it chose
        for itself (``plan.dt``), sub-cycled r times per plate step.
        """
        interval = plan.dt * plan.n_sub
        per_sample = max(1, int(np.ceil(interval / self.dt_plate * (1.0 - 1e-12))))
        r = max(1, -(-plan.n_sub // per_sample))
        return interval / per_sample, r, per_sample

    def _extra(self, h: float, r: int, per_sample: int, plan: StepPlan) -> dict[str, object]:
        mesh = self.plate.describe()
        if self.coarse_note is not None:
            mesh["coarse"] = self.coarse_note
        return {
            "mesh": mesh,
            "dt_s": h,
            "dt_stability_ratio": h / self.dt_critical,
            "dt_critical_s": self.dt_critical,
            "chain_dt_s": h / r,
            "chain_substeps": r,
            "plate_steps": per_sample * (plan.n_samples - 1),
            "steps": per_sample * r * (plan.n_samples - 1),
        }


class SemBoundary(_PlateTier):
    """Chain and spectral-element plate stepped together."""

    def integrate(self, record: ChainRecord, plan: StepPlan) -> ChainRun:
        plate = self.plate
        state = SemPlate(plate.inv_mass, plate.dof_mass, plate.operator,
                         plate.load_dofs, plate.load_weights, np.zeros(plate.n_dofs),
                         np.zeros(plate.n_dofs), float(plate.force_share))
        h, r, per_sample = self.steps(plan)
        start = time.perf_counter()
        status, done, w, e_plate, dissipated = integrate_sem(
            record, float(h), int(r), int(per_sample), int(plan.n_samples), state)
        wall = time.perf_counter() - start
        extra = self._extra(h, r, per_sample, plan)
        extra["plate_energy_J"] = e_plate
        return ChainRun(status, done, e_plate, dissipated, record.pk, wall, extra, w_end=w)


class GreensBoundary(_PlateTier):
    """Chain on the plate's cached contact response (convolution)."""

    def __init__(self, name: str, scene: Scene, reason: str,
                 cache: GreensCache | None = None) -> None:
        super().__init__(name, scene, reason)
        self.cache = cache

    def integrate(self, record: ChainRecord, plan: StepPlan) -> ChainRun:
        h, r, per_sample = self.steps(plan)
        n_plate = per_sample * (plan.n_samples - 1)
        args = (float(h), int(r), int(per_sample), int(plan.n_samples))
        probe = spent = wasted = 0.0
        cached = True
        # A stored response is run on at once: the run itself finds the first load, and a
        # response too short from there stops it, which only a chain loading the plate earlier
        # than the stored one's did can meet. Then it runs again as without one.
        response = stored_response(self.plate, h, self.cache)
        if response is not None:
            start_state = (record.u.copy(), record.v.copy(), record.pk.copy())
            status, done, w, plate_work, dissipated, wall = self._run(record, args, response)
            if status != RUN_SHORT_RESPONSE:
                return self._result(record, plan, status, done, w, plate_work, dissipated,
                                    wall, cached, spent, probe)
            for kept, state in zip(start_state, (record.u, record.v, record.pk), strict=True):
                state[:] = kept
            wasted = wall
        # the plate is at rest until the pulse reaches it: its response is needed from then on
        start = time.perf_counter()
        first = first_load_step(record, *args)
        probe = time.perf_counter() - start + wasted
        needed, spare = response_steps(first, n_plate)
        if first < 0:  # the pulse never reaches the plate within the record
            response, cached = np.zeros(1), False
        else:
            response, cached, spent = contact_response(self.plate, h, needed, self.cache, spare)
        status, done, w, plate_work, dissipated, wall = self._run(record, args, response)
        return self._result(record, plan, status, done, w, plate_work, dissipated, wall, cached,
                            spent, probe)

    @staticmethod
    def _run(record: ChainRecord, args: tuple[float, int, int, int], response: np.ndarray
             ) -> tuple[int, int, float, float, float, float]:
        """:func:`integrate_greens`' result and its seconds."""
        start = time.perf_counter()
        with single_threaded_blas():
            status, done, w, plate_work, dissipated = integrate_greens(record, *args, response)
        return status, done, w, plate_work, dissipated, time.perf_counter() - start

    def _result(self, record: ChainRecord, plan: StepPlan, status: int, done: int, w: float,
                plate_work: float, dissipated: float, wall: float, cached: bool, spent: float,
                probe: float) -> ChainRun:
        """The run with its diagnostics (what the response cost: computed, probed, read)."""
        h, r, per_sample = self.steps(plan)
        extra = self._extra(h, r, per_sample, plan)
        extra.update({"greens_cached": cached, "greens_compute_s": spent, "chain_wall_s": wall,
                      "greens_probe_s": probe})
        return ChainRun(status, done, plate_work, dissipated, record.pk, wall + spent + probe,
                        extra, w_end=w)


SEM_DOF_WEIGHT = 4.0
"""One 3-D spectral-element degree of freedom advanced one step costs about as much as 4 chain
particles advanced one step. Measured on one idle core: the chain (Verlet) 3.5e8-4.6e8
particle-steps/s; the coupled 3-D plate with the sum-factorised stiffness 3.9 chain
particle-steps a dof-step (a 3 mm plate 20 mm from the support, 29,889 dofs). The dense stiffness
this weight was first set for cost 25."""

MINDLIN_DOF_WEIGHT = 1.4
"""One Mindlin plate degree of freedom advanced one step, in chain particle-steps: its order-4
stiffness product runs 16 elements to a vector lane (:mod:`solitonde.model.mindlin_kernels`),
2.1-2.4 ns a dof-step. Measured on one idle core, coupled to the chain: 1.36 (a 3 mm plate 20 mm
from the support, 17,331 dofs)."""

TIERS = (
    Tier("sem", lambda scene, reason, cache: SemBoundary("sem", scene, reason), meshed=True,
         dof_weight=SEM_DOF_WEIGHT),
    Tier("greens", lambda scene, reason, cache: GreensBoundary("greens", scene, reason, cache),
         meshed=True, convolved=True, dof_weight=SEM_DOF_WEIGHT),
    Tier("mindlin", lambda scene, reason, cache: SemBoundary("mindlin", scene, reason),
         meshed=True, dof_weight=MINDLIN_DOF_WEIGHT),
    Tier("mindlin_greens",
         lambda scene, reason, cache: GreensBoundary("mindlin_greens", scene, reason, cache),
         meshed=True, convolved=True, dof_weight=MINDLIN_DOF_WEIGHT),
)
"""The meshed tiers, for :mod:`.registry`."""
