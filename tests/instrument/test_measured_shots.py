"""The measured-shot road (instrument.inference.measured_shots) is one for the command line and
the service: the same metadata is refused by both, naming the field, and shots are grouped by
position the same way however a coordinate was spelled."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app as build_cli
from solitonde.instrument.inference import measured_shots
from solitonde.instrument.inference.measured_shots import (
    ShotInputError,
    ShotLimitError,
    check_metadata,
    position_key,
    shot_fields,
)
from solitonde.instrument.service.app import build_app
from solitonde.instrument.service.settings import Settings

DATA = Path(__file__).resolve().parents[2] / "data_samples" / "waveforms"
CSV = DATA / "synthetic_D9.53_t4.83_snr40.csv"  # two shots, plate and position in its metadata


def _cli(*args: str):
    return CliRunner().invoke(build_cli(), [str(a) for a in args])


def _with_header(tmp_path: Path, line: str, value: str) -> Path:
    text = CSV.read_text()
    old = next(row for row in text.splitlines() if row.startswith(f"# {line}:"))
    path = tmp_path / "shot.csv"
    path.write_text(text.replace(old, f"# {line}: {value}"))
    return path


@pytest.mark.parametrize(("metadata", "field", "error"), [
    ({"sphere_diameter": "abc"}, "sphere_diameter", ShotInputError),
    ({"sphere_diameter": 2.0}, "sphere_diameter", ShotInputError),
    ({"sphere_diameter": True}, "sphere_diameter", ShotInputError),
    ({"x_m": float("nan")}, "x_m", ShotInputError),
    ({"y_m": "left"}, "y_m", ShotInputError),
    ({"plate_id": "P" * 201}, "plate_id", ShotLimitError),
    ({"note": "n" * 1001}, "note", ShotLimitError),
])
def test_check_metadata_names_the_field(metadata, field, error) -> None:
    with pytest.raises(error) as caught:
        check_metadata([{}, metadata], shot_fields("shots"))
    assert caught.value.field == f"shots.1.metadata.{field}"
    assert str(caught.value).startswith(f"shots.1.metadata.{field}: ")
    check_metadata([{"sphere_diameter": 9.53e-3, "x_m": 0.2, "plate_id": "P" * 200}],
                   shot_fields("shots"))


def test_a_position_outside_the_plate_is_refused_where_the_plate_is_known() -> None:
    check_metadata([{"x_m": 0.9}], shot_fields(""))  # no plate size: any finite metres
    with pytest.raises(ShotInputError, match=r"x_m: 0.9 is not a position on the plate "
                       r"\(allowed: 0..0.5 m"):
        check_metadata([{"x_m": 0.9}], shot_fields(""), plate_size=(0.5, 0.5))


def test_positions_group_however_a_coordinate_was_spelled() -> None:
    assert position_key({"plate_id": "P", "position": "A", "x_m": 1, "y_m": "0.25"}) == \
        position_key({"plate_id": "P", "position": "A", "x_m": 1.0, "y_m": 0.25})
    groups = measured_shots.by_position(
        [{"x_m": 1}, {"x_m": 2.0}, {"x_m": 1.0}], lambda m: position_key(m))
    assert [len(g) for g in groups.values()] == [2, 1]


def test_one_measurement_holds_one_position() -> None:
    with pytest.raises(ShotInputError) as caught:
        measured_shots.one_position([{"position": "A"}, {"position": "B"}],
                                    shot_fields("shots"))
    assert caught.value.field == "shots.1.metadata.position"


def test_a_flag_the_service_would_refuse_is_a_usage_error_naming_the_flag() -> None:
    """`--plate-id` longer than the service's 200 characters: refused before any work."""
    res = _cli("analyze", CSV, "--plate-id", "P" * 201, "--json")
    assert res.exit_code == 2, res.output
    assert "--plate-id: 201 characters; at most 200" in res.output


def test_the_cli_and_the_service_refuse_the_same_file(tmp_path: Path) -> None:
    """A file stating a sphere size of 2.5 m: the service answers 422 naming the metadata key,
    `analyze` fails that file naming the same key (it analysed it before), each saying that
    sizes are in metres."""
    path = _with_header(tmp_path, "sphere_diameter", "2.5")
    res = _cli("analyze", path, "--json")
    assert res.exit_code == 1, res.output
    (err,) = json.loads(res.stdout)["errors"]
    assert err["error"].startswith("metadata.sphere_diameter: sizes are in metres: 2.5 mm is "
                                   "2.5e-3")
    settings = Settings(store_path=tmp_path / "store.sqlite")
    with TestClient(build_app(settings)) as client:
        r = client.post("/v1/measurements", files={"file": (path.name, path.read_bytes())})
    assert r.status_code == 422, r.text
    assert r.json()["field"] == "file.shots.0.metadata.sphere_diameter"
    assert "sizes are in metres: 2.5 mm is 2.5e-3" in r.json()["detail"]
    # the same file with a plausible size goes through both
    good = _with_header(tmp_path, "sphere_diameter", "0.00953")
    assert _cli("analyze", good, "--json").exit_code == 0
