"""Synthetic validation end to end on a tiny table (coarse plate mesh), and the CLI contract."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app
from solitonde.instrument.studies.validate import validate
from solitonde.instrument.tables.table import ModelTable
from solitonde.instrument.tables.table_build import Sweep, build_table
from solitonde.signal.features import AGGREGATE_VERSION

FAST = {"sem": {"elements": [6, 6, 1], "order": [2, 2, 2]}}


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("val") / "tiny.h5"
    distances = [0.0, 0.01, 0.03, 0.06, 0.1, 0.16, 0.3, 0.457]
    build_table(Sweep([4.76e-3, 9.53e-3], [2.5e-3, 3.5e-3, 5e-3], distances, scene=FAST), out,
                workers=1)
    return out


def test_validation_scores_and_calibration(tiny: Path, tmp_path: Path) -> None:
    """The fitted calibration finds the known dissipation (ARR lowered more for the smaller
    sphere, reflection later); estimates land near the truth; the draw is reproducible and the
    stored measurements are reused."""
    table = ModelTable.load(tiny)
    store = tmp_path / "m.json"
    report = validate(table, 6, seed=2, workers=1, measurements=store)
    m = report.metrics
    f_small, o_small = report.calibration.for_diameter(4.76e-3)
    f_big, _ = report.calibration.for_diameter(9.53e-3)
    assert 0.75 < f_small < 0.95 and f_small < f_big < 1.0
    assert o_small > 0
    assert m["n"] == 6 and m["n_estimated"] >= 3
    assert m["thickness_error_median"] < 0.08
    for key in ("coverage_95", "status_accuracy"):
        assert 0.0 <= m[key] <= 1.0
    again = validate(table, 6, seed=2, workers=1, measurements=store)
    assert again.metrics["thickness_error_median"] == m["thickness_error_median"]
    assert again.metrics["simulation_wall_s"] == m["simulation_wall_s"]  # reused, not rerun
    # shots summarised by the fixed outlier level of before: simulated again, not reused
    old = json.loads(store.read_text())
    assert old["key"]["aggregate_version"] == AGGREGATE_VERSION
    old["key"]["aggregate_version"] = 1
    store.write_text(json.dumps(old))
    redone = validate(table, 6, seed=2, workers=1, measurements=store)
    assert redone.metrics["simulation_wall_s"] != m["simulation_wall_s"]
    assert json.loads(store.read_text())["key"]["aggregate_version"] == AGGREGATE_VERSION


def test_validate_cli_json_keys(tiny: Path) -> None:
    """`solitonde validate --json` prints the public keys."""
    result = CliRunner().invoke(build_app(), ["validate", "--n", "2", "--seed", "1", "--table",
                                              str(tiny), "--workers", "1", "--no-progress",
                                              "--diameters", "4.76e-3", "--json"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.output)
    for key in ("thickness_error_median", "thickness_error_p90", "coverage_95",
                "status_accuracy", "coverage_95_two_sided", "answered", "interval_width_median",
                "inconsistent_rate", "flagged_or_covered", "missed_unflagged",
                "ambiguous_rate", "by_distance"):
        assert key in data
    assert data["wrong_family"] is None and 0.0 <= data["answered"] <= 1.0


def test_validate_one_shot_near_the_support_scores_by_distance(tiny: Path) -> None:
    """``--shots 1 --near-support 0.03``: every plate drawn within 30 mm of the support, one shot
    per size; ``by_distance`` holds the non-empty bins and adds up to the plates."""
    result = CliRunner().invoke(build_app(), [
        "validate", "--n", "3", "--seed", "4", "--table", str(tiny), "--workers", "1",
        "--no-progress", "--diameters", "9.53e-3", "--shots", "1", "--near-support", "0.03",
        "--json"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.output)
    assert data["shots"] == 1 and data["near_support_m"] == 0.03
    assert 0.0 <= data["ambiguous_rate"] <= 1.0
    bins = data["by_distance"]
    assert sum(b["n"] for b in bins) == 3
    for b in bins:
        assert b["distance_m"][1] is not None and b["distance_m"][1] <= 0.03
        assert set(b) == {"distance_m", "n", "answered", "coverage_95", "missed_unflagged",
                          "ambiguous_rate"}


@pytest.mark.parametrize(("args", "field", "hint"), [
    (["--near-support", "0"], "--near-support", "beyond the table's nearest"),
    (["--near-support", "nan"], "--near-support", "beyond the table's nearest"),
])
def test_validate_near_support_must_hold_a_distance(tmp_path: Path, args: list[str], field: str,
                                                    hint: str) -> None:
    output = _bad_validate(tmp_path, *args)
    assert output.startswith(f"error: {field}:") and hint in output


def test_validate_wrong_family_simulates_another_material(tiny: Path) -> None:
    """`--wrong-family MATERIAL`: the truths on that plate, the table's own reference plates;
    the scores say how often the answer is flagged or covers. A name not in the library is one
    error line naming the flag."""
    runner = CliRunner()
    result = runner.invoke(build_app(), ["validate", "--n", "2", "--seed", "1", "--table",
                                         str(tiny), "--workers", "1", "--no-progress",
                                         "--diameters", "9.53e-3", "--json",
                                         "--wrong-family", "steel_structural"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.output)
    assert data["wrong_family"] == "steel_structural"
    assert 0.0 <= data["flagged_or_covered"] <= 1.0
    assert data["missed_unflagged"] + data["flagged_or_covered"] <= 1.0 + 1e-12
    bad = runner.invoke(build_app(), ["validate", "--n", "1", "--table", str(tiny),
                                      "--workers", "1", "--no-progress", "--wrong-family",
                                      "unobtainium"])
    assert bad.exit_code == 2 and bad.output.startswith("error: --wrong-family:")


def test_table_and_invert_cli(tiny: Path) -> None:
    """`table info --json` and `invert --json` on the same table: the public keys."""
    runner = CliRunner()
    info = runner.invoke(build_app(), ["table", "info", str(tiny), "--json"])
    assert info.exit_code == 0, info.output
    assert json.loads(info.output)["shape"] == [2, 3, 8]
    table = ModelTable.load(tiny)
    tof, arr = float(table.features["tof_s"][0, 1, 7]), float(table.features["arr"][0, 1, 7])
    res = runner.invoke(build_app(), ["invert", "--tof", str(tof), "--arr", str(arr),
                                      "--diameter", "4.76e-3", "--table", str(tiny), "--json"])
    assert res.exit_code == 0, res.output
    data = json.loads(res.output)
    for key in ("thickness_m", "distance_m"):
        assert {"map", "median", "ci68", "ci95", "status"} <= set(data[key])
    bad = runner.invoke(build_app(), ["invert", "--tof", str(tof), "--arr", str(arr),
                                      "--diameter", "7e-3", "--table", str(tiny)])
    assert bad.exit_code == 2 and "diameter_m" in bad.output


DEFAULT_TABLE = Path(__file__).resolve().parents[2] / "data_samples" / "default_table.h5"


def _bad_validate(tmp_path: Path, *args: str) -> str:
    result = CliRunner().invoke(build_app(), ["validate", "--n", "1", "--table",
                                              str(DEFAULT_TABLE), "--workers", "1",
                                              "--no-progress", *args])
    assert result.exit_code == 2, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    assert "Traceback" not in result.output
    return result.output


@pytest.mark.parametrize(("args", "field", "hint"), [
    (["--diameters", "0.0127"], "--diameters", "not a sphere size of this table"),
    (["--diameters", "abc"], "--diameters", "not a number"),
    (["--diameters", "9.53e-3,abc"], "--diameters", "not a number"),
    (["--diameters", "9.53e-3,0.00953"], "--diameters", "listed twice"),
    (["--diameters", "9.53e-3", "--diameters", "0.00953"], "--diameters", "listed twice"),
    (["--diameters", "4.76e-3", "--diameters", "abc"], "--diameters", "not a number"),
    (["--diameters", "nan"], "--diameters", "not a sphere size"),
    (["--seed", "-1"], "--seed", ">= 0"),
])
def test_validate_bad_flags_are_one_error_line(tmp_path: Path, args: list[str], field: str,
                                               hint: str) -> None:
    output = _bad_validate(tmp_path, *args)
    assert output.startswith(f"error: {field}:") and hint in output


@pytest.mark.parametrize("text", ["{bad", "[1]", '{"key": 1}', "\xff\xfe"])
def test_validate_corrupt_measurements_file_is_refused_not_overwritten(tmp_path: Path,
                                                                       text: str) -> None:
    store = tmp_path / "m.json"
    store.write_bytes(text.encode("latin-1"))
    output = _bad_validate(tmp_path, "--measurements", str(store))
    assert output.startswith("error: --measurements:") and "delete it" in output
    assert store.read_bytes() == text.encode("latin-1")


def test_validate_measurements_of_the_draw_but_malformed_plates_is_refused(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A file whose key matches this draw but whose plates were edited: an error, not a
    KeyError in the scoring."""
    from solitonde.instrument.studies import validate as module

    seen: dict[str, object] = {}

    def capture(path: object, key: dict[str, object]) -> None:
        seen.update(key)
        raise RuntimeError("stop")

    with monkeypatch.context() as patch:
        patch.setattr(module, "_load_measurements", capture)
        with pytest.raises(RuntimeError):
            validate(ModelTable.load(DEFAULT_TABLE), 1, seed=0, measurements=tmp_path / "x")
    store = tmp_path / "m.json"
    store.write_text(json.dumps({"key": seen, "plates": [{"thickness_m": 0.003}] * 2,
                                 "wall_s": 1.0}))
    output = _bad_validate(tmp_path, "--measurements", str(store))
    assert output.startswith("error: --measurements:") and "KeyError" in output


