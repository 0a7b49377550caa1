"""The paper's Figs. 3-10 drawn from the reproduction's points and theory curves: a PNG and the
CSV behind each."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from solitonde.instrument.studies.figures import (
    DIAMETER_MARKERS,
    PLATE_COLOURS,
    new_figure,
    save_csv,
    save_png,
)
from solitonde.instrument.studies.paper_checks import SETTLE_TOLERANCE, TraceInfo
from solitonde.instrument.studies.paper_points import arr_or_bound, groups
from solitonde.instrument.studies.paper_setup import (
    DIAMETERS_M,
    PLATES_M,
    THICK_PLATE_M,
    TRACE_DIAMETER_M,
    scene_for,
)
from solitonde.instrument.tables.greens_cache import LayeredCache
from solitonde.instrument.tables.measured import as_measured, detect_options
from solitonde.model import zener
from solitonde.model.lamb import MODES, lamb_dispersion
from solitonde.model.simulate import simulate
from solitonde.signal.features import extract


def fig3(out: Path, cache: LayeredCache) -> dict[str, TraceInfo]:
    """Sensor traces on a thin (2.29 mm) and a thick (9.52 mm) plate, D = 9.53 mm, centre."""
    fig, ax = new_figure()
    traces = {}
    info: dict[str, TraceInfo] = {}
    for label, t in (("thin", PLATES_M[0]), ("thick", THICK_PLATE_M)):
        scene = scene_for(TRACE_DIAMETER_M, t)
        r = simulate(scene, greens_cache=cache)
        f = extract(as_measured(r), **detect_options(r.scene))
        traces[label] = (r.time, r.samples)
        info[label] = {"thickness_m": t, "plate_model": r.plate_model,
                       "incident_time_s": f.incident_time_s, "tof_s": f.tof_s, "arr": f.arr}
        ax.plot(r.time * 1e3, r.samples, label=f"t = {t * 1e3:.2f} mm (D/t = {scene.d_over_t:.2f},"
                f" {r.plate_model})", color="tab:red" if label == "thin" else "tab:blue")
    # Records differ in length (auto duration): the CSV keeps both whole, the shorter NaN-padded.
    longest = max(traces.values(), key=lambda tr: tr[0].size)[0]
    columns = {"time_s": longest}
    for label, (time_s, force) in traces.items():
        if not np.allclose(time_s, longest[:time_s.size], rtol=0.0, atol=1e-12):
            raise ValueError("fig 3: the two traces are not on one time grid")
        padded = np.full(longest.size, np.nan)
        padded[:force.size] = force
        columns[f"force_{label}_N"] = padded
    frame = pd.DataFrame(columns)
    ax.set_xlabel("time after impact (ms)")
    ax.set_ylabel("sensor force (N)")
    ax.set_title("Fig. 3: sensor traces, D = 9.53 mm, plate centre")
    ax.legend()
    save_png(fig, out / "fig3_traces.png")
    save_csv(frame, out / "fig3_traces.csv")
    return info


def fig4(out: Path, grid_theory: pd.DataFrame, points: int) -> None:
    """e and tau_c against lambda, the grid's lambdas marked."""
    top = max(5.0, 1.1 * float(grid_theory["lambda"].max()))
    lam = np.linspace(0.0, top, points)
    e, tau = zener.restitution_and_contact_time_many(lam)
    frame = pd.DataFrame({"lambda": lam, "e": e, "tau_c": tau})
    fig, ax = new_figure()
    ax.plot(lam, e, color="tab:blue", label="restitution e")
    ax.set_xlabel("inelasticity parameter lambda (-)")
    ax.set_ylabel("coefficient of restitution e (-)", color="tab:blue")
    ax.plot(grid_theory["lambda"], grid_theory["e"], "o", color="tab:blue", ms=4,
            label="the 3 x 3 grid")
    ax2 = ax.twinx()
    ax2.plot(lam, tau, color="tab:orange")
    ax2.set_ylabel("dimensionless contact time tau_c (-)", color="tab:orange")
    ax.set_title("Fig. 4: Zener impact, e and tau_c against lambda")
    ax.legend(loc="center right")
    save_png(fig, out / "fig4_zener.png")
    grid = grid_theory[["diameter_m", "thickness_m", "d_over_t", "lambda", "e", "tau_c"]]
    save_csv(pd.concat([frame.assign(source="curve"), grid.assign(source="grid")],
                       ignore_index=True), out / "fig4_zener.csv")


