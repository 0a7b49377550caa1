"""Answers that know their limits, on recordings from an independent solve written for the tests.

A 4.0 mm structural-steel plate (E 210 GPa, nu 0.30, rho 7850) under the paper's chain (D 9.53 mm,
gravity on), solved by scipy's DOP853 on Zener's dashpot (tests/support/independent_chain.py, no
model code), five shots at 40 dB. Against the bundled aluminium table the answer must be flagged
inconsistent (the command exits 1, the service answers 201 with the warning); against the bundled
steel table (E 200 GPa, nu 0.26: a near miss, the plate 2.4 sd out in E' at the corner of its
grade's range) every answer must say that the data sit at the edge of the material's range, and
hold 4.0 mm or be read with that warning. Over noise draws 1-12 ten intervals hold it by 149 um or
more; two (draws 1 and 5) miss it by 1.4 and 3.4 um, flagged: with TOF read by a spline far from
the supports the table no longer states the straight line's interpolation error there, which had
widened these intervals enough to reach the truth. The material's linearised spread holds a
plate this far out only in part, and says so. Never a constrained interval that misses with no
warning.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from independent_chain import sensor_trace, write_shots
from recordings import STEEL, STEEL_TABLE, post_recording, steel_shots
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app as build_cli
from solitonde.instrument.inference.inversion import invert
from solitonde.instrument.inference.inversion_inputs import FeatureSummary
from solitonde.instrument.service.app import build_app
from solitonde.instrument.service.settings import Settings
from solitonde.instrument.tables.table import ModelTable
from solitonde.model.materials import DEFAULT_PROPERTY_SPREAD

ROOT = Path(__file__).resolve().parents[2]
ALUMINIUM = ROOT / "data_samples" / "default_table.h5"
TRUTH_M = 4.0e-3


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    t, force = sensor_trace(STEEL, TRUTH_M)
    folder = tmp_path_factory.mktemp("steel")
    steel_shots(folder / "steel.csv", t, force)
    return folder / "steel.csv"


def _analyze(*args: str) -> tuple[int, dict]:
    result = CliRunner().invoke(build_cli(), ["analyze", *args, "--json"])
    return result.exit_code, json.loads(result.stdout)


def _at_material_edge(estimate: dict) -> bool:
    return any(w.startswith("the data sit at the edge of the material's range")
               for w in estimate["warnings"])


def _never_a_silent_miss(estimate: dict) -> None:
    t = estimate["thickness_m"]
    if t["status"] == "constrained":
        low, high = t["ci95"]
        assert (low <= TRUTH_M <= high or _at_material_edge(estimate)
                or any(w.startswith("inconsistent") for w in estimate["warnings"])), t


def test_steel_against_the_aluminium_table_is_flagged_inconsistent(recording: Path) -> None:
    code, out = _analyze(str(recording), "--invert", "--sphere-diameter", "9.53e-3", "--table",
                         str(ALUMINIUM))
    assert code == 1
    est = out["estimates"][0]["estimate"]
    assert est["thickness_m"]["status"] == "inconsistent"
    assert est["distance_m"]["status"] == "inconsistent"
    assert est["warnings"][0].startswith("inconsistent:")
    assert "plate's material is not the table's" in est["warnings"][0]
    assert {"chi2", "dof", "p_value"} <= set(est["fit"])
    assert any("inconsistent" in e["error"] for e in out["errors"])
    _never_a_silent_miss(est)


def test_steel_against_the_near_miss_steel_table_is_read_at_the_materials_edge(
        recording: Path) -> None:
    code, out = _analyze(str(recording), "--invert", "--sphere-diameter", "9.53e-3", "--table",
                         str(STEEL_TABLE))
    assert code == 0, out["errors"]
    est = out["estimates"][0]["estimate"]
    assert est["thickness_m"]["status"] == "constrained"
    low, high = est["thickness_m"]["ci95"]
    assert _at_material_edge(est), est["warnings"]
    # a plate 7.6 % stiffer in E' than the table's bends like one (1.076)^(1/3) = 2.5 % thicker
    # (D ~ E' t^3): the material's mismatch alone can move the answer no further
    assert abs(est["thickness_m"]["median"] - TRUTH_M) < 0.025 * TRUTH_M
    assert high - low < 0.15 * TRUTH_M  # an answer, not the whole grade's range of readings
    assert est["fit"]["p_value"] > 1e-3
    assert est["material_spread"]["youngs_modulus_rel_sd"] > 0  # the library's, for A36 steel
    assert any(w.startswith("no calibration") for w in est["warnings"])
    _never_a_silent_miss(est)
    # the spread is what brings the truth in: the same features with the properties taken as
    # exact read the plate further from 4.0 mm (the TOF and ARR of a stiffer steel disagree
    # about the thickness; the material's direction reconciles them)
    exact = invert(ModelTable.load(STEEL_TABLE), [FeatureSummary.from_any(est["inputs"][0])],
                   material_spread={"youngs_modulus_rel_sd": 0.0, "poisson_ratio_sd": 0.0,
                                    "density_rel_sd": 0.0})
    assert abs(est["thickness_m"]["median"] - TRUTH_M) < abs(exact.thickness_m.median - TRUTH_M)


def test_the_service_answers_201_with_the_warning(recording: Path, tmp_path: Path) -> None:
    r = post_recording(recording, ALUMINIUM, tmp_path / "s.sqlite")
    assert r.status_code == 201, r.text
    est = r.json()["estimate"]
    assert est["thickness_m"]["status"] == "inconsistent"
    assert est["warnings"][0].startswith("inconsistent:")


def test_a_plate_given_by_its_properties_is_checked_against_the_table(recording: Path) -> None:
    """--plate-material takes a property mapping: the steel plate's own properties are not the
    aluminium table's family (refused, exit 1 naming the flag); with its spread stated, the
    steel table's family still differs (E 210 vs 200 GPa) and is refused too."""
    mapping = json.dumps({"name": "S235", **STEEL, "youngs_modulus_rel_sd": 0.03})
    code, out = _analyze(str(recording), "--invert", "--sphere-diameter", "9.53e-3", "--table",
                         str(ALUMINIUM), "--plate-material", mapping)
    assert code == 1
    assert out["estimates"][0]["error"].startswith("--plate-material:")
    bad = CliRunner().invoke(build_cli(), ["analyze", str(recording), "--invert",
                                           "--plate-material", '{"name": "x", "density": 1}'])
    assert bad.exit_code == 2 and "--plate-material: [youngs_modulus] missing" in bad.output


