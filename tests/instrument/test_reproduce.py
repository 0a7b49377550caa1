"""`solitonde reproduce --quick`: the paper's figures regenerate and show the paper's trends."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app
from solitonde.instrument.studies.paper_checks import (
    check_critical_distance,
    paper_statements,
    settled_distance,
    spearman,
)
from solitonde.instrument.studies.paper_points import theory_curve
from solitonde.instrument.studies.paper_setup import (
    CENTRE_M,
    DIAMETERS_M,
    PLATES_M,
    THICK_PLATE_M,
    TRACE_DIAMETER_M,
    scene_for,
)
from solitonde.model import zener

FIGURES = ("fig3_traces", "fig4_zener", "fig5_arr", "fig6_tof", "fig7_arr_vs_distance",
           "fig8_tof_vs_distance", "fig9_lamb", "fig10_critical_distance")


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    """One quick reproduction through the CLI, with a fresh plate-response cache."""
    root = tmp_path_factory.mktemp("reproduce")
    out = root / "out"
    result = CliRunner().invoke(
        build_app(), ["reproduce", "--out", str(out), "--quick", "--cache", str(root / "cache")])
    assert result.exit_code == 0, result.output
    return out


def test_every_figure_and_its_data(quick):
    """Figs. 3-10 as PNG, the CSV behind each, and the summary."""
    for name in FIGURES:
        png = (quick / f"{name}.png").read_bytes()
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 5_000
    for name in ("fig3_traces", "fig4_zener", "fig5_arr", "fig6_tof", "fig7_8_distance_sweep",
                 "fig9_lamb", "fig10_critical_distance"):
        assert len(pd.read_csv(quick / f"{name}.csv")) > 0
    summary = json.loads((quick / "summary.json").read_text())
    assert summary["quick"] is True and summary["all_passed"] is True


def test_arr_falls_with_d_over_t(quick):
    """Simulated ARR of the 3 x 3 grid falls with D/t and is near 0 (<= 0.1) above D/t = 5."""
    f = pd.read_csv(quick / "fig5_arr.csv")
    grid = f[f["source"] == "chain_infinite"]
    assert len(grid) == 9
    arr = grid["arr"].fillna(grid["arr_upper_bound"]).to_numpy()
    assert np.all(np.isfinite(arr))
    assert spearman(grid["d_over_t"], arr) <= -0.9
    assert np.all(arr[grid["d_over_t"].to_numpy() > 5] <= 0.1)
    # and the analytic line is monotone
    line = f[f["source"] == "theory"].sort_values("d_over_t")
    assert np.all(np.diff(line["arr"]) <= 0)


def test_tof_over_d_collapses(quick):
    """At equal D/t the three spheres give one TOF/D (gravity off) while their TOFs differ ~D."""
    f = pd.read_csv(quick / "fig6_tof.csv")
    eq = f[(f["source"] == "chain_infinite_equal_d_over_t") & (~f["gravity"].astype(bool))]
    assert len(eq) == 4 * len(DIAMETERS_M)
    for _, g in eq.groupby(eq["d_over_t"].round(6)):
        tod = g["tof_s"] / g["diameter_m"]
        assert (tod.max() - tod.min()) / tod.mean() < 0.01
        assert g["tof_s"].max() / g["tof_s"].min() > 3.5  # D ranges over a factor 4
    summary = json.loads((quick / "summary.json").read_text())
    check = summary["checks"]["tof_over_d_collapses"]
    # with gravity the preload breaks the scaling a little: reported, a few per cent
    assert 0.0 < check["max_relative_spread_tof_over_d_gravity_on"] < 0.1


def test_near_support_and_critical_distance(quick):
    """Near the support ARR exceeds the centre value; thinner plates settle farther out."""
    s = pd.read_csv(quick / "fig7_8_distance_sweep.csv")
    assert set(np.round(s["thickness_m"], 6)) == set(np.round(PLATES_M, 6))
    for _, g in s.groupby(["diameter_m", "thickness_m"]):
        g = g.sort_values("distance_m")
        near = g[g["distance_m"] > 0].iloc[0]
        assert near["arr"] > g.iloc[-1]["arr"]
        # on the clamped edge the plate cannot move: the half-space result for every plate
        at0 = g.iloc[0]
        half = scene_for(near["diameter_m"], near["thickness_m"], 0.0, "halfspace")
        from solitonde.model.simulate import simulate
        assert at0["tof_s"] == pytest.approx(simulate(half).truth["tof_s"], rel=2e-3)
    crit = pd.read_csv(quick / "fig10_critical_distance.csv")
    sim = crit[crit["source"] == "simulated"]
    for _, g in sim.groupby("diameter_m"):
        lc = g.sort_values("thickness_m")["critical_distance_m"].to_numpy()
        assert np.all(np.isfinite(lc)) and np.all(np.diff(lc) < 0)
        again = [settled_distance(h["distance_m"], h["tof_s"])
                 for _, h in s[np.isclose(s["diameter_m"], g["diameter_m"].iloc[0])]
                 .groupby("thickness_m")]
        assert np.allclose(sorted(again), sorted(lc))


def test_settled_distance_definition():
    """Linear interpolation of the relative TOF deviation across the 2 % band, last exit wins."""
    x = [0.0, 0.1, 0.2, 0.3, 0.4]
    far = 1.0
    # deviations 10 %, 4 %, 3 %, 1 %, 0: leaves the band between 0.2 (3 %) and 0.3 (1 %)
    tof = [far * 1.10, far * 0.96, far * 1.03, far * 1.01, far]
    assert settled_distance(x, tof) == pytest.approx(0.25)
    assert settled_distance(x, [1.0] * 5) == 0.0
    assert math.isnan(settled_distance(x, [1.0, 1.0, 1.0, 1.5, 1.0]))
    assert math.isnan(settled_distance(x, [1.0, math.nan, 1.0, 1.0, 1.0]))


def test_critical_distance_check_scores_plates_with_a_reflection():
    """Ordering is required where D/t <= 5; beyond it (ARR near 0) plates are listed, not scored."""
    def frame(values):
        return pd.DataFrame([{"diameter_m": d, "thickness_m": t, "critical_distance_m": lc}
                             for d, t, lc in values])
    ordered = [(9.53e-3, 2.29e-3, 0.04), (9.53e-3, 3.18e-3, 0.025), (9.53e-3, 4.83e-3, 0.019)]
    beyond = [(19.05e-3, 2.29e-3, 0.25), (19.05e-3, 3.18e-3, math.nan),
              (19.05e-3, 4.83e-3, 0.066)]
    check = check_critical_distance(frame(ordered + beyond))
    assert check["passed"]
    assert check["per_diameter"]["19.05 mm"]["passed"] is None  # one scored plate: no ordering
    assert [p["d_over_t"] > 5 for p in check["per_diameter"]["19.05 mm"]["not_scored"]] == [True,
                                                                                           True]
    swapped = [(9.53e-3, 2.29e-3, 0.02), (9.53e-3, 3.18e-3, 0.025), (9.53e-3, 4.83e-3, 0.019)]
    assert not check_critical_distance(frame(swapped))["passed"]
    undefined = [(9.53e-3, 2.29e-3, math.nan), (9.53e-3, 3.18e-3, 0.025)]
    assert not check_critical_distance(frame(undefined))["passed"]
    assert not check_critical_distance(frame(beyond[:2]))["passed"]  # nothing left to score
    assert not check_critical_distance(frame(beyond))["passed"]  # one plate: nothing tested


@pytest.mark.parametrize("diameter", DIAMETERS_M)
def test_theory_curve_is_predict(diameter):
    """The fast theory curve of Figs. 5-6 equals zener.predict point by point."""
    ts = [1.5e-3, 3.18e-3, 9.52e-3]
    curve = theory_curve(diameter, ts)
    for t, row in zip(ts, curve.itertuples(), strict=True):
        p = zener.predict(scene_for(diameter, t))
        assert row.arr == pytest.approx(p.arr, rel=1e-7, abs=1e-12)
        assert row.tof_s == pytest.approx(p.tof_s, rel=1e-7)
        assert row.tau_c == pytest.approx(p.tau_c, rel=1e-7)


def test_fig3_csv_holds_both_whole_traces(quick):
    """The CSV behind Fig. 3 holds every plotted sample of both traces (was cut to the shorter)."""
    from solitonde.model.simulate import simulate

    f = pd.read_csv(quick / "fig3_traces.csv")
    for column, thickness in (("force_thin_N", PLATES_M[0]), ("force_thick_N", THICK_PLATE_M)):
        r = simulate(scene_for(TRACE_DIAMETER_M, thickness))
        kept = f[column].notna().to_numpy()
        assert kept.sum() == r.samples.size
        np.testing.assert_allclose(f["time_s"].to_numpy()[kept], r.time, rtol=1e-9)
        np.testing.assert_allclose(f[column].to_numpy()[kept], r.samples, rtol=1e-9, atol=1e-9)


def test_paper_statements_list_values_in_thickness_order():
    """Each near-support list follows thickness_m, whatever order the sweep's rows come in.

    With workers > 1 the rows arrive in finishing order; the lists at L = 0 and at the first
    L > 0 were each in their own row order, so a value could sit under another plate's thickness.
    """
    rows = [{"diameter_m": 9.53e-3, "thickness_m": t, "distance_m": L,
             "tof_s": 1e-3 * (0.5 + t + L), "arr": 0.5 + 10 * t + L}
            for t in PLATES_M for L in (0.0, 0.01, CENTRE_M)]
    # finishing order: L = 0 of the thick plate first, L = 0.01 of the thin plate first
    order = sorted(range(len(rows)), key=lambda i: (rows[i]["distance_m"],
                                                    -rows[i]["thickness_m"]
                                                    if rows[i]["distance_m"] == 0.0
                                                    else rows[i]["thickness_m"]))
    sweep = pd.DataFrame([rows[i] for i in order])
    crit = pd.DataFrame([{"diameter_m": 9.53e-3, "thickness_m": t, "critical_distance_m": 0.0}
                         for t in PLATES_M])
    statements = paper_statements({}, sweep, crit)
    near = next(v for k, v in statements.items() if k.startswith("near_support"))["9.53 mm"]
    for i, t in enumerate(near["thickness_m"]):
        assert near["tof_at_0_s"][i] == pytest.approx(1e-3 * (0.5 + t))
        assert near["arr_at_0"][i] == pytest.approx(0.5 + 10 * t)
        assert near["tof_at_10mm_s"][i] == pytest.approx(1e-3 * (0.51 + t))
        assert near["arr_at_10mm"][i] == pytest.approx(0.51 + 10 * t)


def test_fig4_csv_holds_the_marked_grid(quick):
    """Fig. 4's CSV has the curve and the 3 x 3 grid points the PNG marks (lambda, e, tau_c)."""
    f = pd.read_csv(quick / "fig4_zener.csv")
    grid = f[f["source"] == "grid"]
    assert len(grid) == len(DIAMETERS_M) * len(PLATES_M)
    for row in grid.to_dict(orient="records"):
        scene = scene_for(row["diameter_m"], row["thickness_m"])
        assert row["d_over_t"] == pytest.approx(scene.d_over_t)
        assert row["lambda"] == pytest.approx(zener.inelasticity(scene), rel=1e-9)
    curve = f[f["source"] == "curve"].sort_values("lambda")
    assert len(curve) > 10 and np.all(np.diff(curve["e"]) <= 0)


def test_a_failed_check_has_its_own_exit_code(tmp_path, monkeypatch) -> None:
    """A failed paper check exits 3, a usage error 2 (both were 2: a CI script could not tell
    them apart)."""
    from typer.testing import CliRunner

    from solitonde.instrument.cli.main import build_app
    from solitonde.instrument.studies import reproduce as reproduce_module

    def failing(out, quick, **kwargs):
        return {"quick": quick, "wall_s": 1.0, "all_passed": False,
                "checks": {"arr_curve": {"passed": False}}}

    monkeypatch.setattr(reproduce_module, "reproduce", failing)
    runner = CliRunner()
    assert runner.invoke(build_app(), ["reproduce", "--out", str(tmp_path), "--quick"]
                         ).exit_code == 3
    assert runner.invoke(build_app(), ["reproduce", "--out", str(tmp_path), "--preset", "x"]
                         ).exit_code == 2
