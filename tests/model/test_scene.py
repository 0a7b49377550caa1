"""Scenes: the paper's defaults, loading and overriding, one clear error per kind of bad input."""

from __future__ import annotations

import json
from math import sqrt

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from solitonde.model import SceneError, load_scene, scene_from_dict


def test_defaults_are_the_paper_setup():
    s = scene_from_dict({})
    assert s.chain.n_particles == 20
    assert s.chain.diameter == 9.53e-3
    assert s.chain.sensor_index == 7
    assert s.chain.material == "steel_440c"
    assert s.plate.thickness == 3.18e-3
    assert s.plate.size == (0.914, 0.914)
    assert s.plate.material == "al_6061"
    # v_imp = sqrt(2 g h) from 5 mm; the paper quotes 0.31 m/s.
    assert s.impact_velocity == pytest.approx(sqrt(2 * 9.80665 * 5e-3), rel=1e-12)
    assert round(s.impact_velocity, 2) == 0.31
    assert s.d_over_t == pytest.approx(9.53 / 3.18, rel=1e-12)


def test_velocity_replaces_drop_height():
    s = scene_from_dict({"striker": {"velocity": 0.5}})
    assert s.impact_velocity == 0.5


@pytest.mark.parametrize("suffix", [".yaml", ".json"])
def test_load_file_and_overrides(tmp_path, suffix):
    data = {"chain": {"diameter": 4.76e-3}, "plate": {"thickness": 2.29e-3}}
    path = tmp_path / f"scene{suffix}"
    path.write_text(json.dumps(data) if suffix == ".json" else yaml.safe_dump(data))
    s = load_scene(path, ["plate.thickness=4.83e-3", "effects.gravity=false"])
    assert s.chain.diameter == 4.76e-3
    assert s.plate.thickness == 4.83e-3
    assert s.effects.gravity is False
    again = s.with_overrides({"chain.n_particles": 30})
    assert again.chain.n_particles == 30 and again.plate.thickness == 4.83e-3


BAD = [
    # non-positive sizes
    ({"chain": {"diameter": 0}}, "chain.diameter", ">= 0.0001"),
    ({"chain": {"diameter": -1e-3}}, "chain.diameter", ">= 0.0001"),
    ({"plate": {"thickness": 0}}, "plate.thickness", ">= 1e-05"),
    ({"plate": {"size": [0, 0.9]}}, "plate.size", "positive"),
    ({"chain": {"n_particles": 0}}, "chain.n_particles", ">= 1"),
    ({"striker": {"drop_height": 0}}, "striker.drop_height", ">= 1e-06"),
    # sensor outside the chain
    ({"chain": {"sensor_index": 21}}, "chain.sensor_index", "1..20"),
    ({"chain": {"n_particles": 5, "sensor_index": 6}}, "chain.sensor_index", "1..5"),
    ({"chain": {"sensor_index": 0}}, "chain.sensor_index", ">= 1"),
    # support distance outside the plate
    ({"plate": {"distance_to_support": 1.0}}, "plate.distance_to_support", "0..0.914"),
    ({"plate": {"distance_to_support": -0.01}}, "plate.distance_to_support", ">= 0"),
    # unknown material
    ({"chain": {"material": "unobtainium"}}, "chain.material", "steel_440c"),
    ({"plate": {"material": "cheese"}}, "plate.material", "al_6061"),
    # unknown key
    ({"chain": {"colour": "red"}}, "chain.colour", "n_particles"),
    ({"sphere": {}}, "sphere", "chain"),
    # wrong type
    ({"chain": {"n_particles": "many"}}, "chain.n_particles", "integer"),
    ({"chain": {"n_particles": 2.5}}, "chain.n_particles", "integer"),
    ({"chain": {"diameter": True}}, "chain.diameter", "number"),
    ({"chain": {"diameter": "big"}}, "chain.diameter", "number"),
    ({"effects": {"gravity": "maybe"}}, "effects.gravity", "true or false"),
    ({"effects": {"plate_model": "fancy"}}, "effects.plate_model", "halfspace"),
    ({"output": {"duration": -1}}, "output.duration", "auto"),
    ({"chain": [1, 2]}, "chain", ""),
]


@pytest.mark.parametrize(("data", "field", "hint"), BAD, ids=[b[1] + ":" + str(i)
                                                            for i, b in enumerate(BAD)])
def test_bad_input_names_the_field(data, field, hint):
    with pytest.raises(SceneError) as info:
        scene_from_dict(data)
    assert info.value.field == field
    assert str(info.value).startswith(field + ":")
    assert hint in str(info.value)


