"""The scan's shared calibration errors, drawn once for every position measured with one
calibration (one calibration, one plate), and the nodes the joint posterior integrates them
over."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.special import logsumexp

from solitonde.instrument.inference.joint_likelihood import RawLikelihood

NODES_PER_ERROR = {1: 9, 2: 5}
"""Nodes per shared calibration error, by how many there are (3 each beyond two)."""
NODE_SPAN_SD = 4.0
"""The nodes span this many sds either side of the error's posterior mean."""


def _proxy(raws: Sequence[RawLikelihood], key: tuple[Any, ...], x: np.ndarray) -> np.ndarray:
    """log p(data | error = x) of the positions that carry this error, each position's (t, L)
    marginalised over a single inversion's prior (the edge ignored), the other errors at 0."""
    total = np.zeros(x.size)
    for raw in raws:
        if key not in raw.keys:
            continue
        a = raw.keys.index(key)
        keep = raw.keep
        g = keep["grid"]
        dev0 = keep["deviance"]
        ok = np.isfinite(dev0)
        logw = np.log(g.weight_t)[:, None] + np.log(g.weight_l)[None, :]
        d = (dev0[ok][None, :] - 2.0 * x[:, None] * keep["shared_b"][a][ok][None, :]
             + x[:, None] ** 2 * keep["shared_q"][a, a][ok][None, :])
        total += logsumexp(logw[ok][None, :] - 0.5 * (d - d.min()), axis=1) - 0.5 * d.min()
    return total


def calibration_nodes(raws: Sequence[RawLikelihood]
                      ) -> tuple[list[tuple[Any, ...]], np.ndarray, np.ndarray]:
    """The scan's shared calibration errors and the nodes over which they are integrated:
    ``(keys, eta (node, error), z2 (node,))`` with ``z2`` each node's ``sum (eta / sd)^2``.

    One error per calibration entry with a stated sd (a sphere size's TOF offset or ARR
    factor), shared by every position measured with it: one calibration, one plate. Each
    error's nodes are equally spaced (the trapezoid rule, which integrates a smooth peak to
    within e^-2pi^2 when the spacing is its sd) across +-:data:`NODE_SPAN_SD` sds of where the
    positions together put it, found by zooming in from the prior's +-6 sd; several errors get
    the product of their nodes."""
    keys = sorted({k for raw in raws for k in raw.keys})
    if not keys:
        return [], np.zeros((1, 0)), np.zeros(1)
    n = NODES_PER_ERROR.get(len(keys), 3)
    axes = []
    for key in keys:
        sd = float(key[3])
        lo, hi = -6.0 * sd, 6.0 * sd
        mean, s = 0.0, sd
        for _ in range(10):
            x = np.linspace(lo, hi, 25)
            lp = -0.5 * (x / sd) ** 2 + _proxy(raws, key, x)
            w = np.exp(lp - lp.max())
            w /= w.sum()
            mean = float(w @ x)
            s = float(np.sqrt(w @ (x - mean) ** 2))
            h = x[1] - x[0]
            if s >= 1.5 * h:
                break
            half = max(6.0 * s, 2.0 * h)
            lo, hi = mean - half, mean + half
        axes.append(mean + s * np.linspace(-NODE_SPAN_SD, NODE_SPAN_SD, n))
    mesh = np.meshgrid(*axes, indexing="ij")
    eta = np.stack([m.ravel() for m in mesh], axis=1)
    sds = np.array([float(k[3]) for k in keys])
    return keys, eta, ((eta / sds[None, :]) ** 2).sum(axis=1)
