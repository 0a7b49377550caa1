"""What every plate model ("tier") shares: the chain's setup and time grid handed to it, what
its driver hands back, the :class:`BottomBoundary` interface, and a tier's record in the registry
(:class:`Tier`, its capabilities as attributes).

A new tier subclasses :class:`BottomBoundary`, gives it ``name``, ``reason`` and ``a_bottom``,
implements :meth:`BottomBoundary.integrate` (and :meth:`BottomBoundary.max_rate` if the plate has
a time scale of its own), and lists a :class:`Tier` in :mod:`.registry`. ``integrate`` receives a
:class:`ChainSetup` (initial state, constants, preallocated output arrays) and a :class:`StepPlan`
(dt, steps per sample, samples) and returns a :class:`ChainRun`. Its compiled driver loop calls
the kernels of :mod:`solitonde.model.chain` per step, as
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

from ..record import ChainRecord, chain_record

if TYPE_CHECKING:
    from ..greens import GreensCache
    from ..scene import Scene


@dataclass
class ChainSetup:
    """Everything a driver needs about the chain; arrays are modified in place by the run.

    Attributes
    ----------
    u, v: displacements (down, m) and velocities (m/s) of particles 0..N (0 = striker).
    w: initial top-surface deflection of the plate under the chain, m.
    m: particle mass, kg. g: gravity, m/s^2 (0 when gravity is off).
    a_s: sphere-sphere Hertz constant, N/m^1.5. a_b: bottom contact constant, N/m^1.5.
    f_static: static force the bottom contact carries at the start, N (N m g, or 0).
    tau: Kuwabara-Kono dissipative time, s (0: elastic).
    sensor: sensor particle, 1..N.
    samples, energy: outputs per sample (sensor force N, energy balance J).
    u_trace, v_trace, f_trace, w_trace: per-sample fields, zero rows when traces are off.
    m0, a_0: the striker's mass and its contact constant with particle 1 (None: a chain sphere).
    """

    u: np.ndarray
    v: np.ndarray
    w: float
    m: float
    g: float
    a_s: float
    a_b: float
    f_static: float
    tau: float
    sensor: int
    samples: np.ndarray
    energy: np.ndarray
    u_trace: np.ndarray
    v_trace: np.ndarray
    f_trace: np.ndarray
    w_trace: np.ndarray
    m0: float | None = None
    a_0: float | None = None


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
    """What a driver hands back (the arrays of the setup hold the sampled outputs)."""

    status: int
    samples_done: int
    plate_work: float
    dissipated: float
    peaks: np.ndarray
    wall_s: float
    extra: dict[str, Any] = field(default_factory=dict)


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
    def integrate(self, setup: ChainSetup, plan: StepPlan) -> ChainRun:
        """Advance chain and plate over ``plan``, filling the setup's output arrays."""


def setup_record(setup: ChainSetup, peaks: np.ndarray) -> ChainRecord:
    """The compiled drivers' view of a setup: its arrays (shared) and constants, u0 a copy of u."""
    return chain_record(
        setup.u, setup.v, setup.u.copy(), setup.m, setup.g, setup.a_s, setup.a_b, setup.f_static,
        setup.tau, setup.sensor, setup.samples, setup.energy, setup.u_trace, setup.v_trace,
        setup.f_trace, setup.w_trace, peaks, setup.m0, setup.a_0,
    )


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
    """

    name: str
    build: TierFactory
    static: bool = False
    dopri5: bool = False
    meshed: bool = False
    convolved: bool = False