@pytest.mark.parametrize("flag", ["--out", "--measurements"])
def test_validate_output_paths_are_checked_before_simulating(tmp_path: Path, flag: str) -> None:
    output = _bad_validate(tmp_path, flag, str(tmp_path))
    assert output.startswith(f"error: {flag}:") and "directory" in output
    output = _bad_validate(tmp_path, flag, str(tmp_path / "missing" / "x.json"))
    assert output.startswith(f"error: {flag}:") and "does not exist" in output


def test_validate_function_refuses_a_negative_seed() -> None:
    from solitonde.instrument.studies.validate import ValidationInputError

    with pytest.raises(ValidationInputError) as info:
        validate(ModelTable.load(DEFAULT_TABLE), 1, seed=-1)
    assert info.value.field == "seed"


def test_validate_refuses_an_unknown_truth_plate_theory(tmp_path: Path) -> None:
    """The plate theory behind the truths is named and checked before any simulation."""
    from solitonde.instrument.studies.validate import ValidationInputError

    with pytest.raises(ValidationInputError) as info:
        validate(ModelTable.load(DEFAULT_TABLE), 1, truth_plate_theory="kirchhoff")
    assert info.value.field == "truth_plate_theory"
    output = _bad_validate(tmp_path, "--truth-plate-theory", "kirchhoff")
    assert output.startswith("error: --truth-plate-theory:") and "3d" in output


