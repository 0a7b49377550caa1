"""What accuracy costs: TOF and ARR error of each plate model and resolution against a reference.

Two scenes, the paper's D = 9.53 mm sphere on its thinnest plate (t = 2.29 mm, where the plate
matters most): one near the clamped support (L = 20 mm) and one at the centre. Each is run on

- ``infinite``: the chain on Zener's dashpot (no mesh);
- ``sem``: the chain coupled step by step to the spectral-element plate, over a ladder of in-plane
  element counts, polynomial orders, through-thickness resolution and step factors;
- ``greens``: the same plate as a cached contact response, timed cold (the response computed,
  what the first shot at a new plate/position pays) and warm (reused: every further sphere size or
  drop height at that position, i.e. a table build);
- ``mindlin`` and ``mindlin_greens``: the Mindlin-Reissner plate on the same in-plane mesh,
  coupled and as a cached response (``solitonde bench plates`` maps it over sizes and plates).

Errors are relative, against a converged ``sem`` run (:func:`reference_config`); TOF and ARR are
extracted from the sensor trace with :func:`solitonde.signal.features.extract`, as for
measurements. Wall times are the whole ``simulate`` call after a warm-up (no compilation), with
the plate assembly included (its process cache is cleared before each timed run).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NotRequired, TypedDict, cast

import numpy as np
import pandas as pd

from solitonde.instrument.plotting import spread_labels
from solitonde.instrument.studies.figures import new_figure, save_csv, save_json, save_png
from solitonde.instrument.tables.measured import as_measured, detect_options
from solitonde.model import greens
from solitonde.model.scene import Scene, SceneDict, scene_from_dict
from solitonde.model.simulate import simulate
from solitonde.model.tiers import CONVOLVED_PLATE_MODELS, meshed
from solitonde.signal.features import extract

DIAMETER_M = 9.53e-3
THICKNESS_M = 2.29e-3
SCENES_M = {"near_support": 0.02, "centre": 0.457}
"""Distance to the clamped support of the two benchmark scenes."""



class Budget(TypedDict):
    """Largest relative errors a use accepts."""

    tof: float
    arr: float


BUDGETS: dict[str, Budget] = {
    "rest_simulate": {"tof": 0.02, "arr": 0.10},
    "table_build": {"tof": 0.01, "arr": 0.05},
}
"""Largest relative TOF and ARR errors each use accepts. A REST shot is compared with one measured
shot (shot-to-shot scatter of a few per cent in TOF, more in ARR, and measured ARR lies below the
dissipation-free model anyway); a table should stay below the inversion's resolution. ARR gets the
wider band because ARR is the noisier measured feature (and the one the inversion weighs less)."""


class SemSection(TypedDict):
    """The scene's ``sem`` section of a meshed configuration."""

    preset: str
    elements: list[int]
    order: list[int]
    step_factor: float
    contact_refinement: NotRequired[int]
    mindlin_element_size: NotRequired[float]


class Shot(TypedDict):
    """One timed shot: the features as read, the model's own, its cost and mesh size."""

    tof_s: float
    arr: float
    truth_tof_s: float
    truth_arr: float
    wall_s: float
    dofs: int
    plate_dt_s: float | None
    energy_drift: float


class BenchRow(Shot):
    """One configuration at one scene (a row of accuracy.csv): its shot, the warm time with
    the plate's response kept, the errors against the reference, and whether it is on the
    Pareto front."""

    scene: str
    distance_m: float
    config: str
    tier: str
    elements: str
    order: str
    step_factor: float
    wall_warm_s: float
    tof_error: float
    arr_error: float
    error: float
    pareto: bool


class RestChoice(TypedDict):
    """The cheapest configuration within the REST budget at one scene."""

    config: str
    tof_error: float
    arr_error: float
    cost_s: float


class TableChoice(TypedDict):
    """The cheapest configuration within the table budget on both scenes (``config`` None, and
    ``why``, when none is)."""

    budget: Budget
    config: str | None
    why: NotRequired[str]
    tof_error: NotRequired[float]
    arr_error: NotRequired[float]
    cost_per_shot_s: NotRequired[float]
    first_shot_per_position_s: NotRequired[float]