def test_bad_overrides_and_files(tmp_path):
    with pytest.raises(SceneError) as info:
        load_scene(None, ["plate.thickness"])
    assert "section.key=value" in str(info.value)
    with pytest.raises(SceneError) as info:
        load_scene(None, ["plate.thickness=-2"])
    assert info.value.field == "plate.thickness"
    with pytest.raises(SceneError) as info:
        load_scene(tmp_path / "missing.yaml")
    assert info.value.field == "scene"
    broken = tmp_path / "broken.json"
    broken.write_text("{not json")
    with pytest.raises(SceneError):
        load_scene(broken)
    listed = tmp_path / "list.yaml"
    listed.write_text("- 1\n- 2\n")
    with pytest.raises(SceneError):
        load_scene(listed)


@settings(max_examples=50, deadline=None)
@given(diameter=st.floats(1e-4, 1.0), thickness=st.floats(1e-4, 1.0))
def test_any_positive_sizes_are_accepted(diameter, thickness):
    s = scene_from_dict({"chain": {"diameter": diameter}, "plate": {"thickness": thickness}})
    assert s.d_over_t == pytest.approx(diameter / thickness, rel=1e-15)


@settings(max_examples=50, deadline=None)
@given(value=st.one_of(st.floats(max_value=0.0, allow_nan=False), st.booleans(), st.text()),
       field=st.sampled_from(["chain.diameter", "plate.thickness", "striker.drop_height"]))
def test_any_non_positive_or_non_numeric_size_is_refused_naming_the_field(value, field):
    section, key = field.split(".")
    try:
        float(value)
        numeric = not isinstance(value, bool)
    except ValueError:
        numeric = False
    if numeric and float(value) > 0:  # a numeric string such as "1e-3" is a valid size
        return
    with pytest.raises(SceneError) as info:
        scene_from_dict({section: {key: value}})
    assert info.value.field == field


NAN, INF = float("nan"), float("inf")
# every float field of the scene, with a value that is otherwise in range
FLOAT_FIELDS = [
    "chain.diameter", "striker.drop_height", "striker.velocity", "plate.thickness",
    "plate.distance_to_support", "effects.damping", "output.sample_rate", "output.duration",
    "sem.step_factor", "sem.auto_margin", "sem.contact_radius", "solver.rtol",
]


@pytest.mark.parametrize("value", [NAN, INF, -INF, "NaN", "inf", 10**400])
@pytest.mark.parametrize("field", FLOAT_FIELDS)
def test_non_finite_floats_are_refused_naming_the_field(field, value):
    """NaN passes every bound check and infinity reaches the solvers: both are refused."""
    section, key = field.split(".")
    with pytest.raises(SceneError) as info:
        scene_from_dict({section: {key: value}})
    assert info.value.field == field
    assert "finite" in str(info.value) or "auto" in str(info.value)


@pytest.mark.parametrize("size", [[NAN, 1.0], [1.0, INF], [1e400, 1.0], ["nan", 1.0]])
def test_non_finite_plate_size_is_refused_with_the_range(size):
    with pytest.raises(SceneError) as info:
        load_scene(None, [f"plate.size={json.dumps(size)}", "effects.plate_model=sem",
                          "plate.distance_to_support=0.05"])
    assert info.value.field.startswith("plate.size")
    assert "0 < size <= 100 m" in str(info.value)


@pytest.mark.parametrize("size", [[100.5, 1.0], [1.0, 1e6], [0.0, 1.0], [1.0, -2.0]])
def test_plate_size_outside_the_range_is_refused(size):
    with pytest.raises(SceneError) as info:
        scene_from_dict({"plate": {"size": size, "distance_to_support": 0.05}})
    assert info.value.field == "plate.size"
    assert "0 < size <= 100 m" in str(info.value)


def test_plate_size_at_the_limit_is_accepted():
    assert scene_from_dict({"plate": {"size": [100, 0.5]}}).plate.size == (100.0, 0.5)


def test_infinite_duration_override_is_a_scene_error():
    with pytest.raises(SceneError) as info:
        load_scene(None, ["output.duration=Infinity"])
    assert info.value.field == "output.duration"


def test_huge_finite_duration_is_a_budget_error_not_an_overflow():
    """1e308 s over a 1e-8 s step overflows the sample count to inf; that is over budget."""
    from solitonde.model.errors import SimulationError
    from solitonde.model.simulate import simulate

    with pytest.raises(SimulationError, match="step_budget_exceeded"):
        simulate(scene_from_dict({"output": {"duration": 1e308}}))