def fig5(out: Path, curve: pd.DataFrame, grid_inf: pd.DataFrame, centre: pd.DataFrame) -> None:
    """ARR against D/t: analytic line, chain on Zener's dashpot, chain on the SEM plate (centre)."""
    fig, ax = new_figure()
    ax.plot(curve["d_over_t"], curve["arr"], "k-", label="Zener theory (Eq. 9)")
    for d, g in groups(grid_inf, "diameter_m"):
        ax.plot(g["d_over_t"], arr_or_bound(g), DIAMETER_MARKERS.get(d, "o"), mfc="none",
                color="tab:blue", label=f"chain + dashpot, D = {d * 1e3:.2f} mm")
    for d, g in groups(centre, "diameter_m"):
        ax.plot(g["d_over_t"], arr_or_bound(g), DIAMETER_MARKERS.get(d, "o"), color="tab:red",
                label=f"chain + SEM plate (centre), D = {d * 1e3:.2f} mm")
    ax.axvline(5.0, color="0.7", ls=":")
    ax.set_xlabel("D/t (-)")
    ax.set_ylabel("ARR (-)")
    ax.set_title("Fig. 5: amplitude ratio against D/t")
    ax.legend(fontsize=7)
    save_png(fig, out / "fig5_arr.png")
    save_csv(pd.concat([curve.assign(source="theory"),
                        grid_inf.assign(source="chain_infinite"),
                        centre.assign(source="chain_greens_centre")], ignore_index=True),
             out / "fig5_arr.csv")


def fig6(out: Path, curves: pd.DataFrame, grid_inf: pd.DataFrame, centre: pd.DataFrame,
         collapse: pd.DataFrame) -> None:
    """TOF and TOF/D against D/t (plus the equal-D/t runs of the collapse check)."""
    fig, (a, b) = new_figure(2)
    for _, g in curves.groupby("diameter_m"):
        ok = np.isfinite(g["tof_s"]) & (g["tof_s"] < 3e-3)
        a.plot(g["d_over_t"][ok], g["tof_s"][ok] * 1e3, "-", color="0.4", lw=1)
    one = curves[np.isclose(curves["diameter_m"], TRACE_DIAMETER_M)]  # the same for every D
    b.plot(one["d_over_t"], one["tof_over_d_s_per_m"], "k-", lw=1, label="theory (Eq. 16)")
    for source, frame, colour in (("dashpot", grid_inf, "tab:blue"), ("SEM centre", centre,
                                                                      "tab:red")):
        for d, g in groups(frame, "diameter_m"):
            mk = DIAMETER_MARKERS.get(d, "o")
            a.plot(g["d_over_t"], g["tof_s"] * 1e3, mk, color=colour, mfc="none" if
                   source == "dashpot" else colour, label=f"{source}, D = {d * 1e3:.2f} mm")
            b.plot(g["d_over_t"], g["tof_s"] / g["diameter_m"], mk, color=colour,
                   mfc="none" if source == "dashpot" else colour)
    for d, g in groups(collapse[collapse["gravity"]], "diameter_m"):
        b.plot(g["d_over_t"], g["tof_s"] / g["diameter_m"], "x", color="0.3", ms=5,
               label="dashpot, equal D/t" if d == DIAMETERS_M[0] else None)
    a.set_xlabel("D/t (-)")
    a.set_ylabel("TOF (ms)")
    a.set_title("Fig. 6a: TOF (lines: theory per D)")
    a.legend(fontsize=6)
    b.set_xlabel("D/t (-)")
    b.set_ylabel("TOF/D (s/m)")
    b.set_title("Fig. 6b: TOF/D on one curve")
    b.set_ylim(0, 0.2)
    b.legend(fontsize=7)
    save_png(fig, out / "fig6_tof.png")
    cols = ["diameter_m", "thickness_m", "d_over_t", "tof_s"]
    frame = pd.concat([curves[cols].assign(source="theory"),
                       grid_inf[cols].assign(source="chain_infinite"),
                       centre[cols].assign(source="chain_greens_centre"),
                       collapse[[*cols, "gravity"]].assign(source="chain_infinite_equal_d_over_t")],
                      ignore_index=True)
    frame["tof_over_d_s_per_m"] = frame["tof_s"] / frame["diameter_m"]
    save_csv(frame, out / "fig6_tof.csv")