class ConfigName(TypedDict):
    config: str


class Recommendation(TypedDict):
    """Per use, the cheapest configuration within its budget.

    ``rest_simulate`` holds the ``budget`` and, per scene, a :class:`RestChoice` (None when no
    configuration meets the budget there)."""

    rest_simulate: dict[str, Budget | RestChoice | None]
    table_build: TableChoice
    reference: ConfigName


@dataclass(frozen=True)
class Config:
    """One plate model at one resolution.

    ``preset`` is the plate's contact model (``sem.preset``): ``resolved`` spreads the force over
    a patch of radius t on a locally refined mesh (``refinement`` elements across the patch),
    ``paper`` is the paper's single-node load.
    """

    tier: str
    elements: tuple[int, int, int] | None = None
    order: tuple[int, int, int] | None = None
    step_factor: float | None = None
    preset: str = "resolved"
    refinement: int = 1
    mindlin_size: float = 6.0

    @property
    def label(self) -> str:
        if self.elements is None or self.order is None:
            return self.tier
        e, o = self.elements, self.order
        if self.tier.startswith("mindlin"):
            text = f"{self.tier} {self.preset} {e[0]}x{e[1]} p{o[0]}{o[1]}"
            if self.preset == "resolved" and self.mindlin_size != 6.0:
                text += f" e{self.mindlin_size:g}"
            return text + (f" sf{self.step_factor:g}" if self.step_factor not in (None, 0.9)
                           else "")
        text = f"{self.tier} {self.preset} {e[0]}x{e[1]}x{e[2]} p{o[0]}{o[1]}{o[2]}"
        if self.preset == "resolved" and self.refinement != 1:
            text += f" r{self.refinement}"
        return text + (f" sf{self.step_factor:g}" if self.step_factor not in (None, 0.9) else "")

    def scene(self, distance: float) -> Scene:
        data: SceneDict = {
            "chain": {"diameter": DIAMETER_M},
            "plate": {"thickness": THICKNESS_M, "distance_to_support": distance},
            "effects": {"plate_model": self.tier},
        }
        if self.elements is not None:
            sem: SemSection = {"preset": self.preset, "elements": list(self.elements),
                                   "order": list(self.order or ()),
                                   "step_factor": self.step_factor or 0.9}
            if self.preset == "resolved":
                sem["contact_refinement"] = self.refinement
                sem["mindlin_element_size"] = self.mindlin_size
            data["sem"] = dict(sem)
        return scene_from_dict(data)


def reference_config(quick: bool = False) -> Config:
    """The reference: the finest converged-contact ``sem`` plate this bench affords on 2 cores.

    The resolved contact patch on 24 x 24 x 1 elements of order 4 x 4 x 3 with two refinement
    elements across the patch (about 1e5 DOF, 2 minutes a shot). On the resolved preset TOF and
    the near-support ARR move by less than 1 % across the ladder; the small ARR at the centre of
    the thin plate (0.085) still moves by 1-2 % with 24 elements and with thickness order 3, so
    that is about how far this reference can be trusted there. The paper's single-node load
    has no mesh limit at all (its 3D point-load compliance grows as the mesh refines) and is in
    the ladder for comparison. ``quick`` (tests) uses a small mesh so that only the machinery is
    exercised.
    """
    if quick:
        return Config("sem", (12, 12, 1), (3, 3, 2), 0.9, "paper")
    return Config("sem", (24, 24, 1), (4, 4, 3), 0.9, "resolved", 2)


