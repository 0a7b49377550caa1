"""The scan as one unknown, validated: simulated scans of random plates inverted jointly
(instrument.inference.joint_map) against position by position, and the next position chosen by
the joint posterior (instrument.inference.suggest) against at random.

Each scan (seeded): a plate of the table's family, its thickness drawn log-uniformly inside the
table's range as :mod:`.validate` draws it; the plate's rectangle is the scan's frame
``[0, a] x [0, b]`` (the family's size), and its clamped edge a line near one of the
rectangle's sides (which side at random), tilted by up to :data:`TILT_DEG` and set in by up to
:data:`INSET_M`: a random angle and offset; the opposite clamped edge lies the plate's length
``a`` from it. Positions stand at distances from the edge drawn log-uniformly in
:data:`DISTANCE_RANGE_M` (an operator looking for the support measures near it, some further
away) and anywhere along it inside the rectangle. Its chain stands off those recorded
coordinates by the joint map's stated coordinate error (a normal draw of
:data:`~solitonde.instrument.inference.joint_map.POSITION_SD_M` per coordinate; off with
``exact_positions``), and there every position is simulated, measured and
calibrated exactly as :func:`.validate.measure_plate` does (the tier ``auto`` picks, or the 3-D
plate where it would pick the 2-D one with ``truth_plate_theory="3d"``, a
Kuwabara-Kono dissipation the elastic table lacks, 5 shots at 40 dB, one sphere size, the
chain's damping (with the table's dissipation layer), an ARR factor and TOF offset fitted on two
reference plates).

Scored per scan with 3-10 positions (:data:`POSITIONS`):

* thickness coverage of every position's 95 % answer (one-sided bounds count when they hold, as
  in :mod:`.validate`), joint (thickness free per position; and tied with a common mean, 5 %
  spread) against position by position;
* the edge offset's 95 % coverage: the joint posterior's against the per-position fit of
  :mod:`~solitonde.instrument.inference.edge_fit`, with its binomial standard error and each
  miss in the sds its interval states (:func:`_z`; the angle's and the edge's at the scan too):
  30 scans tell a coverage of 0.967 from 1.000 and nothing finer;
* the width of the thickness interval at positions within :data:`NEAR_EDGE_M` of the edge (an
  open side reaches the table's end, so a bound or no answer is as wide as the table allows);
* the edge's error against the number of positions: starting from the scan's first three, one
  position added at a time, up to :data:`MAX_POSITIONS`: the suggestion of the joint posterior
  (objective ``edge``), or a random one drawn as the first three were (near the true edge: an
  operator who already knows roughly where the support is), or a random one anywhere on the
  plate. The error is the largest distance between
  the located edge (the joint posterior's best) and the true one along the true edge's span
  inside the rectangle; the count is the number of positions at which it first falls below
  :data:`TARGET_ERROR_M`.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from solitonde.instrument.errors import InstrumentError
from solitonde.instrument.inference import joint_map, suggest
from solitonde.instrument.inference.calibration import Calibration
from solitonde.instrument.inference.calibration_fit import Reference, fit_calibration
from solitonde.instrument.inference.edge_fit import locate
from solitonde.instrument.inference.inversion import FeatureSummary, invert
from solitonde.instrument.studies import validate as single
from solitonde.instrument.tables.table import ModelTable
from solitonde.instrument.tables.table_build import run_tasks
from solitonde.model.scene import apply_overrides
from solitonde.signal.atomic import write_text
from solitonde.signal.features import EXTRACTOR_VERSION

TILT_DEG = 5.0
INSET_M = 0.03
DISTANCE_RANGE_M = (0.003, 0.2)
POSITIONS = (3, 10)
MAX_POSITIONS = 10
START_POSITIONS = 3
NEAR_EDGE_M = 0.03
TARGET_ERROR_M = 0.005
STRATEGIES = ("suggested", "random_near_edge", "random_on_plate")
"""How the positions after the first three are chosen: the joint posterior's suggestion;
at random as the first ones were (near the true edge: an operator who already knows roughly
where the support is); at random anywhere on the plate."""
COMMON_SPREAD = 0.05
TRUTH_PLATE_THEORIES = ("auto", "3d", "mindlin")
"""``sem.plate_theory`` of the simulated plates (:func:`run`)."""


class StudyInputError(InstrumentError, ValueError):
    """A study request that cannot be run; ``field`` names what is wrong."""


def _covered(ci: Sequence[float | None] | None, truth: float) -> bool:
    lo, hi = ci or (None, None)
    return (lo is None or lo <= truth) and (hi is None or truth <= hi)


def _answered(p: Mapping[str, Any]) -> bool:
    return p.get("status") in single.ANSWERS


def _width(p: Mapping[str, Any], t_range: tuple[float, float]) -> float:
    """The 95 % interval's width with an open side at the table's end (no answer: the table)."""
    lo, hi = (p.get("ci95") or (None, None)) if _answered(p) else (None, None)
    return (hi if hi is not None else t_range[1]) - (lo if lo is not None else t_range[0])


class Scan:
    """One random plate and the positions one may measure on it."""

    def __init__(self, table: ModelTable, seed: int, diameter_m: float,
                 coordinate_sd_m: float = 0.0) -> None:
        family = table.family or {}
        size = family.get("plate_size_m") or [0.914, 0.914]
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


class Measurer:
    """Simulated positions, measured as :func:`.validate.measure_plate` measures them; kept
    in a file (optional) so that a study can be re-scored without simulating again. The file
    records the scene its positions were simulated on (the truths' plate theory among it) and
    the extractor's reading they were read with: a file of another scene or reading is refused,
    not mixed in."""

    def __init__(self, base: Mapping[str, Any], path: str | Path | None) -> None:
        self.base = dict(base)
        self.path = Path(path) if path is not None else None
        self.cache: dict[str, Any] = {}
        if self.path is not None and self.path.is_file():
            try:
                data = json.loads(self.path.read_text(encoding="utf-8"))
                self.cache = data["positions"]
                # files written before the scene was recorded hold the table's own tiers
                stored = data.get("scene")
                reading = int(data.get("reading_version", 1))
            except (OSError, ValueError, KeyError, TypeError) as exc:
                raise StudyInputError("measurements", f"{str(self.path)!r} is not a file this "
                                      f"study wrote ({exc}); delete it or give another") from None
            if (stored is None and _plate_theory(self.base) != "auto") or (
                    stored is not None and stored != json.loads(json.dumps(self.base))):
                raise StudyInputError("measurements", f"{str(self.path)!r} holds positions "
                                      f"simulated on another scene (its sem.plate_theory "
                                      f"{_plate_theory(stored or {})!r}, this study's "
                                      f"{_plate_theory(self.base)!r}); give another file")
            if reading != EXTRACTOR_VERSION:
                raise StudyInputError("measurements", f"{str(self.path)!r} holds positions read "
                                      f"with the extractor's reading {reading}, this solitonde "
                                      f"reads with {EXTRACTOR_VERSION}; give another file")
        self.simulated = 0
        self.wall_s = 0.0

    @staticmethod
    def key(d: float, t: float, length: float, seed: int) -> str:
        return f"{d:.6e}|{t:.9e}|{length:.9e}|{seed}"

    def prefetch(self, requests: Sequence[tuple[float, float, float, int]], workers: int,
                 progress: Callable[[str, int, int], None] | None = None) -> None:
        """Simulate the requested ``(d, t, length, seed)`` not yet kept, ``workers`` at a time
        (a study's positions are independent runs)."""
        todo = {self.key(*r): r for r in requests if self.key(*r) not in self.cache}
        if not todo:
            return
        started = time.perf_counter()
        tasks = [(self.base, [d], t, max(length, 0.0), seed, k)
                 for k, (d, t, length, seed) in todo.items()]
        for done, (key, m) in enumerate(run_tasks(_measure_keyed, tasks, workers, None), 1):
            self.cache[key] = {str(k): v for k, v in m["summaries"].items()}
            self.simulated += 1
            if progress is not None:
                progress("positions simulated", done, len(tasks))
        self.wall_s += time.perf_counter() - started

    def __call__(self, d: float, t: float, length: float, seed: int) -> list[FeatureSummary]:
        key = self.key(d, t, length, seed)
        self.prefetch([(d, t, length, seed)], 1)
        return [FeatureSummary(s["diameter_m"], s["tof_s"], s["arr"], s["tof_std_s"],
                               s["arr_std"], int(s["n_shots"]), s.get("arr_upper_bound"))
                for s in self.cache[key].values() if s is not None]

    def save(self) -> None:
        if self.path is None:
            return
        write_text(self.path, json.dumps({"scene": self.base, "positions": self.cache,
                                          "reading_version": EXTRACTOR_VERSION}))


def _plate_theory(scene: Mapping[str, Any]) -> str:
    return str((scene.get("sem") or {}).get("plate_theory", "auto"))


def _measure_keyed(base: Mapping[str, Any], diameters: Sequence[float], t: float,
                   length: float, seed: int, key: str) -> tuple[str, dict[str, Any]]:
    """:func:`.validate.measure_plate` with the key it is kept under (results come back in the
    order they finish)."""
    return key, single.measure_plate(base, diameters, t, length, seed)


def _references(table: ModelTable, d: float, seed: int
                ) -> list[tuple[float, float, float, int]]:
    """The two reference plates' ``(d, t, length, seed)``: far from the supports, as
    :mod:`.validate` places them."""
    t_axis, l_axis = table.axes["thickness_m"], table.axes["distance_m"]
    l_ref = float(np.clip(single.REFERENCE_DISTANCE_M, l_axis[0], l_axis[-1]))
    return [(d, float(np.clip(t_ref, t_axis[0], t_axis[-1])), l_ref, seed + k)
            for k, t_ref in enumerate((single.REFERENCE_THICKNESS_M,
                                       single.REFERENCE2_THICKNESS_M))]


def _calibration(table: ModelTable, measure: Measurer, d: float, seed: int) -> Calibration:
    """The chain's damping, an ARR factor and TOF offset fitted on two reference plates, as
    :mod:`.validate` does."""
    refs = []
    for d_ref, t_ref, l_ref, s_ref in _references(table, d, seed):
        refs += [Reference(t_ref, l_ref, s) for s in measure(d_ref, t_ref, l_ref, s_ref)
                 if not s.hidden]
    return fit_calibration(table, refs)


def _stood(scan: Scan, xy: Sequence[tuple[float, float]]) -> list[tuple[float, int]]:
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


def _scan_positions(scan: Scan, xy: Sequence[tuple[float, float]], measure: Measurer,
                    cal: Calibration) -> list[joint_map.ScanPosition]:
    out = []
    for k, ((x, y), (length, seed)) in enumerate(zip(xy, _stood(scan, xy), strict=True)):
        inputs = measure(scan.diameter_m, scan.thickness_m, length, seed)
        out.append(joint_map.ScanPosition(f"P{k + 1:02d}", x, y, inputs, cal))
    return out


def _joint_edge(table: ModelTable, positions: Sequence[joint_map.ScanPosition],
                shared_calibration: bool = False
                ) -> tuple[joint_map.JointPosterior | None, float, float]:
    try:
        post = joint_map.posterior(table, positions, shared_calibration=shared_calibration)
    except joint_map.JointMapError:
        return None, math.nan, math.nan
    theta, offset = joint_map.median_edge(post)
    return post, theta, offset


def score_scan(table: ModelTable, scan: Scan, measure: Measurer, cal: Calibration,
               sequential: bool = True, shared_calibration: bool = False) -> dict[str, Any]:
    """One scan's rows: per position the three answers against the truth, the edge's coverage,
    and (``sequential``) the edge's error as positions are added, suggested or random."""
    t_range = (float(table.axes["thickness_m"][0]), float(table.axes["thickness_m"][-1]))
    xy = scan.random_positions[:scan.n_positions]
    positions = _scan_positions(scan, xy, measure, cal)
    row: dict[str, Any] = {"seed": scan.seed, "thickness_m": scan.thickness_m,
                           "normal_angle_deg": math.degrees(scan.theta),
                           "offset_m": scan.offset_m, "n_positions": scan.n_positions}
    alone: list[dict[str, Any] | None] = []
    for p in positions:
        found = invert(table, p.inputs, cal) if p.inputs else None
        alone.append(None if found is None else found.to_dict())
    joint: dict[str, Any] = {}
    at_scan: dict[str, Any] = {}
    for kind in ("free", "common"):
        try:
            post = joint_map.posterior(table, positions, joint_map.ThicknessPrior(
                kind, COMMON_SPREAD), shared_calibration=shared_calibration)
            joint[kind] = joint_map.summary(post)
            at_scan[kind] = _edge_at_scan(post, scan)
        except joint_map.JointMapError as exc:
            joint[kind] = {"error": str(exc)}
    per_position = []
    by_name = {k: {p["position"]: p for p in j.get("positions", [])} for k, j in joint.items()}
    for p, est in zip(positions, alone, strict=True):
        truth_l = scan.distance(p.x_m, p.y_m)
        entry: dict[str, Any] = {"x_m": p.x_m, "y_m": p.y_m, "distance_m": truth_l}
        answers = {"alone": (est or {}).get("thickness_m") or {"status": "none"}}
        for kind in joint:
            answers[kind] = (by_name[kind].get(p.name) or {}).get("thickness_m") or \
                {"status": "none"}
        for name, ans in answers.items():
            entry[name] = {"status": ans.get("status"), "ci95": ans.get("ci95"),
                           "covered": (_covered(ans.get("ci95"), scan.thickness_m)
                                       if _answered(ans) else None),
                           "width_m": _width(ans, t_range)}
        per_position.append(entry)
    row["positions"] = per_position
    # the edge's offset: joint against the per-position fit
    for kind, j in joint.items():
        s = j.get("support")
        row[f"edge_{kind}"] = None if not s else {
            "ci95_offset_m": s["ci95_offset_m"], "offset_m": s["offset_m"],
            "normal_angle_deg": s["normal_angle_deg"],
            "covered": _offset_covered(s, scan), "offset_z": _offset_z(s, scan),
            "fit": j.get("fit"),
            "error_m": scan.edge_error(math.radians(s["normal_angle_deg"]), s["offset_m"]),
            **at_scan.get(kind, {})}
    fit, reason = locate([{"x_m": p.x_m, "y_m": p.y_m, "distance_m": (e or {}).get("distance_m")}
                          for p, e in zip(positions, alone, strict=True)])
    row["edge_alone"] = {"reason": reason} if fit is None else {
        "ci95_offset_m": list(fit.ci95_offset_m), "offset_m": fit.offset_m,
        "normal_angle_deg": fit.normal_angle_deg,
        "covered": _offset_covered(fit.to_dict(), scan),
        "offset_z": _offset_z(fit.to_dict(), scan),
        "error_m": scan.edge_error(math.radians(fit.normal_angle_deg), fit.offset_m)}
    if sequential:
        row["sequence"] = _sequence(table, scan, measure, cal, shared_calibration)
    return row


def _edge_at_scan(post: joint_map.JointPosterior, scan: Scan) -> dict[str, Any]:
    """The edge's two parameters as the scan sees them: its direction (the 95 % interval of
    the normal's angle) and where it lies at the scan (the 95 % interval of the positions'
    centroid's distance from it), each with whether it holds the truth. The offset in the
    frame mixes both: at the frame's origin, far along the edge from the scan, an angle's error
    moves it by the lever arm times the angle."""
    theta_b = float(post.cells.theta[post.best])
    flip = math.cos(theta_b - scan.theta) < 0  # the located edge seen from the other side
    n_true = -scan.normal if flip else scan.normal
    truth_theta = (scan.theta + math.pi) if flip else scan.theta
    rel = (post.cells.theta - truth_theta + math.pi) % (2 * math.pi) - math.pi
    a_lo, a_hi = joint_map.weighted_quantiles(rel, post.mass, (0.025, 0.975))
    c_true = float(post.anchor @ n_true) - scan.true_offset(theta_b)
    c_lo, c_hi = joint_map.weighted_quantiles(post.cells.c, post.mass, (0.025, 0.975))
    return {"angle_ci95_width_deg": math.degrees(a_hi - a_lo),
            "angle_covered": bool(a_lo <= 0.0 <= a_hi), "angle_z": _z(0.0, a_lo, a_hi),
            "at_scan_ci95_width_m": c_hi - c_lo, "at_scan_covered": bool(c_lo <= c_true <= c_hi),
            "at_scan_z": _z(c_true, c_lo, c_hi),
            "lever_m": float(abs(post.anchor @ np.array([-n_true[1], n_true[0]])))}


def _offset_covered(support: Mapping[str, Any], scan: Scan) -> bool:
    """Whether the 95 % offset interval holds the true edge's offset (of the clamped edge the
    located one stands for)."""
    lo, hi = support["ci95_offset_m"]
    return bool(lo <= scan.true_offset(math.radians(support["normal_angle_deg"])) <= hi)


def _z(truth: float, lo: float, hi: float) -> float:
    """The truth's distance from a 95 % interval's middle in the sds the interval states (its
    half-width over 1.96): over many answers whose intervals are as wide as their errors, an
    rms of 1, and 95 % of them within 1.96. A coverage counts only whether |z| < 1.96."""
    half = 0.5 * (hi - lo)
    return float((truth - 0.5 * (lo + hi)) / (half / 1.96)) if half > 0 else math.nan


def _offset_z(support: Mapping[str, Any], scan: Scan) -> float:
    lo, hi = support["ci95_offset_m"]
    return _z(scan.true_offset(math.radians(support["normal_angle_deg"])), lo, hi)


def _sequence(table: ModelTable, scan: Scan, measure: Measurer, cal: Calibration,
              shared_calibration: bool = False) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for strategy in STRATEGIES:
        xy = list(scan.random_positions[:START_POSITIONS])
        fallback = (scan.plate_positions if strategy == "random_on_plate"
                    else scan.random_positions)
        errors = []
        while True:
            positions = _scan_positions(scan, xy, measure, cal)
            post, theta, offset = _joint_edge(table, positions, shared_calibration)
            errors.append(math.inf if post is None else scan.edge_error(theta, offset))
            if len(xy) >= MAX_POSITIONS:
                break
            if strategy != "suggested" or post is None:
                xy.append(fallback[len(xy)])
                continue
            nxt = suggest.suggest(post, 1, objective="edge", region=(0.0, scan.a, 0.0, scan.b))
            if not nxt["suggestions"]:
                xy.append(scan.random_positions[len(xy)])
                continue
            s = nxt["suggestions"][0]
            xy.append((s["x_m"], s["y_m"]))
        reached = next((START_POSITIONS + k for k, e in enumerate(errors)
                        if e <= TARGET_ERROR_M), None)
        out[strategy] = {"errors_m": errors, "positions_to_target": reached,
                         "xy": [list(p) for p in xy]}
    return out


def run(table: ModelTable, n_scans: int, seed: int = 0, *, diameter_m: float | None = None,
        measurements: str | Path | None = None, sequential: bool = True,
        progress: Callable[[str, int, int], None] | None = None,
        shared_calibration: bool = False, exact_positions: bool = False,
        truth_plate_theory: str = "auto", workers: int = 1) -> dict[str, Any]:
    """The study (see the module doc): per-scan rows and the summary metrics.
    ``shared_calibration``: the joint maps draw the calibration's TOF offset error once per
    scan (:func:`~solitonde.instrument.inference.joint_map.posterior`). Each position's chain
    stands off its recorded coordinates by the error the joint map states for them
    (:data:`~solitonde.instrument.inference.joint_map.POSITION_SD_M` per coordinate), so the
    study tests that statement; ``exact_positions`` puts it exactly there.
    ``truth_plate_theory`` (``sem.plate_theory`` of every simulated plate, the reference plates
    included, as :func:`.validate.validate` does): ``3d`` simulates next to a support on the 3-D
    plate while the table holds the 2-D plate there, so the 2-D plate's own error, which the
    intervals state, is in the truths too. ``workers`` simulate the scans' first positions
    (all of them without ``sequential``) in parallel before the scans are scored."""
    if isinstance(n_scans, bool) or not isinstance(n_scans, int) or n_scans < 1:
        raise StudyInputError("scans", f"must be an integer >= 1, got {n_scans!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise StudyInputError("seed", f"must be an integer >= 0, got {seed!r}")
    sizes = [float(d) for d in table.axes["diameter_m"]]
    if diameter_m is None:
        diameter_m = min(sizes, key=lambda d: abs(d - 9.53e-3))
    else:
        diameter_m = float(table.axes["diameter_m"][table.diameter_index(diameter_m)])
    if truth_plate_theory not in TRUTH_PLATE_THEORIES:
        raise StudyInputError("truth_plate_theory", f"must be one of "
                              f"{', '.join(TRUTH_PLATE_THEORIES)}, got {truth_plate_theory!r}")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise StudyInputError("workers", f"must be an integer >= 1, got {workers!r}")
    base = dict(table.sweep.get("scene", {}))
    if truth_plate_theory != "auto":
        base = apply_overrides(base, {"sem.plate_theory": truth_plate_theory})
    measure = Measurer(base, measurements)
    started = time.perf_counter()
    coordinate_sd_m = 0.0 if exact_positions else joint_map.POSITION_SD_M
    scans = [Scan(table, int(np.random.default_rng([seed, k]).integers(0, 2**31)), diameter_m,
                  coordinate_sd_m) for k in range(n_scans)]
    requests = _references(table, diameter_m, seed * 1000 + 1)
    for scan in scans:
        lists = [scan.random_positions[:scan.n_positions]]
        if sequential:
            lists += [scan.random_positions,
                      scan.random_positions[:START_POSITIONS]
                      + scan.plate_positions[START_POSITIONS:]]
        for xy in lists:
            requests += [(diameter_m, scan.thickness_m, length, s)
                         for length, s in _stood(scan, xy)]
    measure.prefetch(requests, workers, progress)
    measure.save()
    cal = _calibration(table, measure, diameter_m, seed * 1000 + 1)
    rows = []
    for k, scan in enumerate(scans):
        rows.append(score_scan(table, scan, measure, cal, sequential, shared_calibration))
        measure.save()
        if progress is not None:
            progress("scans scored", k + 1, n_scans)
    metrics = summarise(rows)
    metrics.update(n_scans=n_scans, seed=seed, diameter_m=diameter_m,
                   shared_calibration=shared_calibration,
                   coordinate_sd_m=coordinate_sd_m, truth_plate_theory=truth_plate_theory,
                   simulated_positions=measure.simulated, simulation_wall_s=measure.wall_s,
                   wall_s=time.perf_counter() - started,
                   calibration=cal.to_dict()["per_diameter"],
                   table=str(table.path) if table.path else None)
    return {"metrics": metrics, "scans": rows}


SPLIT_STEPS = ("alone", "distance_known", "no_material_spread", "no_calibration_uncertainty",
               "no_table_error")
"""The near-edge width split, each step removing one more source of a position's thickness
interval: the distance (known exactly), the material's spread, the calibration's stated
uncertainty, the table's interpolation error; what is left is the shots' noise."""


def _width_at_distance(table: ModelTable, inputs: Sequence[FeatureSummary],
                       cal: Calibration | None, spread: Mapping[str, float] | None,
                       distance_m: float, t_range: tuple[float, float]) -> float:
    """The 95 % thickness interval's width (an open side to the table's end) of a position's
    own likelihood at a known distance, by a single inversion's rules."""
    from solitonde.instrument.inference.inversion import cell_likelihood, summarise_marginal

    keep = cell_likelihood(table, inputs, cal, material_spread=spread)
    dev, g = keep["deviance"], keep["grid"]
    ok = np.isfinite(dev)
    if not ok.any():
        return t_range[1] - t_range[0]
    like = np.where(ok, np.exp(-0.5 * (np.where(ok, dev, 0.0) - dev[ok].min())), 0.0)
    grid = g.distance_m
    j = int(np.clip(np.searchsorted(grid, distance_m) - 1, 0, grid.size - 2))
    f = float(np.clip((distance_m - grid[j]) / (grid[j + 1] - grid[j]), 0.0, 1.0))
    col = (1.0 - f) * like[:, j] + f * like[:, j + 1]
    if col.max() <= 0:
        return t_range[1] - t_range[0]
    mass = col * g.weight_t
    est = summarise_marginal(np.log(g.thickness_m), mass / mass.sum(), g.weight_t,
                             lower_physical=False, transform=np.exp, profile=col / col.max())
    return _width(est.to_dict(), t_range)


def width_split(table: ModelTable, n_scans: int, seed: int = 0, *,
                diameter_m: float | None = None, measurements: str | Path | None = None
                ) -> dict[str, Any]:
    """What a near-edge position's thickness interval is made of: for every position of the
    study's scans within :data:`NEAR_EDGE_M` of the edge, the width of its own 95 % interval
    (:data:`SPLIT_STEPS`): alone, then with its distance known exactly, then without the
    material's spread, the calibration's stated uncertainty and the table's interpolation error
    in turn. Medians of the widths (m, and over the plate's thickness) and of their ratio to the
    width alone. The same scans, positions and measurements as :func:`run` (the measurements
    file it keeps is reused)."""
    from dataclasses import replace

    from solitonde.instrument.inference.inversion import fine_grid

    if isinstance(n_scans, bool) or not isinstance(n_scans, int) or n_scans < 1:
        raise StudyInputError("scans", f"must be an integer >= 1, got {n_scans!r}")
    sizes = [float(d) for d in table.axes["diameter_m"]]
    diameter_m = (min(sizes, key=lambda d: abs(d - 9.53e-3)) if diameter_m is None
                  else float(table.axes["diameter_m"][table.diameter_index(diameter_m)]))
    t_range = (float(table.axes["thickness_m"][0]), float(table.axes["thickness_m"][-1]))
    measure = Measurer(table.sweep.get("scene", {}), measurements)
    cal = _calibration(table, measure, diameter_m, seed * 1000 + 1)
    exact = cal.to_dict()
    for entry in exact["per_diameter"]:
        entry["arr_factor_std"] = entry["tof_offset_std_s"] = 0.0
    cal_exact = Calibration.from_any(exact)
    no_material = dict.fromkeys(("youngs_modulus_rel_sd", "poisson_ratio_sd",
                                 "density_rel_sd"), 0.0)
    rows: list[dict[str, Any]] = []
    for k in range(n_scans):
        scan = Scan(table, int(np.random.default_rng([seed, k]).integers(0, 2**31)), diameter_m)
        for p in _scan_positions(scan, scan.random_positions[:scan.n_positions], measure, cal):
            dist = scan.distance(p.x_m, p.y_m)
            if dist > NEAR_EDGE_M or not p.inputs:
                continue
            est = invert(table, p.inputs, cal).to_dict()["thickness_m"]
            widths = [_width(est, t_range),
                      _width_at_distance(table, p.inputs, cal, None, dist, t_range),
                      _width_at_distance(table, p.inputs, cal, no_material, dist, t_range),
                      _width_at_distance(table, p.inputs, cal_exact, no_material, dist,
                                         t_range)]
            # the table's interpolation error set to zero on the fine grid, then restored
            key = f"fine:{table.diameter_index(diameter_m)}"
            g = fine_grid(table, table.diameter_index(diameter_m))
            table._cache[key] = replace(g, model_tof_var=np.zeros_like(g.model_tof_var),
                                        model_arr_var=np.zeros_like(g.model_arr_var))
            try:
                widths.append(_width_at_distance(table, p.inputs, cal_exact, no_material, dist,
                                                 t_range))
            finally:
                table._cache[key] = g
            rows.append({"thickness_m": scan.thickness_m, "distance_m": dist,
                         "widths_m": dict(zip(SPLIT_STEPS, widths, strict=True))})
    measure.save()
    out: dict[str, Any] = {"positions": len(rows), "n_scans": n_scans, "seed": seed}
    for step in SPLIT_STEPS:
        w = np.array([r["widths_m"][step] for r in rows])
        t = np.array([r["thickness_m"] for r in rows])
        alone = np.array([r["widths_m"]["alone"] for r in rows])
        out[step] = {"median_width_m": float(np.median(w)) if rows else None,
                     "median_width_rel_t": float(np.median(w / t)) if rows else None,
                     "median_ratio_to_alone": float(np.median(w / alone)) if rows else None}
    return out


def _rms(values: Sequence[float | None]) -> float | None:
    v = np.array([x for x in values if x is not None and math.isfinite(x)], dtype=float)
    return float(np.sqrt(np.mean(v**2))) if v.size else None


def _binomial_se(hits: Sequence[bool]) -> float | None:
    if not hits:
        return None
    p = float(np.mean(hits))
    return math.sqrt(max(p * (1.0 - p), 1.0 / len(hits)) / len(hits))


def summarise(rows: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Coverage, widths near the edge, and the edge's error against the number of positions."""
    out: dict[str, Any] = {}
    for name in ("alone", "free", "common"):
        cov = [p[name]["covered"] for r in rows for p in r["positions"]
               if p[name]["covered"] is not None]
        n_all = sum(len(r["positions"]) for r in rows)
        near = [p[name]["width_m"] / r["thickness_m"] for r in rows for p in r["positions"]
                if p["distance_m"] <= NEAR_EDGE_M]
        near_abs = [p[name]["width_m"] for r in rows for p in r["positions"]
                    if p["distance_m"] <= NEAR_EDGE_M]
        out[f"thickness_{name}"] = {
            "coverage_95": float(np.mean(cov)) if cov else None, "answers": len(cov),
            "positions": n_all,
            "statuses": _counts(p[name]["status"] for r in rows for p in r["positions"]),
            "near_edge_width_median_rel": float(np.median(near)) if near else None,
            "near_edge_width_median_m": float(np.median(near_abs)) if near_abs else None,
            "near_edge_positions": len(near)}
    for name in ("alone", "free", "common"):
        edges = [r.get(f"edge_{name}") for r in rows]
        located = [e for e in edges if e and "covered" in e]
        out[f"edge_{name}"] = {
            "coverage_95": float(np.mean([e["covered"] for e in located])) if located else None,
            "located": len(located), "scans": len(rows),
            "error_median_m": float(np.median([e["error_m"] for e in located]))
            if located else None,
            "ci95_width_median_m": float(np.median([e["ci95_offset_m"][1] - e["ci95_offset_m"][0]
                                                    for e in located])) if located else None,
            # how sure a coverage over this many scans is (binomial, at the coverage seen;
            # 30 scans resolve 0.967 from 1.000 and no finer), and the offset's z (_z)
            "coverage_95_se": _binomial_se([e["covered"] for e in located]),
            "offset_z_rms": _rms([e.get("offset_z") for e in located])}
        seen = [e for e in located if "angle_covered" in e]
        if seen:
            out[f"edge_{name}"].update(
                angle_coverage_95=float(np.mean([e["angle_covered"] for e in seen])),
                angle_ci95_width_median_deg=float(np.median([e["angle_ci95_width_deg"]
                                                             for e in seen])),
                at_scan_coverage_95=float(np.mean([e["at_scan_covered"] for e in seen])),
                at_scan_ci95_width_median_m=float(np.median([e["at_scan_ci95_width_m"]
                                                             for e in seen])),
                lever_median_m=float(np.median([e["lever_m"] for e in seen])),
                angle_z_rms=_rms([e.get("angle_z") for e in seen]),
                at_scan_z_rms=_rms([e.get("at_scan_z") for e in seen]))
            # where the edge lies at the scan means something only where its direction is
            # fixed: the joint map warns beyond joint_map.WIDE_ANGLE_DEG
            fixed = [e for e in seen if e["angle_ci95_width_deg"] <= joint_map.WIDE_ANGLE_DEG]
            out[f"edge_{name}"].update(
                direction_fixed_scans=len(fixed),
                at_scan_coverage_95_direction_fixed=float(np.mean(
                    [e["at_scan_covered"] for e in fixed])) if fixed else None,
                at_scan_z_rms_direction_fixed=_rms([e.get("at_scan_z") for e in fixed]))
    free = [r["edge_free"]["fit"]["p_value"] for r in rows if r.get("edge_free")]
    out["joint_fit_p_below_0.001"] = float(np.mean([p < 1e-3 for p in free])) if free else None
    seqs = [r["sequence"] for r in rows if "sequence" in r]
    if seqs:
        for strategy in STRATEGIES:
            errors = np.array([s[strategy]["errors_m"] for s in seqs])
            counts = [s[strategy]["positions_to_target"] for s in seqs]
            reached = [c for c in counts if c is not None]
            out[f"sequence_{strategy}"] = {
                "edge_error_median_m_by_positions": {
                    str(START_POSITIONS + k): float(np.median(errors[:, k]))
                    for k in range(errors.shape[1])},
                "reached_target": len(reached), "scans": len(seqs),
                # a scan that never reached it counts as needing more than the maximum
                "positions_to_target_median": float(np.median(
                    [c if c is not None else MAX_POSITIONS + 1 for c in counts])),
                "positions_to_target_mean_reached": float(np.mean(reached)) if reached else None,
                "target_m": TARGET_ERROR_M}
        big = MAX_POSITIONS + 1
        for other in STRATEGIES[1:]:
            pairs = [(s["suggested"]["positions_to_target"], s[other]["positions_to_target"])
                     for s in seqs]
            out[f"suggested_fewer_than_{other}"] = sum((a or big) < (b or big) for a, b in pairs)
            out[f"suggested_more_than_{other}"] = sum((a or big) > (b or big) for a, b in pairs)
    return out


def _counts(values: Any) -> dict[str, int]:
    out: dict[str, int] = {}
    for v in values:
        out[str(v)] = out.get(str(v), 0) + 1
    return out


__all__ = ["SPLIT_STEPS", "Scan", "StudyInputError", "run", "score_scan", "summarise",
           "width_split"]