def test_plate_materials_are_drawn_with_the_grades_spread() -> None:
    """Each plate's E, nu and rho come from a normal distribution about the table's value with
    the spread its intervals state (6061-T6: E 0.85 %, nu 0.010, rho 0.37 %). With 4,000 draws a
    sample sd is known to 1.1 % (1 / sqrt(2n)), its mean to 1.6 % of an sd: 5 % and 6 % of an sd
    are 4-sigma bounds."""
    from solitonde.instrument.inference.material_spread import spread_of
    from solitonde.instrument.studies.validate import draw_plate_materials
    from solitonde.model.materials import properties_from

    table = ModelTable.load(DEFAULT_TABLE)
    spread = spread_of(table)
    plates = draw_plate_materials(table, spread, 4000, np.random.default_rng(5))
    nominal = table.family["plate_material"]
    for key, sd_key, relative in (("youngs_modulus", "youngs_modulus_rel_sd", True),
                                  ("poisson_ratio", "poisson_ratio_sd", False),
                                  ("density", "density_rel_sd", True)):
        values = np.array([p[key] for p in plates])
        stated = spread[sd_key] * (nominal[key] if relative else 1.0)
        assert stated > 0
        assert abs(values.std() / stated - 1.0) < 0.05, key
        assert abs(values.mean() - nominal[key]) < 0.06 * stated, key
    properties_from(plates[0])  # a mapping a scene accepts


