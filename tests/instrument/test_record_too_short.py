"""A record too short for the reflection gives no bound, on recordings from an independent solve.

A 4.0 mm structural-steel plate under the paper's chain (D 9.53 mm, gravity on), solved by
scipy's DOP853 on Zener's dashpot (tests/support/independent_chain.py, no model code): the
incident peaks 137 us after the impact, the reflection 630 us after it. A scope record that ends
before the reflection shows none, and one that ends on its rise shows a pulse cut by the record's
end. Before, both answered "at most 1.9 mm" with exit 0 (the first through the hidden
reflection's ARR bound, the second through a cut pulse read as a weak reflection): a confident
wrong answer. A hidden reflection bounds the thickness only where the record would have shown it.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from independent_chain import recorded_for
from recordings import STEEL, STEEL_TABLE, analyze_inverted, steel_shots

from solitonde.signal import io as signal_io
from solitonde.signal.features import aggregate, extract


def _recording(folder: Path, duration_s: float) -> Path:
    t, force = recorded_for(STEEL, 4.0e-3, duration_s)
    return steel_shots(folder / f"steel_{duration_s * 1e6:.0f}us.csv", t, force, shots=3)


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("short")


def test_a_record_ending_before_the_reflection_bounds_nothing(folder: Path) -> None:
    path = _recording(folder, 5.2e-4)
    code, out = analyze_inverted(path)
    assert code == 0, out["errors"]
    assert all(s["flags"] == ["no_reflection"] for s in out["shots"])
    est = out["estimates"][0]["estimate"]
    # the model's reflections all arrive after the records' window: no thickness is excluded
    assert est["thickness_m"]["status"] == "unconstrained", est["thickness_m"]
    window = est["inputs"][0]["tof_window_s"]
    # the record's end (520 us) less the incident's peak (137 us) and 2.5 of its widths
    assert 0.2e-3 < window < 0.383e-3
    assert any(f"within {window * 1e6:.4g} us of the incident" in w and "not excluded" in w
               for w in est["warnings"]), est["warnings"]


def test_a_reflection_cut_by_the_record_end_is_no_reading(folder: Path) -> None:
    path = _recording(folder, 6.0e-4)
    features = [extract(w) for w in signal_io.read(path)]
    assert all("truncated" in f.flags for f in features)
    agg = aggregate(features)
    assert agg["arr"].count == 0 and agg.arr_upper_bound is None
    assert [r["reason"].split(":")[0] for r in agg.rejected] == ["truncated"] * 3
    code, out = analyze_inverted(path)
    assert code == 1
    assert out["estimates"][0]["estimate"] is None
    message = out["errors"][0]["error"]
    assert "every shot is truncated" in message and "record longer" in message


def test_a_whole_record_still_answers(folder: Path) -> None:
    """The same shots recorded to 800 us: the reflection is whole and read (4.0 mm within the
    answer's reach), and its window is longer than its TOF."""
    path = _recording(folder, 8.0e-4)
    features = [extract(w) for w in signal_io.read(path)]
    assert all(f.reflection_window_s > f.tof_s and "truncated" not in f.flags for f in features)
    code, out = analyze_inverted(path)
    assert code == 0, out["errors"]
    est = out["estimates"][0]["estimate"]
    assert est["thickness_m"]["status"] == "constrained"
    assert abs(est["thickness_m"]["median"] - 4.0e-3) < 0.1e-3


def test_the_window_reaches_the_service_and_is_checked(tmp_path: Path) -> None:
    """POST /v1/invert takes a silent size's ``tof_window_s``: a window shorter than every model
    TOF bounds nothing, a longer one gives the bound back; a window beside a TOF is refused by
    name."""
    from fastapi.testclient import TestClient

    from solitonde.instrument.inference.inversion_inputs import FeatureSummary, InversionError
    from solitonde.instrument.service.app import build_app as build_service
    from solitonde.instrument.service.settings import Settings

    hidden = {"diameter_m": 9.53e-3, "arr_upper_bound": 0.02, "n_shots": 3}
    settings = Settings(store_path=tmp_path / "s.sqlite", table_path=STEEL_TABLE)
    with TestClient(build_service(settings)) as client:
        answers = [client.post("/v1/invert", json={"inputs": [{**hidden, **extra}]})
                   for extra in ({}, {"tof_window_s": 2e-4}, {"tof_window_s": 1e-3})]
    assert [r.status_code for r in answers] == [200] * 3, [r.text for r in answers]
    statuses = [r.json()["estimate"]["thickness_m"]["status"] for r in answers]
    assert statuses == ["upper_bound_only", "unconstrained", "upper_bound_only"]
    with pytest.raises(InversionError, match="tof_window_s"):
        FeatureSummary(9.53e-3, 5e-4, 0.6, tof_window_s=1e-3)
