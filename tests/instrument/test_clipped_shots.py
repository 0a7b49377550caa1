"""A clipped incident is no reading, on recordings from an independent solve.

A 4.0 mm structural-steel plate under the paper's chain (D 9.53 mm, gravity on), solved by
scipy's DOP853 on Zener's dashpot (tests/support/independent_chain.py, no model code), five
shots at 40 dB, then cut at the scope's rail as an ADC does (the noise first, the clip last). The
incident peaks at 33.7 N; with the rail at 25 N its top is lost, the ARR reads 0.84 instead of
0.67, and the inversion read "2.08 mm, 95 % 1.88-2.91, constrained" with exit 0 although every
shot was flagged ``saturated``. Now a saturated shot is rejected from the aggregate, listed with
the reason, and a size whose every shot is gives no input: ``analyze --invert`` exits 1 saying so.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from independent_chain import recorded_for
from recordings import (
    STEEL,
    STEEL_TABLE,
    analyze_inverted,
    edit_shots,
    post_recording,
    steel_shots,
)

from solitonde.signal import io as signal_io
from solitonde.signal.features import aggregate, extract


def _clipped(folder: Path, rail_n: float, clip_shots: int = 5) -> Path:
    """Five noisy shots of the independent solve, the first ``clip_shots`` cut at ``rail_n``."""
    t, force = recorded_for(STEEL, 4.0e-3, 1.0e-3)
    path = steel_shots(folder / f"rail_{rail_n:g}_{clip_shots}.csv", t, force)
    return edit_shots(path, lambda _, k, v: min(v, rail_n) if k < clip_shots else v)


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("clipped")


def test_every_shot_clipped_is_no_answer(folder: Path) -> None:
    path = _clipped(folder, 25.0)
    features = [extract(w) for w in signal_io.read(path)]
    assert all("saturated" in f.flags for f in features)
    assert np.mean([f.arr for f in features]) > 0.8  # what the clipped peak reads (truth 0.67)
    agg = aggregate(features)
    assert agg["arr"].count == 0
    assert [r["reason"].split(":")[0] for r in agg.rejected] == ["saturated"] * 5
    code, out = analyze_inverted(path)
    assert code == 1
    assert out["estimates"][0]["estimate"] is None
    message = out["errors"][0]["error"]
    assert "every shot is saturated" in message and "range" in message


def test_the_unclipped_shots_answer_alone(folder: Path) -> None:
    """Two of five shots clipped: the three whole ones give the answer, 4.0 mm within reach."""
    code, out = analyze_inverted(_clipped(folder, 25.0, clip_shots=2))
    assert code == 0, out["errors"]
    agg = out["aggregates"][0]
    assert [r["index"] for r in agg["rejected"]] == [0, 1]
    est = out["estimates"][0]["estimate"]
    assert est["inputs"][0]["n_shots"] == 3
    assert est["thickness_m"]["status"] == "constrained"
    assert abs(est["thickness_m"]["median"] - 4.0e-3) < 0.1e-3


def test_the_service_says_why_it_has_no_answer(folder: Path, tmp_path: Path) -> None:
    """POST /v1/measurements with every shot clipped: 201 (the shots are stored, each with its
    flag), no estimate, and the reason names the clipping."""
    r = post_recording(_clipped(folder, 25.0), STEEL_TABLE, tmp_path / "s.sqlite")
    assert r.status_code == 201, r.text
    body = r.json()
    assert body["estimate"] is None
    assert "every shot is saturated" in body["estimate_reason"]
    assert all("saturated" in s["features"]["flags"] for s in body["shots"])


def test_a_mix_of_unreadable_shots_is_named(folder: Path) -> None:
    """Three clipped shots and two cut by the record's end: no input, and the reason counts
    both (the pipeline's skip reason, which makes ``analyze --invert`` exit 1)."""
    import dataclasses

    from solitonde.instrument.inference.pipeline import ALL_REJECTED, summarise

    features = [extract(w) for w in signal_io.read(_clipped(folder, 25.0))]
    features[3:] = [dataclasses.replace(f, flags=["truncated"]) for f in features[3:]]
    (size,) = summarise([9.53e-3] * 5, features)
    reason = size.skip_reason()
    assert reason is not None and ALL_REJECTED in reason
    assert "saturated 3, truncated 2" in reason