def test_validate_simulates_each_plate_on_its_drawn_material(tiny: Path, tmp_path: Path) -> None:
    """The same draw (seed) with and without ``--exact-material``: the same plates (t, L), the
    drawn materials recorded per row and in the metrics, and the measured features differ, so
    the draw reached the simulation; stored measurements of one are not reused for the other."""
    runner = CliRunner()
    store = tmp_path / "m.json"
    rows, measured = {}, {}
    for flag in ("--draw-material", "--exact-material"):
        out = tmp_path / f"{flag}.json"
        result = runner.invoke(build_app(), ["validate", "--n", "1", "--seed", "4", "--table",
                                             str(tiny), "--workers", "1", "--no-progress",
                                             "--diameters", "9.53e-3", "--json", flag,
                                             "--measurements", str(store), "--out", str(out)])
        assert result.exit_code == 0, result.output
        rows[flag] = json.loads(out.read_text())
        measured[flag] = json.loads(store.read_text())
    drawn, exact = rows["--draw-material"], rows["--exact-material"]
    assert drawn["metrics"]["material_spread_drawn"]["youngs_modulus_rel_sd"] > 0
    assert exact["metrics"]["material_spread_drawn"] is None
    (d,), (x,) = drawn["scenes"], exact["scenes"]
    assert (d["thickness_m"], d["distance_m"]) == (x["thickness_m"], x["distance_m"])
    assert x["plate_material"] is None
    assert d["plate_material"]["name"].endswith("(drawn)")
    assert d["plate_material"]["youngs_modulus"] != pytest.approx(
        ModelTable.load(tiny).family["plate_material"]["youngs_modulus"], rel=1e-9)
    assert measured["--exact-material"]["key"]["material_spread_drawn"] is None  # rewritten
    (pd,), (px,) = (m["plates"][1:] for m in measured.values())  # [0]: the reference plate
    sd, sx = (next(iter(p["summaries"].values())) for p in (pd, px))
    assert sd["arr"] != sx["arr"] and sd["tof_s"] != sx["tof_s"]


def test_truths_on_the_3d_plate_are_meshed_as_finely_as_the_mindlin_plate(tiny: Path) -> None:
    """``--truth-plate-theory 3d``: a thin plate's truth takes the Mindlin plate's in-plane
    elements (the flexural-wavelength rule), not the 3-D plate's default 16 x 16, which does
    not resolve its flexural waves; a thick plate keeps the default; the other truths are as
    the table's scene says. The stored draw's key names the mesh, so shots simulated on the
    coarser 3-D plate are never reused."""
    from solitonde.instrument.studies.validate import TRUTH_MESH, _draw, _draw_key, _scene_dict
    from solitonde.model.scene import apply_overrides, scene_from_dict
    from solitonde.model.tiers.meshed import mindlin_elements

    base_3d = apply_overrides({}, {"sem.plate_theory": "3d"})
    thin = _scene_dict(base_3d, 9.53e-3, 1.99e-3, 0.047)
    expected = mindlin_elements(scene_from_dict(apply_overrides(
        {}, {"chain.diameter": 9.53e-3, "plate.thickness": 1.99e-3})))
    assert thin["sem"]["elements"] == list(expected)
    assert expected[0] > 16 and expected[1] > 16  # thinner than the default mesh resolves
    thick = _scene_dict(base_3d, 9.53e-3, 12e-3, 0.047)
    assert thick["sem"]["elements"] == [16, 16, 1]
    assert "elements" not in _scene_dict({}, 9.53e-3, 1.99e-3, 0.047).get("sem", {})
    assert scene_from_dict(thin).sem.plate_theory == "3d"
    table = ModelTable.load(tiny)
    draw = _draw(table, 1, 0, 0.457, False)
    keys = [_draw_key(table, 1, 0, [9.53e-3], base, 1, None, draw, False)
            for base in (base_3d, {})]
    assert keys[0]["truth_mesh"] == TRUTH_MESH and "truth_mesh" not in keys[1]
