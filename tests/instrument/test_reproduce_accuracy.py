"""`solitonde bench accuracy`: Pareto front and recommendations from a table of runs."""

from __future__ import annotations

import json

import pandas as pd
import pytest
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app
from solitonde.instrument.studies.accuracy import BUDGETS, Config, combined_error, pareto, recommend


def _frame(rows):
    f = pd.DataFrame(rows, columns=["scene", "config", "tier", "tof_error", "arr_error", "wall_s",
                                    "wall_warm_s"])
    f["error"] = f[["tof_error", "arr_error"]].max(axis=1)
    return f


ROWS = [
    ("centre", "infinite", "infinite", 0.008, 0.09, 0.01, float("nan")),
    ("centre", "sem a", "sem", 0.10, 0.30, 10.0, float("nan")),
    ("centre", "sem b", "sem", 0.005, 0.04, 80.0, float("nan")),
    ("centre", "greens b", "greens", 0.005, 0.04 * (1 + 1e-9), 60.0, 0.15),
    ("near_support", "infinite", "infinite", 0.17, 0.75, 0.01, float("nan")),
    ("near_support", "sem a", "sem", 0.01, 0.06, 12.0, float("nan")),
    ("near_support", "sem b", "sem", 0.003, 0.005, 80.0, float("nan")),
    ("near_support", "greens b", "greens", 0.003, 0.005, 85.0, 0.14),
]


def test_pareto_front():
    """Dominated runs drop out; a cached greens run dominates the sem run it equals to round-off."""
    f = _frame(ROWS)
    f["pareto"] = pareto(f)
    front = set(zip(f["scene"][f["pareto"]], f["config"][f["pareto"]], strict=True))
    assert ("centre", "sem a") not in front  # slower and worse than the dashpot
    assert ("centre", "sem b") not in front and ("centre", "greens b") in front
    assert ("centre", "infinite") in front
    assert ("near_support", "infinite") in front  # fastest, whatever its error
    assert ("near_support", "sem b") not in front


def test_recommendation_respects_budgets():
    """REST: cheapest first shot within budget per scene; table: cheapest cached shot on both."""
    rec = recommend(_frame(ROWS), Config("sem", (48, 48, 1), (4, 4, 2), preset="paper"))
    assert rec["rest_simulate"]["centre"]["config"] == "infinite"  # 0.8 % TOF, 9 % ARR
    assert rec["rest_simulate"]["near_support"]["config"] == "sem a"  # dashpot is 17 % off
    assert rec["table_build"]["config"] == "greens b"
    assert rec["table_build"]["cost_per_shot_s"] == pytest.approx(0.15)
    assert rec["table_build"]["tof_error"] <= BUDGETS["table_build"]["tof"]
    assert rec["reference"]["config"] == "sem paper 48x48x1 p442"


def test_a_run_missing_a_feature_is_not_accurate():
    """No ARR (no reflection found) is no error figure, not the TOF error alone: off the front."""
    nan = float("nan")
    f = pd.DataFrame([("centre", "infinite", "infinite", 0.002, 0.03, 0.010, nan),
                      ("centre", "sem coarse", "sem", 0.001, nan, 0.005, nan)],
                     columns=["scene", "config", "tier", "tof_error", "arr_error", "wall_s",
                              "wall_warm_s"])
    f["error"] = combined_error(f)
    assert f["error"].iloc[0] == pytest.approx(0.03) and pd.isna(f["error"].iloc[1])
    # the cheapest run stays on the front whatever its error; it no longer pushes the dashpot off
    assert pareto(f) == [True, True]
    f.loc[1, "wall_s"] = 0.02
    assert pareto(f) == [True, False]


def test_quick_table_says_it_is_not_advice(capsys):
    """--quick's printed table and recommendation say the tiny-mesh numbers are not converged."""
    from solitonde.instrument.cli.cmd_bench import _print

    f = _frame(ROWS).assign(tof_s=6.9e-4, arr=0.085)
    f["pareto"] = pareto(f)
    result = {"rows": f.to_dict(orient="records"), "reference": {"config": "sem paper 12x12x1"},
              "recommendation": recommend(f, Config("sem", (12, 12, 1), (3, 3, 2))), "quick": True}
    _print(result)
    text = " ".join(capsys.readouterr().out.split())
    assert "not converged" in text and "not advice" in text
    _print({**result, "quick": False})
    assert "not advice" not in capsys.readouterr().out


@pytest.mark.slow
def test_bench_cli_quick(tmp_path):
    """The command end to end on tiny meshes: JSON, CSV and the Pareto PNG."""
    result = CliRunner().invoke(build_app(), ["bench", "accuracy", "--quick", "--json",
                                              "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    data = json.loads(result.output)
    assert {r["tier"] for r in data["rows"]} == {"infinite", "sem", "greens"}
    assert (tmp_path / "accuracy_pareto.png").read_bytes()[:4] == b"\x89PNG"
    assert len(pd.read_csv(tmp_path / "accuracy.csv")) == len(data["rows"])