def test_the_near_miss_is_held_or_flagged_in_every_noise_draw(tmp_path: Path) -> None:
    """The same plate in noise draws 1-12: every answer says the data sit at the edge of the
    material's range, and each holds 4.0 mm by more than 50 um (not by a micrometre's luck), or
    one of its readings does, or it is read with that warning alone (draws 1 and 5 miss by
    micrometres). Most hold it: a warning is no licence to miss by far."""
    held = 0
    t, force = sensor_trace(STEEL, TRUTH_M)
    for seed in range(1, 13):
        path = write_shots(tmp_path / f"s{seed}.csv", t, force, shots=5, snr_db=40.0, seed=seed,
                           metadata={"plate_id": "steel-4mm"})
        code, out = _analyze(str(path), "--invert", "--sphere-diameter", "9.53e-3", "--table",
                             str(STEEL_TABLE))
        assert code == 0, (seed, out["errors"])
        est = out["estimates"][0]["estimate"]
        spans = ([r["thickness_m"]["ci95"] for r in est["readings"]]
                 or [est["thickness_m"]["ci95"]])
        margins = [min(TRUTH_M - lo, hi - TRUTH_M) for lo, hi in spans]
        assert _at_material_edge(est), (seed, est["warnings"])
        held += max(margins) > 50e-6
        assert abs(est["thickness_m"]["median"] - TRUTH_M) < 0.025 * TRUTH_M, seed
    assert held >= 10


