"""A shot's features are declared once (issue 30): the fields of ``Features`` give its JSON, the
summarised numbers and the batch path's columns; the flag rules are one function that the
per-shot and the batch paths both call."""

from __future__ import annotations

import itertools
import math
import pickle
from dataclasses import fields

import numpy as np
import pytest

from solitonde.signal.batch import FeatureTable, extract_batch
from solitonde.signal.features import FEATURES, FIELD_KINDS, Features
from solitonde.signal.pulses import FLAGS, WIDTH_TOLERANCE, quality_flags
from solitonde.signal.synth import pulse_train

JSON_KEYS = (
    "tof_s", "arr", "incident_time_s", "reflected_time_s", "incident_peak_N", "reflected_peak_N",
    "snr_db", "flags", "arr_upper_bound", "secondary_times_s", "secondary_ratios", "baseline_N",
    "noise_N", "arr_local", "incident_rise_N", "reflected_rise_N", "tof_peak_s", "arr_peak",
    "incident_width_s", "reflection_window_s",
)
"""The JSON keys of a shot's features: a public contract (the service stores and serves them)."""


def _features(**changes: object) -> Features:
    base = dict(tof_s=1e-4, arr=0.5, incident_time_s=1e-5, reflected_time_s=1.1e-4,
                incident_peak_N=100.0, reflected_peak_N=50.0, snr_db=40.0,
                flags=["low_snr"], secondary_times_s=[2e-4], secondary_ratios=[0.1])
    return Features(**{**base, **changes})


def test_the_json_keys_are_the_fields_in_order() -> None:
    f = _features()
    assert tuple(f.to_dict()) == JSON_KEYS == tuple(x.name for x in fields(Features))
    assert JSON_KEYS[:7] == FEATURES
    assert set(FIELD_KINDS.values()) == {"number", "optional", "series", "flags"}


def test_to_dict_copies_the_lists() -> None:
    """The dict's lists are new lists (the frozen Features cannot be changed through them),
    a tuple of flags becomes a list, and numbers are passed through."""
    f = _features(flags=("low_snr",))
    d = f.to_dict()
    assert d["flags"] == ["low_snr"] and isinstance(d["flags"], list)
    d["secondary_times_s"].append(9.0)
    assert f.secondary_times_s == [2e-4]
    assert d["tof_s"] == 1e-4 and d["arr_upper_bound"] is None


def test_features_whole_are_the_constructors_and_take_every_field() -> None:
    """Features.whole (the extractor's fast path) builds what the constructor builds: equal,
    the same dict and pickle, frozen; a missing or an extra field is an error naming it."""
    f = _features(arr_local=0.49, reflection_window_s=3e-3)
    values = {name: getattr(f, name) for name in JSON_KEYS}
    made = Features.whole(values)
    assert made == f and made.to_dict() == f.to_dict() and pickle.loads(pickle.dumps(made)) == f
    with pytest.raises(AttributeError):
        made.arr = 1.0  # type: ignore[misc]
    with pytest.raises(TypeError, match="missing \\['arr'\\], extra \\[\\]"):
        Features.whole({k: v for k, v in values.items() if k != "arr"})
    with pytest.raises(TypeError, match="extra \\['arr_db'\\]"):
        Features.whole({**values, "arr_db": 1.0})


def test_the_batch_table_has_a_column_for_every_field_and_no_other() -> None:
    n = np.zeros(2)
    columns = {name: n for name in FIELD_KINDS}
    FeatureTable(n.astype(bool), n, columns)
    with pytest.raises(ValueError, match="missing \\['incident_width_s'\\]"):
        FeatureTable(n.astype(bool), n, {k: v for k, v in columns.items()
                                         if k != "incident_width_s"})
    with pytest.raises(ValueError, match="extra \\['tof_us'\\]"):
        FeatureTable(n.astype(bool), n, {**columns, "tof_us": n})


def test_a_batch_table_reads_like_its_fields_and_pickles() -> None:
    dt, n = 1e-7, 2000
    x = np.stack([pulse_train(n, dt, [(3e-5, 20.0, 1.5e-5), (1.2e-4, a, 1.5e-5)])
                  for a in (8.0, 0.0)])
    table = extract_batch(x, dt)
    assert [f is not None and f.tof_s is not None for f in table.to_features()] == [True, False]
    assert table.tof_s is table.columns["tof_s"]
    back = pickle.loads(pickle.dumps(table))
    assert back.to_features() == table.to_features()
    with pytest.raises(AttributeError, match="tof_us"):
        _ = table.tof_us


BOOLEANS = ("detected", "has_reflection", "early", "saturated", "incident_merged",
            "reflection_merged", "more_than_two", "incident_cut", "reflection_cut", "train")


def _cases() -> list[dict[str, object]]:
    out = []
    for bits in itertools.product((False, True), repeat=len(BOOLEANS)):
        case: dict[str, object] = dict(zip(BOOLEANS, bits, strict=True))
        if case["has_reflection"] and not case["detected"]:
            continue  # a reflection needs an incident
        for sign, snr, ratio in ((1.0, 30.0, 1.0), (-1.0, 3.0, WIDTH_TOLERANCE * 1.01),
                                 (1.0, math.nan, math.nan)):
            out.append({**case, "sign": sign, "check_snr_db": snr, "width_ratio": ratio})
    return out


def test_the_flag_rules_read_the_same_on_one_shot_and_on_arrays() -> None:
    """Every combination of what the kernels report: the per-shot call (bools and floats, as
    detect makes it) and one call on arrays (as the batch makes it) raise the same flags."""
    cases = _cases()
    arrays = {k: np.array([c[k] for c in cases]) for k in cases[0]}
    many = quality_flags(**arrays, low_snr_db=10.0)
    assert list(many) == list(FLAGS)
    for i, case in enumerate(cases):
        one = quality_flags(**case, low_snr_db=10.0)
        assert all(isinstance(v, bool) for v in one.values()), one
        assert one == {k: bool(v[i]) for k, v in many.items()}, case


def test_the_flag_rules() -> None:
    """Without a pulse only the pre-trigger's truncation and the polarity can be flagged; a
    merged incident is an overlap unless the incident's train explains it."""
    for case in _cases():
        one = quality_flags(**case, low_snr_db=10.0)
        if not case["detected"]:
            assert {k for k, v in one.items() if v} <= {"truncated", "inverted_polarity"}
        assert one["truncated"] == (case["early"] or (case["detected"] and case["incident_cut"])
                                    or (case["has_reflection"] and case["reflection_cut"]))
        assert one["implausible_units"] == (case["detected"] and not (
            1 / WIDTH_TOLERANCE <= case["width_ratio"] <= WIDTH_TOLERANCE))
        if case["has_reflection"] and case["incident_merged"] and not case["more_than_two"]:
            assert one["overlapping"] == (not case["train"])
