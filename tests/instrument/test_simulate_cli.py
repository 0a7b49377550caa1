"""`solitonde simulate`: JSON contract, CSV round trip through the signal reader, plot, errors."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app
from solitonde.model.scene import scene_from_dict
from solitonde.signal import io as signal_io

KEYS = ["plate_model", "tof_s", "arr", "incident_peak_N", "reflected_peak_N", "incident_time_s",
        "reflected_time_s", "energy_drift", "steps", "dt_s", "wall_s", "status"]


@pytest.fixture(scope="module")
def runner():
    return CliRunner()


def test_json_out_and_plot(runner, tmp_path):
    """--json has the contract keys; --out reads back with the scene; --plot writes a PNG."""
    out, png = tmp_path / "trace.csv", tmp_path / "trace.png"
    res = runner.invoke(build_app(), ["simulate", "--set", "plate.thickness=4.83e-3", "--json",
                                      "--out", str(out), "--plot", str(png)])
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    assert list(data)[:12] == KEYS
    assert data["plate_model"] == "infinite"
    assert data["status"] == "reflection_passed"
    assert 0.0 < data["arr"] < 1.0 and data["tof_s"] > 0.0
    # Features measured from the trace agree with the model's own peaks.
    assert data["tof_s"] == pytest.approx(data["model_truth"]["tof_s"], rel=0.02)
    assert out.read_text().splitlines()[0].startswith("# ")
    assert "time_s,force_N" in out.read_text().splitlines()
    wave = signal_io.read(out)[0]
    assert wave.units == "N"
    assert wave.n == data["n_samples"]
    assert scene_from_dict(wave.metadata["scene"]).plate.thickness == 4.83e-3
    assert png.stat().st_size > 10_000


def test_bad_input_and_impossible_request(runner):
    """A bad --set names the field (exit 2); an impossible duration says why (exit 1)."""
    res = runner.invoke(build_app(), ["simulate", "--set", "plate.thickness=-1"])
    assert res.exit_code == 2
    assert "plate.thickness" in res.output
    res = runner.invoke(build_app(), ["simulate", "--set", "output.duration=100"])
    assert res.exit_code == 1
    assert "step_budget_exceeded" in res.output


def test_unmeasurable_trace_and_non_utf8_scene(runner, tmp_path):
    """A legal scene sampled too coarsely to measure its pulse, and a scene file that is not UTF-8
    text, each get an error naming what to change (exit 2), not a traceback."""
    res = runner.invoke(build_app(), ["simulate", "--set", "output.sample_rate=2e4", "--json"])
    assert res.exit_code == 2 and isinstance(res.exception, SystemExit)
    assert "output.sample_rate" in res.output and "too few samples" in res.output
    scene = tmp_path / "notepad.yaml"
    scene.write_bytes("chain:\n  n_particles: 20\n".encode("utf-16"))
    res = runner.invoke(build_app(), ["simulate", str(scene)])
    assert res.exit_code == 2 and isinstance(res.exception, SystemExit)
    assert "not UTF-8 text" in res.output


def test_out_or_plot_a_folder_is_refused_before_the_run(runner, tmp_path):
    folder = tmp_path / "trace.csv"
    folder.mkdir()
    for flag in ("--out", "--plot"):
        res = runner.invoke(build_app(), ["simulate", flag, str(folder)])
        assert res.exit_code == 2 and isinstance(res.exception, SystemExit), res.output
        assert f"error: {flag}: " in res.output and "folder" in res.output
    assert [p.name for p in tmp_path.iterdir()] == ["trace.csv"]


def test_an_output_that_cannot_be_written_is_an_error_after_the_result(runner, tmp_path):
    """The shot's JSON still prints; the exit code is 1; no temporary file is left behind."""
    (tmp_path / "afile").write_text("x")
    res = runner.invoke(build_app(), ["simulate", "--json", "--plot",
                                      str(tmp_path / "afile" / "t.png")])
    assert res.exit_code == 1 and isinstance(res.exception, SystemExit), res.output
    assert list(json.loads(res.stdout))[:12] == KEYS
    assert "error: --plot: cannot write" in res.stderr
    assert [p.name for p in tmp_path.iterdir()] == ["afile"]


def test_a_3d_plate_coarser_than_the_wavelength_rule_is_said_to_be(runner):
    """The 3-D plate takes ``sem.elements`` as given; where they are fewer than the flexural
    wavelength asks (what the Mindlin plate would take), the JSON's mesh says so under
    ``coarse`` and the text run warns on stderr, naming the elements that resolve it. A
    Mindlin run of the same plate, and a 3-D mesh as fine as the rule, say nothing."""
    from solitonde.model.tiers.meshed import coarse_3d_note, mindlin_elements

    near = ["--set", "plate.distance_to_support=0.02", "--set", "sem.order=[2,2,2]"]
    res = runner.invoke(build_app(), ["simulate", *near, "--set", "sem.plate_theory=3d",
                                      "--set", "sem.elements=[4,4,1]"])
    assert res.exit_code == 0, res.output
    wanted = mindlin_elements(scene_from_dict({"plate": {"distance_to_support": 0.02}}))
    assert (f"warning: the 3-D plate's sem.elements 4 x 4 are fewer than the flexural-wavelength"
            f" rule gives this plate ({wanted[0]} x {wanted[1]}") in res.stderr
    assert f"sem.elements [{wanted[0]}, {wanted[1]}, 1] resolves them" in res.stderr
    res = runner.invoke(build_app(), ["simulate", *near, "--set", "sem.plate_theory=mindlin",
                                      "--json"])
    assert res.exit_code == 0, res.output
    assert "coarse" not in json.loads(res.stdout)["mesh"] and "warning" not in res.stderr
    fine = scene_from_dict({"plate": {"distance_to_support": 0.02},
                            "sem": {"plate_theory": "3d", "elements": list(wanted)}})
    assert coarse_3d_note(fine) is None
    thick = scene_from_dict({"plate": {"thickness": 12e-3}, "sem": {"plate_theory": "3d"}})
    assert coarse_3d_note(thick) is None  # the default 16 x 16 resolves a 12 mm plate