def configs(quick: bool = False) -> list[Config]:
    """The ladder of models and resolutions compared with the reference."""
    if quick:
        return [Config("infinite"), Config("sem", (6, 6, 1), (3, 3, 2), 0.9, "paper"),
                Config("greens", (6, 6, 1), (3, 3, 2), 0.9, "paper"),
                Config("sem", (8, 8, 1), (3, 3, 2), 0.9, "paper")]
    out = [Config("infinite")]
    for n in (6, 8, 12, 16, 24):
        out.append(Config("sem", (n, n, 1), (4, 4, 2), 0.9))
    out += [Config("sem", (12, 12, 1), (3, 3, 2), 0.9),
            Config("sem", (12, 12, 1), (4, 4, 3), 0.9),
            Config("sem", (12, 12, 1), (4, 4, 2), 0.9, "resolved", 2),
            Config("sem", (12, 12, 1), (4, 4, 2), 0.5)]
    for n in (8, 16):
        out.append(Config("greens", (n, n, 1), (4, 4, 2), 0.9))
    for n in (16, 32):
        out.append(Config("sem", (n, n, 1), (4, 4, 2), 0.9, "paper"))
    out.append(Config("greens", (16, 16, 1), (4, 4, 2), 0.9, "paper"))
    for n in (16, 24):
        out.append(Config("mindlin", (n, n, 1), (4, 4, 2), 0.9))
    out += [Config("mindlin", (16, 16, 1), (4, 4, 2), 0.9, mindlin_size=2.0),
            Config("mindlin", (16, 16, 1), (4, 4, 2), 0.9, mindlin_size=12.0),
            Config("mindlin_greens", (16, 16, 1), (4, 4, 2), 0.9)]
    return out


def first_shot(scene: Scene, cache: greens.GreensCache | None = None) -> Shot:
    """TOF and ARR as the extractor reads them, the model's own peaks, and the cost of a shot at
    a new plate: the plate assembled (its process cache cleared) and, without ``cache``, its
    response computed."""
    meshed._plate_cached.cache_clear()  # time the plate assembly too
    started = time.perf_counter()
    r = simulate(scene, greens_cache=greens.MemoryCache() if cache is None else cache)
    wall = time.perf_counter() - started
    f = extract(as_measured(r), **detect_options(r.scene))
    mesh = r.diagnostics.get("mesh") or {}
    return {
        "tof_s": math.nan if f.tof_s is None else f.tof_s,
        "arr": math.nan if f.arr is None else f.arr,
        "truth_tof_s": r.truth["tof_s"],
        "truth_arr": r.truth["arr"],
        "wall_s": wall,
        "dofs": mesh.get("dofs", 0),
        "plate_dt_s": r.diagnostics.get("dt_s"),
        "energy_drift": r.diagnostics["energy_drift"],
    }


def _warm_up() -> None:
    """Compile every kernel once on a tiny mesh so no timing includes numba compilation."""
    for tier in ("infinite", "sem", "greens", "mindlin", "mindlin_greens"):
        simulate(Config(tier, (2, 2, 1), (2, 2, 1), 0.9).scene(0.3))


class BenchScene(TypedDict):
    diameter_m: float
    thickness_m: float
    distances_m: dict[str, float]


class BenchReference(ConfigName):
    """The reference configuration and its shot at each scene (:data:`SCENES_M`)."""

    near_support: Shot
    centre: Shot


class BenchResult(TypedDict):
    """What :func:`run_bench` returns (accuracy.json)."""

    scene: BenchScene
    reference: BenchReference
    rows: list[BenchRow]
    recommendation: Recommendation
    quick: bool