def test_invert_without_a_sphere_size_names_the_flag(recording: Path, tmp_path: Path) -> None:
    text = recording.read_text().splitlines()
    bare = tmp_path / "bare.csv"
    bare.write_text("\n".join(line for line in text if not line.startswith("# plate_id")) + "\n")
    result = CliRunner().invoke(build_cli(), ["analyze", str(bare), "--invert"])
    assert result.exit_code == 1
    assert "--sphere-diameter" in result.output
    assert "(no plate id)" in result.output and "None" not in result.output


def test_rest_plate_material_by_properties_and_a_hidden_reflection(tmp_path: Path) -> None:
    """POST /v1/invert: ``plate_material`` as a property mapping with its spread (the spread is
    the one the intervals carry; another family is a 422 naming plate_material), and a size
    whose shots showed no reflection given by its ARR bound (an upper bound on thickness)."""
    table = ModelTable.load(STEEL_TABLE)
    tof, arr = float(table.features["tof_s"][0, 5, 13]), float(table.features["arr"][0, 5, 13])
    own = {**table.family["plate_material"], "youngs_modulus_rel_sd": 0.05}
    settings = Settings(store_path=tmp_path / "s.sqlite", table_path=STEEL_TABLE)
    with TestClient(build_app(settings)) as client:
        item = {"diameter_m": 9.53e-3, "tof_s": tof, "arr": arr, "n_shots": 5}
        r = client.post("/v1/invert", json={"inputs": [item], "plate_material": own})
        assert r.status_code == 200, r.text
        est = r.json()["estimate"]
        assert est["material_spread"]["youngs_modulus_rel_sd"] == 0.05
        assert est["thickness_m"]["status"] == "constrained" and est["fit"]["p_value"] > 1e-3
        # the same properties under the user's own name, no spread: the stated default,
        # said in the answer's warnings, never a spread of 0
        plain = {**table.family["plate_material"], "name": "plant steel"}
        r = client.post("/v1/invert", json={"inputs": [item], "plate_material": plain})
        assert r.status_code == 200, r.text
        est = r.json()["estimate"]
        assert est["material_spread"] == DEFAULT_PROPERTY_SPREAD
        assert any("default spread of E +- 3 %" in w for w in est["warnings"])
        other = {"name": "S235", **STEEL}
        r = client.post("/v1/invert", json={"inputs": [item], "plate_material": other})
        assert r.status_code == 422 and "plate_material" in r.json()["detail"]
        hidden = {"diameter_m": 9.53e-3, "arr_upper_bound": 0.02, "n_shots": 5}
        r = client.post("/v1/invert", json={"inputs": [hidden]})
        assert r.status_code == 200, r.text
        t = r.json()["estimate"]["thickness_m"]
        assert t["status"] == "upper_bound_only" and t["ci95"][0] is None


def _node(table: ModelTable, i_d: int, i_t: int, i_l: int) -> FeatureSummary:
    return FeatureSummary(float(table.axes["diameter_m"][i_d]),
                          float(table.features["tof_s"][i_d, i_t, i_l]),
                          float(table.features["arr"][i_d, i_t, i_l]), None, None, 5)


def _node_index(table: ModelTable, thickness_m: float) -> int:
    """The thickness node nearest ``thickness_m``."""
    return int(abs(table.axes["thickness_m"] - thickness_m).argmin())


def test_a_size_left_out_where_its_reflection_is_clear_flags_the_answer() -> None:
    """All sizes together out of range, the others agreeing once one is left out: that is the
    known floor-train case only when the left-out size is beyond D/t = 5 at the answer. The
    4.76 mm sphere's features of a 1.5 mm plate beside a 4.15 mm plate's 9.53 and 19.05 mm ones
    are flagged; the three sizes' features of one plate are answered as before."""
    table = ModelTable.load(ALUMINIUM)
    far = table.axes["distance_m"].size - 1
    thick = _node_index(table, 4.15e-3)
    odd = invert(table, [_node(table, 0, 0, far), _node(table, 1, thick, far),
                         _node(table, 2, thick, far)])
    assert odd.extra["excluded_diameters_m"] == [table.axes["diameter_m"][0]]
    assert odd.thickness_m.status == "inconsistent"
    assert "clear one" in odd.warnings[0]
    mid = _node_index(table, 2.87e-3)
    same = invert(table, [_node(table, d, mid, far) for d in range(3)])  # one plate, 2.87 mm
    assert same.thickness_m.status == "constrained" and not same.extra.get(
        "excluded_diameters_m")
    low, high = same.thickness_m.ci95
    assert low <= table.axes["thickness_m"][mid] <= high



