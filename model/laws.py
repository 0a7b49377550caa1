"""The contact laws and the dashpot step, each written once (the paper's Sec. 3.1 and 4.1.1).

Every driver (Verlet, fused leapfrog, DOPRI5, spectral-element and Green's-function plates) calls
these helpers instead of spelling the laws out. They are compiled with ``inline="always"``: numba
inlines them into the caller before the caller is optimised, so each call compiles exactly as
the text it replaces would, under the caller's own ``fastmath`` flags and error model. That keeps
vectorised loops vectorised and the numbers bit for bit what they were when the laws were
written inline. ``cache=True`` caches them for the (rare) direct calls from Python.

* Hertz (Eq. 1): ``F = A [delta]_+^(3/2)``, energy ``(2/5) A [delta]_+^(5/2)``; an open contact
  carries nothing (no tension). The force is written branch-free (``delta`` clamped at 0) so
  that loops over contacts vectorise; for any input it equals the branching form.
* Kuwabara-Kono (Brilliantov et al., Phys. Rev. E 53, 5382, 1996):
  ``F = [A delta^(3/2) + (3/2) A tau delta^(1/2) delta']_+`` for a closed contact; the clamp
  keeps a separating contact from pulling.
* Zener's dashpot (Sec. 4.1.1): ``w' = (A_b [u_N - w]_+^(3/2) - F_static) / Z``, one explicit
  midpoint step with u_N frozen.
"""

from __future__ import annotations

from math import sqrt

from numba import njit


@njit(cache=True, inline="always")
def hertz(a: float, delta: float) -> float:
    """Hertz force ``a delta^(3/2)`` for a closed contact, zero for an open one."""
    d = delta if delta > 0.0 else 0.0
    return a * d * sqrt(d)


@njit(cache=True, inline="always")
def hertz_energy(a: float, delta: float) -> float:
    """Elastic energy ``(2/5) a delta^(5/2)`` stored in a closed contact."""
    if delta > 0.0:
        return 0.4 * a * delta * delta * sqrt(delta)
    return 0.0


@njit(cache=True, inline="always")
def overlap_52(delta: float) -> float:
    """``[delta]_+^(5/2)``, branch-free: the Hertz energy without its constant ``(2/5) A``
    (for sums over contacts that share one A)."""
    d = delta if delta > 0.0 else 0.0
    return d * d * sqrt(d)


@njit(cache=True, inline="always")
def kuwabara_kono(a: float, tau: float, delta: float, rate: float) -> tuple[float, float]:
    """(force, dissipated power) of a damped contact at overlap ``delta`` closing at ``rate``.

    The power is the viscous force times the approach rate, ``(F - A delta^(3/2)) delta'``; it is
    >= 0 because the clamp only removes pulling force. An open contact gives (0, 0).
    """
    if delta > 0.0:
        sd = sqrt(delta)
        el = a * delta * sd
        total = el + 1.5 * a * tau * sd * rate
        if total < 0.0:
            total = 0.0
        return total, (total - el) * rate
    return 0.0, 0.0


@njit(cache=True, inline="always")
def sphere_contact(a: float, tau: float, delta: float, rate: float) -> float:
    """Force of a sphere-sphere contact: Kuwabara-Kono when ``tau > 0``, else elastic Hertz."""
    if tau > 0.0:
        return kuwabara_kono(a, tau, delta, rate)[0]
    return hertz(a, delta)


@njit(cache=True, inline="always")
def dashpot_step(
    w: float, u_n: float, f_now: float, a_b: float, f_static: float, inv_z: float, h: float
) -> float:
    """Explicit midpoint step of ``w' = (A_b [u_N - w]_+^1.5 - F_static) / Z`` over h (u_N frozen).

    ``f_now`` is the bottom force at (u_N, w), which callers usually have at hand. Second order,
    like the Strang splitting around it; the time step keeps ``h k_b / Z`` small (see
    :func:`solitonde.model.plan.choose_time_step`).
    """
    k1 = (f_now - f_static) * inv_z
    k2 = (hertz(a_b, u_n - w - 0.5 * h * k1) - f_static) * inv_z
    return w + h * k2
