"""What every plate model ("tier") shares: the chain's record and time grid handed to it, what
its driver hands back, the :class:`BottomBoundary` interface, and a tier's record in the registry
(:class:`Tier`, its capabilities as attributes).

A new tier subclasses :class:`BottomBoundary`, gives it ``name``, ``reason`` and ``a_bottom``,
implements :meth:`BottomBoundary.integrate` (and :meth:`BottomBoundary.max_rate` if the plate has
a time scale of its own), and lists a :class:`Tier` in :mod:`.registry`. ``integrate`` receives
the chain's :class:`~solitonde.model.record.ChainRecord` (initial state, constants, preallocated
output arrays: the one record type, which the compiled drivers take too) and a
:class:`StepPlan` (dt, steps per sample, samples) and returns a :class:`ChainRun`. Its compiled
driver loop calls the kernels of :mod:`solitonde.model.chain` per step, as
:func:`~solitonde.model.tiers.dashpot.dashpot_steps_run` does:

    1. advance the plate by dt/2 with the chain frozen, book the work ``int F dw`` done on it,
       refresh the bottom force and ``acc[N]`` (:func:`~solitonde.model.chain.bottom_acceleration`);
    2. :func:`~solitonde.model.chain.verlet_step` with the plate frozen at w;
    3. advance the plate by the second dt/2 (merged with the next step's first half, except
       before a sample, where chain and plate must be at the same time);
    4. :func:`~solitonde.model.chain.track_peaks` each step and
       :func:`~solitonde.model.chain.record_sample` plus the energy balance every ``n_sub`` steps.

This Strang splitting keeps the chain update symplectic and the whole step second order; because
the plate moves while the chain is frozen, the work done on the plate in a sub-step is exactly the
drop of the bottom contact's elastic energy, so the energy balance stays exact up to the Verlet
error. A plate that must be stepped more finely (spectral elements) sub-cycles inside step 1 and 3.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ..record import ChainRecord

if TYPE_CHECKING:
    from ..greens import GreensCache
    from ..scene import Scene


@dataclass(frozen=True)
class StepPlan:
    """Time grid: ``n_sub`` steps of ``dt`` between samples, ``n_samples`` samples from t = 0.

    ``integrator`` "dopri5" (plate models in ``DOPRI5_PLATE_MODELS``) integrates
    adaptively to ``rtol`` instead (:mod:`~solitonde.model.dopri`; ``dt`` is then the sample
    interval, ``n_sub`` 1) within ``max_steps`` attempted steps.
    """

    dt: float
    n_sub: int
    n_samples: int
    integrator: str = "verlet"
    rtol: float = 1e-8  # SolverSpec.rtol's default
    max_steps: int = 20_000_000

    @property
    def steps(self) -> int:
        return self.n_sub * (self.n_samples - 1)


@dataclass
class ChainRun:
    """What a driver hands back (the record's arrays hold the sampled outputs); ``w_end`` is the
    plate's top surface under the chain at the end, m."""

    status: int
    samples_done: int
    plate_work: float
    dissipated: float
    peaks: np.ndarray
    wall_s: float
    extra: dict[str, Any] = field(default_factory=dict)
    w_end: float = 0.0


class BottomBoundary(ABC):
    """A plate model seen from the chain: a Hertz constant and a way to move the contact point."""

    name: str
    reason: str
    a_bottom: float

    def max_rate(self, bottom_stiffness: float) -> float:
        """Fastest rate (1/s) of the boundary's own dynamics at the given contact stiffness (N/m).

        The time step must resolve it; a static wall has none (0).
        """
        return 0.0

    @abstractmethod
    def integrate(self, record: ChainRecord, plan: StepPlan) -> ChainRun:
        """Advance chain and plate over ``plan`` from the plate at rest (w = 0), filling the
        record's output arrays and its peak tracker."""


TierFactory = Callable[["Scene", str, "GreensCache | None"], BottomBoundary]


@dataclass(frozen=True)
class Tier:
    """A plate model in the registry: its name, how to build its boundary, and what it can do.

    Attributes
    ----------
    name: the ``effects.plate_model`` value.
    build: ``build(scene, reason, greens_cache)`` makes the boundary (``greens_cache``: the
        plate-response cache, None for the process's; see :mod:`solitonde.model.greens`).
    static: the plate never moves (w = 0): a wall.
    dopri5: ``solver.integrator = "dopri5"`` can run it (an ODE tier).
    meshed: the plate is a mesh (3-D spectral elements or Mindlin).
    convolved: the meshed plate is a cached contact response, convolved with the force.
    dof_weight: what one plate degree of freedom advanced one step costs, in chain
        particle-steps (a run's price, :func:`solitonde.model.plan.plan`); 0 without a mesh.
    """

    name: str
    build: TierFactory
    static: bool = False
    dopri5: bool = False
    meshed: bool = False
    convolved: bool = False
    dof_weight: float = 0.0
