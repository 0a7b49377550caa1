"""A random scan of the map study (:mod:`.map_study`): a plate of the table's family with a
clamped edge near one side of its rectangle, tilted and set in at random, and the positions one
may measure on it."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from solitonde.instrument.tables.table import ModelTable

TILT_DEG = 5.0
INSET_M = 0.03
DISTANCE_RANGE_M = (0.003, 0.2)
POSITIONS = (3, 10)
MAX_POSITIONS = 10


class Scan:
    """One random plate and the positions one may measure on it."""

    def __init__(self, table: ModelTable, seed: int, diameter_m: float,
                 coordinate_sd_m: float = 0.0) -> None:
        size = (table.family["plate_size_m"] if table.family else None) or [0.914, 0.914]
        self.a, self.b = float(size[0]), float(size[1])
        self.rng = np.random.default_rng(seed)
        t_axis = table.axes["thickness_m"]
        lo, hi = math.log(t_axis[0] * 1.01), math.log(t_axis[-1] / 1.01)
        self.thickness_m = float(math.exp(self.rng.uniform(lo, hi)))
        self.diameter_m = diameter_m
        side = int(self.rng.integers(4))
        tilt = math.radians(self.rng.uniform(-TILT_DEG, TILT_DEG))
        inset = float(self.rng.uniform(0.0, INSET_M))
        # the side's midpoint and inward normal in the rectangle [0, a] x [0, b]
        mids = [((0.0, self.b / 2), 0.0), ((self.a, self.b / 2), math.pi),
                ((self.a / 2, 0.0), math.pi / 2), ((self.a / 2, self.b), -math.pi / 2)]
        (mx, my), phi = mids[side]
        self.theta = (phi + tilt) % (2 * math.pi)
        self.normal = np.array([math.cos(self.theta), math.sin(self.theta)])
        self.along = np.array([-self.normal[1], self.normal[0]])
        self.offset_m = float(np.array([mx, my]) @ self.normal + inset)
        # the true edge's span inside the rectangle (for the edge's error)
        self.ends = self._span()
        self.n_positions = int(self.rng.integers(POSITIONS[0], POSITIONS[1] + 1))
        self.random_positions = [self.draw() for _ in range(MAX_POSITIONS)]
        self.plate_positions = [(float(self.rng.uniform(0.0, self.a)),
                                 float(self.rng.uniform(0.0, self.b)))
                                for _ in range(MAX_POSITIONS)]
        self.seed = seed
        self.coordinate_sd_m = coordinate_sd_m
        """How far (1 sd, per coordinate) the chain stood from its recorded coordinates: the
        recorded (x, y) are a position's; its features are simulated where the chain stood."""

    def _span(self) -> np.ndarray:
        base = self.offset_m * self.normal
        s = np.linspace(-2.0, 2.0, 4001)
        pts = base[None, :] + s[:, None] * self.along
        inside = ((pts[:, 0] >= 0) & (pts[:, 0] <= self.a) & (pts[:, 1] >= 0)
                  & (pts[:, 1] <= self.b))
        return pts[inside][[0, -1]]

    def distance(self, x: float, y: float) -> float:
        """Distance of (x, y) from the nearer clamped edge."""
        d = float(np.array([x, y]) @ self.normal - self.offset_m)
        return min(d, self.a - d)

    def draw(self) -> tuple[float, float]:
        """A random position: log-uniform distance from the edge, anywhere along it, inside
        the rectangle."""
        lo, hi = (math.log(v) for v in DISTANCE_RANGE_M)
        for _ in range(1000):
            u = math.exp(self.rng.uniform(lo, hi))
            s = self.rng.uniform(0.0, 1.0)
            p = self.ends[0] + s * (self.ends[1] - self.ends[0]) + u * self.normal
            if 0 <= p[0] <= self.a and 0 <= p[1] <= self.b:
                return float(p[0]), float(p[1])
        raise RuntimeError("no position inside the rectangle")  # not reached for sane sizes

    def edge_error(self, theta: float, offset: float) -> float:
        """Largest distance of the true edge's span from the line at (theta, offset). The two
        clamped edges are alike: a line reported from the opposite side (its normal pointing
        the other way) is compared with the opposite edge."""
        n = np.array([math.cos(theta), math.sin(theta)])
        if n @ self.normal < 0:
            return float(np.max(np.abs((self.ends + self.a * self.normal) @ n - offset)))
        return float(np.max(np.abs(self.ends @ n - offset)))

    def true_offset(self, theta: float) -> float:
        """The true offset of the clamped edge a line at angle ``theta`` stands for (the near
        one, or the opposite one seen from the other side)."""
        if math.cos(theta - self.theta) < 0:
            return -(self.offset_m + self.a)
        return self.offset_m


def stood(scan: Scan, xy: Sequence[tuple[float, float]]) -> list[tuple[float, int]]:
    """Per recorded position, the distance from the edge where its chain stood (off the
    recorded coordinates by the scan's coordinate error) and its noise seed."""
    out = []
    for k, (x, y) in enumerate(xy):
        seed = int(np.random.default_rng([scan.seed, k, int(x * 1e6), int(y * 1e6)])
                   .integers(0, 2**31))
        stood = (x, y)
        if scan.coordinate_sd_m > 0:
            ex, ey = np.random.default_rng([seed, 7]).normal(0.0, scan.coordinate_sd_m, 2)
            stood = (x + float(ex), y + float(ey))
        out.append((scan.distance(*stood), seed))
    return out