def fig7_8(out: Path, sweep: pd.DataFrame, grid_theory: pd.DataFrame) -> None:
    """ARR (Fig. 7) and TOF (Fig. 8) against the distance to the support."""
    shown = [d for d in (9.53e-3, 19.05e-3) if np.isclose(sweep["diameter_m"], d).any()]
    for name, column, scale, unit in (("fig7_arr_vs_distance", "arr", 1.0, " (-)"),
                                      ("fig8_tof_vs_distance", "tof_s", 1e3, " (ms)")):
        fig, axes = new_figure(len(shown))
        axes = np.atleast_1d(axes)
        for ax, d in zip(axes, shown, strict=True):
            for t, g in groups(sweep[np.isclose(sweep["diameter_m"], d)], "thickness_m"):
                g = g.sort_values("distance_m")
                colour = PLATE_COLOURS.get(t, None)
                ax.plot(g["distance_m"] * 1e3, g[column] * scale, "o-", ms=3, color=colour,
                        label=f"t = {t * 1e3:.2f} mm")
                th = grid_theory[np.isclose(grid_theory["diameter_m"], d)
                                 & np.isclose(grid_theory["thickness_m"], t)]
                if len(th):
                    ax.axhline(float(th[column].iloc[0]) * scale, color=colour, ls="--", lw=0.8)
            ax.set_xlabel("distance to the clamped support L (mm)")
            ax.set_ylabel(("ARR" if column == "arr" else "TOF") + unit)
            ax.set_title(f"D = {d * 1e3:.2f} mm (dashed: infinite-plate theory)", fontsize=9)
            ax.legend(fontsize=7)
        fig.suptitle("Fig. 7: ARR against L" if column == "arr" else "Fig. 8: TOF against L")
        save_png(fig, out / f"{name}.png")
    save_csv(sweep.sort_values(["diameter_m", "thickness_m", "distance_m"]),
             out / "fig7_8_distance_sweep.csv")


def fig9(out: Path, points: int) -> None:
    """Group velocities of A0, S0 and A1 against frequency for the three plates."""
    from solitonde.model.materials import get_material

    material = get_material("al_6061")
    f = np.linspace(2e3, 1e6, points)
    fig, ax = new_figure()
    rows = []
    styles = {"A0": "-", "S0": "--", "A1": ":"}
    for t in PLATES_M:
        disp = lamb_dispersion(t, material, f)
        for mode in MODES:
            cg = disp.group_velocity[mode]
            ax.plot(f * 1e-3, cg, styles.get(mode, "-"), color=PLATE_COLOURS[t],
                    label=f"{mode}, t = {t * 1e3:.2f} mm")
            rows.append(pd.DataFrame({"thickness_m": t, "mode": mode, "frequency_hz": f,
                                      "group_velocity_m_s": cg,
                                      "phase_velocity_m_s": disp.phase_velocity[mode]}))
    ax.set_xlabel("frequency (kHz)")
    ax.set_ylabel("group velocity (m/s)")
    ax.set_title("Fig. 9: Lamb modes in Al 6061 plates")
    ax.legend(fontsize=6, ncol=3)
    save_png(fig, out / "fig9_lamb.png")
    save_csv(pd.concat(rows, ignore_index=True), out / "fig9_lamb.csv")


def fig10(out: Path, crit: pd.DataFrame) -> pd.DataFrame:
    """Critical distance against D: Eq. 18 for k = 0.57 and 0.2, and the simulated ones."""
    diameters = np.linspace(3e-3, 21e-3, 50)
    lines = pd.DataFrame({
        "diameter_m": diameters,
        "critical_distance_k057_m": [zener.critical_distance(scene_for(d, PLATES_M[1]),
                                                             zener.RAYLEIGH_K) for d in diameters],
        "critical_distance_k02_m": [zener.critical_distance(scene_for(d, PLATES_M[1]), zener.A0_K)
                                    for d in diameters],
    })
    fig, ax = new_figure()
    mm = diameters * 1e3
    ax.plot(mm, lines["critical_distance_k057_m"] * 1e3, "k-", label="Eq. 18, k = 0.57")
    ax.plot(mm, lines["critical_distance_k02_m"] * 1e3, "k--", label="Eq. 18, k = 0.2")
    for t, g in groups(crit, "thickness_m"):
        ax.plot(g["diameter_m"] * 1e3, g["critical_distance_m"] * 1e3, "o", ms=6,
                color=PLATE_COLOURS.get(t), label=f"simulated, t = {t * 1e3:.2f} mm")
    ax.set_xlabel("sphere diameter D (mm)")
    ax.set_ylabel("critical distance (mm)")
    ax.set_title(f"Fig. 10: critical distance (simulated: TOF within "
                 f"{SETTLE_TOLERANCE:.0%} of the centre)", fontsize=9)
    ax.legend(fontsize=7)
    save_png(fig, out / "fig10_critical_distance.png")
    frame = pd.concat([lines.assign(source="eq18"), crit.assign(source="simulated")],
                      ignore_index=True)
    save_csv(frame, out / "fig10_critical_distance.csv")
    return frame

