"""Which of a position's repeated shots is an outlier: modified z-scores and the level, per number
of shots, above which one is rejected.

Iglewicz and Hoaglin's modified z-score, ``0.6745 |x - median| / MAD``, reads as a number of
standard deviations on Gaussian data, and their level of 3.5 suits large samples. A lab repeats
a shot three to ten times, and there the MAD of so few values is itself a wild estimate: on good
shots (Gaussian, no outlier) a fixed 3.5 rejected at least one shot, on TOF or ARR, in 31 % of
sets of 4, 37 % of 5 and 23 % of 10. Each such rejection throws away a good reading and, on
average, narrows the stated scatter (a sample variance kept at 0.82 of the true one for sets of
5). So the level depends on the number of shots: it is the score that the largest of ``n`` good
shots' scores exceeds in ``1 - sqrt(0.99)`` of sets, so that a set read on two independent
features loses a good shot in 1 % of sets (:data:`LEVELS`, by Monte Carlo:
``tests/support/outlier_levels.py``). A misread shot (the reflection taken on a secondary pulse)
lies tens to hundreds of standard deviations off and is still rejected; a shot a few standard
deviations off, among few, stays in and widens the stated scatter instead, which is what its
evidence supports.
"""

from __future__ import annotations

import math
from statistics import NormalDist
from typing import Literal

import numpy as np

REJECTION_RATE = 0.01
"""Sets of good shots (TOF and ARR read) that lose a shot to the outlier test."""
PER_FEATURE_RATE = 1.0 - math.sqrt(1.0 - REJECTION_RATE)
"""The same for one feature: two independent features give :data:`REJECTION_RATE`."""

LEVELS: dict[int, float] = {
    4: 22.7, 5: 26.6, 6: 12.8, 7: 13.7, 8: 9.63, 9: 9.99, 10: 8.12, 11: 8.39, 12: 7.29,
    13: 7.4, 14: 6.69, 15: 6.79, 16: 6.32, 17: 6.38, 18: 6.04, 19: 6.07, 20: 5.81, 21: 5.83,
    22: 5.63, 23: 5.66, 24: 5.48, 25: 5.51, 26: 5.39, 27: 5.4, 28: 5.28, 29: 5.28, 30: 5.2,
    31: 5.2, 32: 5.14, 33: 5.15, 34: 5.06, 35: 5.08, 36: 5.01, 37: 5.03, 38: 4.98, 39: 4.98,
    40: 4.93,
}
"""The modified z-score above which one of ``n`` shots is rejected, for n = 4 to 40: the
``1 - PER_FEATURE_RATE`` quantile of the largest of n Gaussian values' scores (a million sets
per n). An odd n's level lies above its even neighbours': the median is then one of the values,
one deviation is 0 and the MAD smaller."""
MIN_SHOTS = min(LEVELS)
"""Fewer shots than this are never tested: with three, any one of them can look like the odd
one out."""
FLAT_LEVEL = 3.5
"""The level where more than half the values are equal (MAD 0; the score then uses the mean
absolute deviation, which no set of Gaussian values produces): Iglewicz and Hoaglin's."""


def level(n: int) -> float:
    """The modified z-score above which one of ``n`` (at least :data:`MIN_SHOTS`) shots is an
    outlier. Beyond the table, the larger of its last level and the level the MAD would need if
    it were exact (the Gaussian's two-sided quantile for ``n`` values): the rate stays under
    :data:`REJECTION_RATE` (0.45 % at 60 shots) and tends to it as the MAD settles (from a few
    thousand shots on)."""
    if n < MIN_SHOTS:
        raise ValueError(f"the outlier level needs at least {MIN_SHOTS} shots, got {n}")
    if n in LEVELS:
        return LEVELS[n]
    per_value = -math.expm1(math.log1p(-PER_FEATURE_RATE) / n)
    return max(LEVELS[max(LEVELS)], NormalDist().inv_cdf(1.0 - per_value / 2.0))


def cutoff(asked: float | Literal["auto"], n: int, flat: bool) -> tuple[float, str]:
    """The score above which one of ``n`` shots is rejected, and the reason a rejected one
    states: the level ``asked`` for, or with ``"auto"`` :func:`level` (:data:`FLAT_LEVEL` where
    :func:`modified_z` fell back on the mean absolute deviation, ``flat``)."""
    if asked != "auto":
        return asked, f"modified z-score > {asked:.3g} (the level asked for)"
    if flat:
        return FLAT_LEVEL, (f"modified z-score > {FLAT_LEVEL:.3g} (most shots read the same "
                            "value: the mean absolute deviation's level)")
    cut = level(n)
    return cut, f"modified z-score > {cut:.3g} (the level 1 % of sets of {n} good shots cross)"


def modified_z(values: np.ndarray) -> tuple[np.ndarray, bool]:
    """Iglewicz-Hoaglin modified z-scores ``0.6745 |x - median| / MAD`` over the finite values,
    and whether the MAD was 0.

    When more than half the values are equal the MAD is 0; the score then uses the mean absolute
    deviation, ``|x - median| / (1.253314 MeanAD)`` (their recommendation), so a lone outlier
    among identical values is still caught (at :data:`FLAT_LEVEL`). All values equal: every
    score 0. A non-finite value scores inf.
    """
    finite = np.isfinite(values)
    z = np.full(values.shape, np.inf)
    if not finite.any():
        return z, False
    x = values[finite]
    med = np.median(x)
    dev = np.abs(x - med)
    mad = np.median(dev)
    if mad > 0:
        z[finite] = 0.6745 * dev / mad
        return z, False
    mean_ad = dev.mean()
    z[finite] = dev / (1.253314 * mean_ad) if mean_ad > 0 else 0.0
    return z, True