def run_bench(quick: bool = False, tick: Callable[[str], None] | None = None) -> BenchResult:
    """Run the ladder on both scenes and return rows, reference values and recommendations.

    ``greens`` runs use a private in-memory response cache (never the user's disk cache), so the
    cold time is honest; the warm time is a second run with the response cached.
    """
    tick = tick or (lambda _label: None)
    _warm_up()
    ref_cfg = reference_config(quick)
    reference: dict[str, Shot] = {}
    for name, distance in SCENES_M.items():
        reference[name] = first_shot(ref_cfg.scene(distance))
        tick(f"reference, {name}")
    rows = []
    for cfg in configs(quick):
        for name, distance in SCENES_M.items():
            cache = greens.MemoryCache()  # cold: no response from an earlier config
            res = first_shot(cfg.scene(distance), cache)
            warm = math.nan
            if cfg.tier in CONVOLVED_PLATE_MODELS:  # plate and response kept, as in a table
                started = time.perf_counter()
                simulate(cfg.scene(distance), greens_cache=cache)
                warm = time.perf_counter() - started
            ref = reference[name]
            rows.append({
                "scene": name, "distance_m": distance, "config": cfg.label, "tier": cfg.tier,
                "elements": "x".join(map(str, cfg.elements)) if cfg.elements else "",
                "order": "x".join(map(str, cfg.order)) if cfg.order else "",
                "step_factor": cfg.step_factor if cfg.step_factor else math.nan,
                **res,
                "wall_warm_s": warm,
                "tof_error": abs(res["tof_s"] - ref["tof_s"]) / ref["tof_s"],
                "arr_error": abs(res["arr"] - ref["arr"]) / ref["arr"],
            })
            tick(f"{cfg.label}, {name}")
    frame = pd.DataFrame(rows)
    frame["error"] = combined_error(frame)
    frame["pareto"] = pareto(frame)
    return {
        "scene": {"diameter_m": DIAMETER_M, "thickness_m": THICKNESS_M,
                  "distances_m": SCENES_M},
        "reference": cast(BenchReference, {"config": ref_cfg.label,
                                           **{k: v for k, v in reference.items()}}),
        "rows": cast(list[BenchRow], frame.to_dict(orient="records")),
        "recommendation": recommend(frame, ref_cfg),
        "quick": quick,
    }


def combined_error(frame: pd.DataFrame) -> pd.Series:
    """max(TOF error, ARR error) per run; NaN when either is missing (e.g. no reflection found).

    A missing feature is not a small error: pandas' default max would skip it and report the
    other error alone.
    """
    return frame[["tof_error", "arr_error"]].max(axis=1, skipna=False)


def pareto(frame: pd.DataFrame) -> list[bool]:
    """Per scene: no other run is both faster (warm time where it exists) and more accurate.

    A run without an error (a feature missing) counts as infinitely wrong.
    """
    cost = frame["wall_warm_s"].fillna(frame["wall_s"]).to_numpy()
    err = np.nan_to_num(frame["error"].to_numpy(dtype=float), nan=np.inf)
    scene = frame["scene"].to_numpy()
    keep = []
    for i in range(len(frame)):
        same = scene == scene[i]
        # greens and sem agree to round-off: errors within 1e-6 relative count as equal
        better = err < err[i] * (1 - 1e-6)
        as_good = err <= err[i] * (1 + 1e-6)
        dominated = np.any(same & (((cost <= cost[i]) & better) | ((cost < cost[i]) & as_good)))
        keep.append(not bool(dominated))
    return keep


def _within(frame: pd.DataFrame, budget: Budget) -> pd.Series:
    return (frame["tof_error"] <= budget["tof"]) & (frame["arr_error"] <= budget["arr"])


def recommend(frame: pd.DataFrame, ref_cfg: Config) -> Recommendation:
    """The cheapest configuration within each use's error budget.

    REST simulate: per scene, by the cost of a first shot (the ``auto`` plate model already picks
    ``infinite`` far from supports, so the centre and the near-support scene may differ). Table
    build: one configuration for both scenes, by the cost per shot once the plate response is
    cached (a table reuses it for every sphere size and drop height at a position); the one-off
    cost of the response is reported with it.
    """
    budget = BUDGETS["rest_simulate"]
    rest: dict[str, Budget | RestChoice | None] = {"budget": budget}
    for key, g in frame.groupby("scene"):
        scene = str(key)
        ok = g[_within(g, budget)].sort_values("wall_s")
        if ok.empty:
            rest[scene] = None
            continue
        best = ok.iloc[0]
        rest[scene] = {"config": best["config"], "tof_error": float(best["tof_error"]),
                       "arr_error": float(best["arr_error"]), "cost_s": float(best["wall_s"])}
    budget = BUDGETS["table_build"]
    frame = frame.assign(ok=_within(frame, budget),
                         cost=frame["wall_warm_s"].fillna(frame["wall_s"]))
    agg = frame.groupby("config").agg(ok=("ok", "all"), cost=("cost", "max"),
                                      first=("wall_s", "max"), tof_error=("tof_error", "max"),
                                      arr_error=("arr_error", "max"))
    agg = agg[agg["ok"]].sort_values("cost")
    table: TableChoice
    if agg.empty:
        table = {"budget": budget, "config": None,
                 "why": "no configuration meets the budget on both scenes"}
    else:
        best = agg.iloc[0]
        table = {"budget": budget, "config": agg.index[0],
                 "tof_error": float(best["tof_error"]), "arr_error": float(best["arr_error"]),
                 "cost_per_shot_s": float(best["cost"]),
                 "first_shot_per_position_s": float(best["first"])}
    return {"rest_simulate": rest, "table_build": table, "reference": {"config": ref_cfg.label}}


