"""`solitonde bench plates`: the Mindlin plate against the 3-D plate, scene by scene."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app
from solitonde.instrument.studies.plate_theory import Point, compare

#: A small plate and mesh: both runs take about a second; the machinery, not the map, is tested.
SMALL = ["plate.size=[0.3,0.3]", "sem.elements=[8,8,1]"]


def test_compare_reports_errors_budget_and_speed_up() -> None:
    """One thin-plate scene near the support on both Green's functions, the 3-D one on the
    Mindlin plate's own mesh: TOF and ARR within the table budget, and the 2-D plate cheaper."""
    result = compare([Point(9.53e-3, 3.18e-3, 0.05)], "greens", overrides=SMALL)
    row, = result["rows"]
    assert result["models"] == {"3d": "greens", "mindlin": "mindlin_greens"}
    assert result["reference_mesh"] == "same-mesh" and result["overrides"] == SMALL
    assert row["tof_error"] <= 0.01 and row["arr_error"] <= 0.05 and row["within_budget"]
    assert row["dofs_mindlin"] < 0.4 * row["dofs_3d"]
    assert row["speedup"] == pytest.approx(row["wall_3d_s"] / row["wall_mindlin_s"])
    assert result["summary"]["within_budget"] == 1 and result["summary"]["outside_budget"] == []
    json.dumps(result)


@pytest.mark.parametrize(("args", "option"), [
    (["--kind", "kirchhoff"], "--kind"),
    (["--reference", "finest"], "--reference"),
    (["--distances", "-0.01"], "--distances"),
    (["--thicknesses", "0"], "--thicknesses"),
    (["--diameters", "abc"], "--diameters"),
    (["--set", "plate.material=unobtainium"], "plate.material"),
])
def test_bad_options_are_refused_before_any_run(args: list[str], option: str) -> None:
    """Exit 2 with an error naming the option (or the scene key) and what is allowed."""
    result = CliRunner().invoke(build_app(), ["bench", "plates", *args])
    assert result.exit_code == 2, result.output
    assert f"error: {option}" in result.output
    assert "Traceback" not in result.output
