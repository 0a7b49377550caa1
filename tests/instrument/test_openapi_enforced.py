"""The OpenAPI document says what the server enforces: a request it allows is not refused for
the value it allowed (sphere sizes of the loaded table within 1 %, its plate materials and ids,
the scene's keys), and the binary body has a route of its own whose query it describes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from service_support import shot_samples

from solitonde.instrument.service.app import build_app
from solitonde.instrument.service.settings import Settings
from solitonde.model.materials import MATERIALS

TABLE = Path(__file__).resolve().parents[2] / "data_samples" / "default_table.h5"


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    store = tmp_path_factory.mktemp("schema") / "s.sqlite"
    with TestClient(build_app(Settings(store_path=store, table_path=TABLE))) as client:
        yield client, client.get("/openapi.json").json()


def _invert(client, diameter, material=None):
    body = {"inputs": [{"diameter_m": diameter, "tof_s": 6.0e-4, "arr": 0.5}]}
    if material is not None:
        body["plate_material"] = material
    return client.post("/v1/invert", json=body)


def test_every_sphere_size_the_schema_allows_is_inverted_and_one_outside_is_not(served):
    client, schema = served
    ranges = schema["components"]["schemas"]["InversionInput"]["properties"]["diameter_m"]["anyOf"]
    assert len(ranges) == 3  # the bundled table's 4.76, 9.53 and 19.05 mm
    for r in ranges:
        for d in (r["minimum"], r["maximum"]):
            assert _invert(client, d).status_code == 200, d
    below = ranges[0]["minimum"] * 0.98
    r = _invert(client, below)
    assert r.status_code == 422 and r.json()["field"].endswith("diameter_m"), r.text


def test_the_plate_materials_the_schema_lists_are_served_and_the_others_refused(served):
    client, schema = served
    listed = schema["components"]["schemas"]["InvertIn"]["properties"]["plate_material"]
    allowed = set(listed["anyOf"][0]["enum"])
    assert "al_6061" in allowed and "steel_304" not in allowed
    for name in sorted(MATERIALS):
        code = _invert(client, 9.53e-3, name).status_code
        assert (code == 200) == (name in allowed), (name, code)
    ids = schema["components"]["schemas"]["ShotMetadata"]["properties"]["table"]["anyOf"][0]
    assert ids["enum"] == [t["id"] for t in client.get("/v1/tables").json()["items"]]


def test_the_scene_schema_names_its_sections_and_refuses_other_keys(served):
    client, schema = served
    assert schema["components"]["schemas"]["SimulateIn"]["properties"]["scene"]["$ref"] == \
        "#/components/schemas/Scene"
    scene = schema["components"]["schemas"]["Scene"]
    assert scene["additionalProperties"] is False
    assert set(scene["properties"]) == {"chain", "striker", "plate", "effects", "output", "sem",
                                        "solver"}
    r = client.post("/v1/simulate", json={"scene": {"chian": {}}})
    assert r.status_code == 422 and r.json()["field"] == "scene.chian"
    r = client.post("/v1/simulate", json={"scene": {"sem": {"symmetry": "yes"}}})
    assert r.status_code == 422 and r.json()["field"] == "scene.sem.symmetry"


def test_a_raw_shot_has_its_own_route_and_the_old_one_still_takes_it(served):
    client, _ = served
    body = shot_samples().astype("<f4").tobytes()
    query = {"dtype": "float32", "dt": 5e-7, "units": "N", "plate_id": "RAW",
             "sphere_diameter": 9.53e-3, "allow_duplicate": "true"}  # the same shot, both routes
    headers = {"content-type": "application/octet-stream"}
    for path in ("/v1/measurements/raw", "/v1/measurements"):
        r = client.post(path, params=query, content=body, headers=headers)
        assert r.status_code == 201, (path, r.text[:300])
        assert r.json()["n_shots"] == 1
    r = client.post("/v1/measurements/raw", json={"shots": []})
    assert r.status_code == 415 and "/v1/measurements" in r.json()["detail"]
    r = client.post("/v1/measurements/raw", params={"dtype": "float32"}, content=body,
                    headers=headers)
    assert r.status_code == 422 and r.json()["field"] == "dt"
    assert np.isfinite(r.json()["status"])


def test_options_on_a_fixed_path_does_not_offer_the_methods_of_an_id_path(served):
    client, _ = served
    for path, allow in (("/v1/measurements/export", "GET, OPTIONS"),
                        ("/v1/measurements/raw", "OPTIONS, POST"),
                        ("/v1/measurements/12", "DELETE, GET, OPTIONS")):
        r = client.options(path)
        assert r.status_code == 204 and r.headers["allow"] == allow, (path, r.headers)
    assert client.delete("/v1/measurements/export").status_code == 405