def write_outputs(result: BenchResult, out: Path) -> None:
    """accuracy.csv, accuracy.json and the Pareto plot accuracy_pareto.png in ``out``."""
    frame = pd.DataFrame(result["rows"])
    save_csv(frame, out / "accuracy.csv")
    save_json(result, out / "accuracy.json")
    fig, axes = new_figure(2)
    colours = {"infinite": "tab:blue", "sem": "tab:red", "greens": "tab:green",
               "mindlin": "tab:purple", "mindlin_greens": "tab:orange"}
    labelled: list[tuple[Any, list[Any]]] = []
    for ax, scene in zip(axes, SCENES_M, strict=True):
        g = frame[frame["scene"] == scene]
        for key, h in g.groupby("tier"):
            tier = str(key)
            ax.plot(h["wall_s"], h["error"].clip(lower=1e-5), "o", color=colours.get(tier),
                    label=f"{tier}" + (" (cold)" if tier in CONVOLVED_PLATE_MODELS else ""))
            if tier in CONVOLVED_PLATE_MODELS:
                ax.plot(h["wall_warm_s"], h["error"].clip(lower=1e-5), "D", mfc="none",
                        color=colours[tier], label=f"{tier} (cached response)")
        front = g[g["pareto"]].assign(cost=lambda d: d["wall_warm_s"].fillna(d["wall_s"]))
        front = front.sort_values("cost")
        ax.plot(front["cost"], front["error"].clip(lower=1e-5), "k:", lw=1, label="Pareto front")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ordered = g.sort_values("error")
        labels = [ax.annotate(str(config).replace("sem ", "").replace("greens ", "")
                              .replace("resolved ", "").replace("mindlin_", "M")
                              .replace("mindlin ", "M "), (float(wall), max(float(error), 1e-5)),
                              textcoords="offset points", xytext=(4, 2), fontsize=6, alpha=0.8)
                  for config, wall, error in zip(ordered["config"], ordered["wall_s"],
                                                 ordered["error"], strict=True)]
        labelled.append((ax, labels))
        ax.set_xlabel("wall time per shot (s)")
        ax.set_ylabel("max(TOF, ARR) relative error (-)")
        ax.set_title(f"{scene.replace('_', ' ')}, L = {SCENES_M[scene] * 1e3:g} mm", fontsize=9)
        ax.legend(fontsize=6)
    fig.suptitle(f"What accuracy costs (D = 9.53 mm, t = 2.29 mm; reference "
                 f"{result['reference']['config']})", fontsize=9)
    fig.tight_layout()
    for ax, labels in labelled:  # config names of nearby runs would print over one another
        spread_labels(ax, labels)
    save_png(fig, out / "accuracy_pareto.png")


def table_rows(result: BenchResult) -> list[list[str]]:
    """Rows for the printed table: config, scene, TOF, ARR, errors, times."""
    rows = []
    for r in result["rows"]:
        rows.append([
            r["config"], r["scene"], f"{r['tof_s'] * 1e6:.2f}", f"{r['arr']:.4f}",
            f"{100 * r['tof_error']:.2f}", f"{100 * r['arr_error']:.2f}", f"{r['wall_s']:.2f}",
            "" if not np.isfinite(r["wall_warm_s"]) else f"{r['wall_warm_s']:.3f}",
            "*" if r["pareto"] else "",
        ])
    return rows