def test_an_at_most_answer_with_a_clear_size_left_out_is_flagged() -> None:
    """A 2.28 mm A36 steel plate 193 mm from the support, as `validate --wrong-family
    steel_structural --seed 0` simulated and read it (5 shots at 40 dB, three sizes) and
    calibrated it on two aluminium references, against the aluminium table: with the 4.76 mm
    sphere left out the other two answered "at most 1.86 mm", p = 0.0016, with no flag. An
    "at most" interval runs down to the table's thinnest plate, 1.5 mm, where that sphere's D/t
    is 3.2 and its reflection clear: the family does not explain the sizes together."""
    table = ModelTable.load(ALUMINIUM)
    measured = [FeatureSummary(19.05e-3, 2039.12e-6, 0.034213, 0.437e-6, 0.000756, 4),
                FeatureSummary(9.53e-3, 531.991e-6, 0.285918, 0.0869e-6, 0.001952, 5),
                FeatureSummary(4.76e-3, 251.116e-6, 0.629333, 0.0114e-6, 0.001727, 4)]
    calibration = {"per_diameter": [
        {"diameter_m": 4.76e-3, "arr_factor": 0.99979, "tof_offset_s": -0.0801e-6,
         "tof_offset_std_s": 0.0975e-6, "damping_s": 1.015e-7, "damping_std_s": 1.6e-9},
        {"diameter_m": 9.53e-3, "arr_factor": 0.99944, "arr_factor_std": 0.00742,
         "arr_factor_transfer_std": 0.00742, "tof_offset_s": -0.0568e-6,
         "tof_offset_std_s": 0.138e-6, "damping_s": 1.0175e-7, "damping_std_s": 4.2e-9},
        {"diameter_m": 19.05e-3, "arr_factor": 1.0401, "arr_factor_std": 0.228,
         "arr_factor_transfer_std": 0.228, "tof_offset_s": 19.28e-6, "tof_offset_std_s": 56.9e-6,
         "tof_offset_transfer_std_s": 56.9e-6, "damping_s": 3e-7, "damping_std_s": 3e-7}]}
    est = invert(table, measured, calibration=calibration)
    assert est.extra["excluded_diameters_m"] == [4.76e-3]
    assert est.thickness_m.ci95[0] is None  # the other sizes' answer is an "at most" one
    assert est.thickness_m.status == "inconsistent"
    assert "t >= 1.5 mm" in est.warnings[0] and "clear one" in est.warnings[0]

def test_invert_exits_1_on_an_inconsistent_answer(recording: Path) -> None:
    """`solitonde invert` with the steel recording's features against the aluminium table:
    the answer is printed in full, but the exit status is 1 and stderr says why (issue 28)."""
    _, out = _analyze(str(recording), "--invert", "--sphere-diameter", "9.53e-3", "--table",
                      str(ALUMINIUM))
    agg = out["estimates"][0]["estimate"]["inputs"][0]
    args = ["invert", "--tof", repr(agg["tof_s"]), "--arr", repr(agg["arr"]), "--diameter",
            "9.53e-3", "--tof-std", repr(agg["tof_std_s"]), "--arr-std", repr(agg["arr_std"]),
            "--shots", str(agg["n_shots"]), "--table", str(ALUMINIUM)]
    result = CliRunner().invoke(build_cli(), [*args, "--json"])
    assert result.exit_code == 1, result.output
    assert json.loads(result.stdout)["thickness_m"]["status"] == "inconsistent"
    assert "error: inconsistent: inconsistent:" not in result.stderr
    assert result.stderr.startswith("error: inconsistent")
    assert "plate's material is not the table's" in result.stderr
    text = CliRunner().invoke(build_cli(), args)
    assert text.exit_code == 1
    assert "INCONSISTENT" in text.stdout
