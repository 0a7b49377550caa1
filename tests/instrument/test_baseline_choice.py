"""What a measured shot's baseline is measured on (issue 27, item 2): the gap against the chain's
relaxation by default where the sphere size is stated, the pre-trigger alone on request
(``analyze --baseline pre-trigger``, metadata ``baseline``) for a chain unlike the model's; a
value that is neither is refused by name, on the command line and over REST."""

from __future__ import annotations

import json
from pathlib import Path

from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app as build_cli
from solitonde.signal import io as signal_io
from solitonde.signal.features import extract

ROOT = Path(__file__).resolve().parents[2]
CSV = ROOT / "data_samples" / "waveforms" / "synthetic_D9.53_t4.83_snr40.csv"


def _analyze(*args: str) -> tuple[int, dict]:
    result = CliRunner().invoke(build_cli(), ["analyze", str(CSV), *args, "--json"])
    return result.exit_code, json.loads(result.stdout) if result.exit_code != 2 else {}


def test_each_row_says_its_baseline_and_pre_trigger_is_the_extractor_alone() -> None:
    code, gap = _analyze()
    assert code == 0
    assert [r["baseline"] for r in gap["shots"]] == ["gap", "gap"]
    code, pre = _analyze("--baseline", "pre-trigger")
    assert code == 0
    assert [r["baseline"] for r in pre["shots"]] == ["pre-trigger", "pre-trigger"]
    from solitonde.instrument.inference.chain_geometry import shot_options

    alone = [extract(w, **shot_options(9.53e-3)).arr for w in signal_io.read(CSV)]
    assert [r["arr"] for r in pre["shots"]] == alone
    # this sample carries a drift of 1 % of the incident: the two baselines differ by more than
    # the round-off, and by less than the drift's share of the reflection
    for g, p in zip(gap["shots"], pre["shots"], strict=True):
        assert 1e-4 < abs(g["arr"] / p["arr"] - 1.0) < 0.02


def test_a_baseline_that_is_neither_is_refused_by_name() -> None:
    result = CliRunner().invoke(build_cli(), ["analyze", str(CSV), "--baseline", "sideways"])
    assert result.exit_code == 2
    assert "--baseline" in result.output and "gap or pre-trigger" in result.output


def test_the_service_refuses_an_unknown_baseline_in_a_shots_metadata(client) -> None:
    shot = signal_io.read(CSV)[0].to_dict()
    shot["metadata"] = {**shot["metadata"], "baseline": "sideways"}
    r = client.post("/v1/measurements", json={"shots": [shot]})
    assert r.status_code == 422, r.text
    assert r.json()["field"].endswith("metadata.baseline")
    shot["metadata"]["baseline"] = "pre-trigger"
    r = client.post("/v1/measurements", json={"shots": [shot]})
    assert r.status_code == 201, r.text
