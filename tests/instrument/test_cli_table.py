"""`solitonde table build` on the command line: Ctrl-C says where the work is kept and how to
resume (exit 130), instead of a traceback with exit 1."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from solitonde.instrument.cli import cmd_table
from solitonde.instrument.cli.main import build_app

GRID = ["--diameters", "4.76e-3", "--thicknesses", "3e-3", "--distances", "0.3", "--workers",
        "1", "--no-progress"]


def _interrupting(inside_numba: bool):
    def build_table(sweep, out, **kw):
        Path(str(out) + ".partial").write_bytes(b"")  # what an interrupted build leaves
        if not inside_numba:
            raise KeyboardInterrupt
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:  # how numba re-raises Ctrl-C from compiled code
            raise SystemError("CPUDispatcher returned a result with an exception set") from exc
    return build_table


@pytest.mark.parametrize("inside_numba", [False, True])
def test_ctrl_c_names_the_partial_file_and_exits_130(tmp_path: Path, monkeypatch,
                                                     inside_numba: bool) -> None:
    monkeypatch.setattr(cmd_table, "build_table", _interrupting(inside_numba))
    out = tmp_path / "t.h5"
    res = CliRunner().invoke(build_app(), ["table", "build", *GRID, "--out", str(out)])
    assert res.exit_code == 130 and isinstance(res.exception, SystemExit), res.output
    assert "interrupted" in res.output and "t.h5.partial" in res.output
    assert "resume" in res.output


def test_other_system_errors_are_not_taken_for_ctrl_c(tmp_path: Path, monkeypatch) -> None:
    def broken(sweep, out, **kw):
        raise SystemError("something else")
    monkeypatch.setattr(cmd_table, "build_table", broken)
    res = CliRunner().invoke(build_app(), ["table", "build", *GRID, "--out",
                                           str(tmp_path / "t.h5")])
    assert isinstance(res.exception, SystemError)


def test_an_existing_table_is_not_replaced_without_overwrite(tmp_path: Path, monkeypatch) -> None:
    """`table build` onto an existing file (without --out: the bundled table) is refused before
    any work, naming --overwrite; with --overwrite it builds; a partial file is a resume."""
    calls: list[Path] = []

    def build_table(sweep, out, **kw):
        calls.append(out)
        raise cmd_table.TableError("stop here")  # the build itself is not under test

    monkeypatch.setattr(cmd_table, "build_table", build_table)
    out = tmp_path / "t.h5"
    out.write_bytes(b"a finished table")
    res = CliRunner().invoke(build_app(), ["table", "build", *GRID, "--out", str(out)])
    assert res.exit_code == 2 and "--overwrite" in res.output and calls == []
    assert out.read_bytes() == b"a finished table"
    res = CliRunner().invoke(build_app(), ["table", "build", *GRID])
    assert res.exit_code == 2 and "the bundled table" in res.output and calls == []
    res = CliRunner().invoke(build_app(), ["table", "build", *GRID, "--out", str(out),
                                           "--overwrite"])
    assert calls == [out]
    Path(str(out) + ".partial").write_bytes(b"")  # an interrupted rebuild resumes
    CliRunner().invoke(build_app(), ["table", "build", *GRID, "--out", str(out)])
    assert calls == [out, out]


def test_a_scene_builds_its_own_sphere_size_and_the_plan_comes_first(tmp_path: Path) -> None:
    """`table build --scene` without --diameters: the scene's sphere only; the plan (points,
    sizes, thicknesses, distances, pilot, estimate) is printed before the result, and the pilot's
    plate is kept in the table."""
    from solitonde.instrument.tables.table import ModelTable

    scene = tmp_path / "my_plate.yaml"
    scene.write_text("chain: {diameter: 4.76e-3}\nplate: {material: steel_structural}\n"
                     "effects: {plate_model: infinite}\n")
    out = tmp_path / "my.h5"
    res = CliRunner().invoke(build_app(), ["table", "build", "--scene", str(scene), "--out",
                                           str(out), "--thicknesses", "3e-3,4e-3",
                                           "--distances", "0.3,0.4", "--workers", "1",
                                           "--no-progress"])
    assert res.exit_code == 0, res.output
    # the plan says when its pilot compiled the kernels (over 10 s: a fresh cache on a busy
    # machine), a line this test's order need not hold
    lines = [line for line in res.output.splitlines()
             if not line.startswith("  (the pilot first compiled")]
    assert lines[0] == "plan: 4 points = 1 sphere size x 2 thicknesses x 2 distances"
    assert lines[1].split(":")[1].strip() == "4.76"
    assert lines[2].split(":")[1].strip() == "3, 4"
    assert lines[3].split(":")[1].strip() == "300, 400"
    assert lines[4].startswith("  4 points far (Zener's dashpot): pilot ")
    assert lines[5].startswith("  estimated time: ") and "on 1 worker " in lines[5]
    assert lines[6].startswith(f"wrote {out}: 4 scenes on 4 plates")  # the pilot's counted
    table = ModelTable.load(out)
    assert table.summary()["complete"]
    assert table.summary()["axes"]["diameter_m"]["values"] == [4.76e-3]

    both = tmp_path / "both.h5"
    res = CliRunner().invoke(build_app(), ["table", "build", "--scene", str(scene), "--out",
                                           str(both), "--diameters", "4.76e-3,9.53e-3",
                                           "--thicknesses", "3e-3", "--distances", "0.3",
                                           "--workers", "1", "--no-progress"])
    assert res.exit_code == 0, res.output
    assert res.output.startswith("plan: 2 points = 2 sphere sizes x 1 thicknesses")


def test_a_build_with_a_dissipation_layer_stores_the_damped_sweep(tmp_path: Path) -> None:
    """`table build --dissipation-layer TAU`: the same sweep simulated with Kuwabara-Kono damping,
    stored in the table; damping takes some of the reflection and nothing else is left behind."""
    from solitonde.instrument.tables.table import ModelTable

    out = tmp_path / "layered.h5"
    res = CliRunner().invoke(build_app(), ["table", "build", *GRID, "--thicknesses", "3e-3,5e-3",
                                           "--set", "effects.plate_model=infinite", "--out",
                                           str(out), "--dissipation-layer", "2e-7"])
    assert res.exit_code == 0, res.output
    table = ModelTable.load(out)
    layer = table.dissipation
    assert layer is not None and layer.damping_s == (2e-7,)
    assert (layer.status == 0).all()
    ratio = layer.features["arr"][0] / table.features["arr"]
    # a small sphere's contacts are short, so tau takes a quarter of the reflection or more
    assert ((ratio > 0.6) & (ratio < 0.9)).all(), ratio
    assert sorted(p.name for p in tmp_path.iterdir()) == ["layered.h5"]
    assert "tau = 2e-07 s" in CliRunner().invoke(build_app(), ["table", "info", str(out)]).output
    bad = CliRunner().invoke(build_app(), ["table", "build", *GRID, "--out",
                                           str(tmp_path / "x.h5"), "--dissipation-layer", "0"])
    assert bad.exit_code == 2 and "--dissipation-layer" in bad.output
    assert not (tmp_path / "x.h5").exists()


def test_a_points_cost_follows_the_thickness_between_the_pilots() -> None:
    """Pilots at the thinnest, a middle and the thickest plate: between two of them the cost is a
    power law in the thickness through both, held beyond the ends; one pilot is a constant."""
    from solitonde.instrument.tables.table_build import point_cost

    pairs = [(2e-3, 8.0, 0.8), (8e-3, 2.0, 0.4)]  # cost ~ t^-1, layer cost ~ t^-0.5
    assert point_cost(pairs, 4e-3) == pytest.approx(4.0)
    assert point_cost(pairs, 4e-3, layer=True) == pytest.approx(0.8 / 2**0.5)
    assert point_cost(pairs, 1e-3) == pytest.approx(8.0)
    assert point_cost(pairs, 20e-3) == pytest.approx(2.0)
    assert point_cost([(3e-3, 1.5, 0.2)], 6e-3) == pytest.approx(1.5)
    three = [(2e-3, 8.0, 0.8), (4e-3, 1.0, 0.4), (8e-3, 0.5, 0.4)]  # t^-3, then t^-1
    assert point_cost(three, 2 ** 0.5 * 2e-3) == pytest.approx(8.0 / 2**1.5)
    assert point_cost(three, 2 ** 0.5 * 4e-3) == pytest.approx(1.0 / 2**0.5)


def test_the_plan_counts_the_dissipation_layers(tmp_path: Path) -> None:
    """With --dissipation-layer the plan names the layers and their time (chain runs only: the
    plates' responses come from the store), and the estimate includes them."""
    out = tmp_path / "t.h5"
    res = CliRunner().invoke(build_app(), [
        "table", "build", "--diameters", "4.76e-3", "--thicknesses", "3e-3,5e-3",
        "--distances", "0,0.3", "--set", "sem.elements=[6,6,1]", "--set", "sem.order=[2,2,2]",
        "--workers", "1", "--no-progress", "--out", str(out), "--responses",
        str(tmp_path / "store"), "--dissipation-layer", "1e-7", "--dissipation-layer", "2e-7"])
    assert res.exit_code == 0, res.output
    lines = res.output.splitlines()
    meshed = next(line for line in lines if "near a support" in line)
    assert " s a point at 3 mm, " in meshed and meshed.endswith(" s a point at 5 mm")
    layer = next(line for line in lines if "dissipation layers" in line)
    assert re.fullmatch(r"  2 dissipation layers: the plates' responses read from the store, "
                        r"only the chains run \(damped: [0-9.]+x the elastic chain's time\): "
                        r"[0-9.]+ (s|min)", layer), layer
    assert any(line.startswith("  estimated time: ") for line in lines)


def test_the_plan_times_each_plate_by_the_models_own_count() -> None:
    """The model's step and dof counts set each plate's time: a 19.05 mm chain on a clamped 6 mm
    steel plate runs half the plate steps of a 5 mm one (the step, quantised to the sample
    period, doubles there), so it costs about half, while 4 and 5 mm cost alike; a smooth law
    through pilots at 4, 6 and 8 mm put the 5 mm row at 60 % of what it took. Counted without
    running anything (the plan builds the meshes only)."""
    from solitonde.instrument.tables.sweep import Sweep
    from solitonde.instrument.tables.table_build import plate_model_costs

    sweep = Sweep([19.05e-3], [4e-3, 5e-3, 6e-3], [0.04], scene={
        "plate": {"size": [0.6, 0.6], "material": "steel_structural",
                  "supports": "opposite_edges"}})
    (c4, _), = plate_model_costs(sweep, 0, 0)
    (c5, chain5), = plate_model_costs(sweep, 1, 0)
    (c6, chain6), = plate_model_costs(sweep, 2, 0)
    assert c5 / c4 == pytest.approx(1.0, abs=0.1)
    assert c5 / c6 == pytest.approx(2.0, rel=0.1)
    assert 0 < chain6 < c6 and 0 < chain5 < c5  # the chain alone: what a stored response leaves


def test_the_plan_says_what_it_counted() -> None:
    """The plan's last line: the time still to come, what was spent before it, and the total;
    a measured slowdown of busy workers is named."""
    from solitonde.instrument.cli.cmd_table import plan_text
    from solitonde.instrument.tables.sweep import Sweep
    from solitonde.instrument.tables.table_build import BuildPlan

    sweep = Sweep([9.53e-3], [3e-3], [0.3])
    plan = BuildPlan(sweep, 1, 1, {"dashpot": 1}, {"dashpot": [(3e-3, 0.5, 0.1)]},
                     pilot_wall_s=3.0, eta_s=60.0, workers=2, layers=1, layers_eta_s=20.0,
                     start_s=4.0, slopes_eta_s=1.0, elapsed_s=8.0, slowdown=1.3,
                     damped_factor=1.4)
    lines = plan_text(plan).splitlines()
    assert ("  1 dissipation layer: the plates' responses read from the store, only the chains "
            "run (damped: 1.4x the elastic chain's time): 20 s") in lines
    assert lines[-1] == ("  estimated time: 81 s on 2 workers after a 3 s pilot and the "
                         "workers' 4 s start (89 s in all)")
    assert "  material slopes: 1 s" in lines
    # the seconds the command ran before its build began count in the total
    assert plan_text(plan, before_s=2.0).splitlines()[-1].endswith("(1.5 min in all)")
    small = BuildPlan(sweep, 1, 1, {"dashpot": 1}, {"dashpot": [(3e-3, 0.5, 0.1)]},
                      pilot_wall_s=1.0, eta_s=2.0, workers=1, elapsed_s=1.0, here=True)
    assert plan_text(small).splitlines()[-1] == (
        "  estimated time: 2 s here, a plate at a time (less than the workers' start would "
        "take) after a 1 s pilot (3 s in all)")
    assert "  (a plate takes 1.3x the pilot's time with every worker busy: counted)" in lines
