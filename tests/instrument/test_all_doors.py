"""One road: the same recording through every door gives the same features and estimates, to
the last bit, with and without an instrument set-up.

The recording is an independent solve (scipy's DOP853 on a Hertzian chain over Zener's dashpot,
tests/support/independent_chain.py): a 3.2 mm 6061 plate far from its supports, three shots at
40 dB, written as a scope's CSV that states no sphere size. The doors: ``analyze --invert``
(in-process), the multipart upload, the JSON body, ``solitonde post`` and ``solitonde watch``
(processes) against a real uvicorn server on the bundled table, the plate map of the stored
measurements, and a reanalysis of the store. With a set-up (the size, the table and a chain
calibration the service keeps) every door states the set-up instead of the size, and
``analyze --setup FILE`` reads the set-up saved from the service.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any
from urllib.parse import quote

import httpx
import pytest
from independent_chain import recorded_for, write_shots
from service_support import start_uvicorn, stop_group
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app
from solitonde.signal import io as signal_io
from solitonde.signal.features import FEATURES

ROOT = Path(__file__).resolve().parents[2]
TABLE = ROOT / "data_samples" / "default_table.h5"
AL_6061 = {"youngs_modulus": 68.9e9, "poisson_ratio": 0.33, "density": 2700.0}
D = 9.53e-3
COMPARED = (*FEATURES, "tof_peak_s", "arr_peak", "flags", "arr_upper_bound")
"""The shot features every door reports, compared bit for bit."""
ESTIMATED = ("thickness_m", "distance_m", "chi2_min", "inputs", "calibration",
             "material_spread", "readings")
"""The estimate's parts compared bit for bit (the table's path and the time differ by door)."""
CHAIN_CALIBRATION = {"arr_factor": 0.97, "tof_offset_s": 2.0e-6, "per_diameter": [
    {"diameter_m": D, "arr_factor": 0.97, "arr_factor_std": 0.01, "tof_offset_s": 2.0e-6,
     "tof_offset_std_s": 0.5e-6, "damping_s": 9.0e-8, "damping_std_s": 1.0e-8}]}
"""A chain calibration a lab could have fitted (a damped chain, a small offset)."""


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The scope CSV: three noisy shots of the independent solve, no sphere size stated."""
    t, force = recorded_for(AL_6061, 3.2e-3, 8.0e-4)
    folder = tmp_path_factory.mktemp("doors")
    return write_shots(folder / "scope.csv", t, force, shots=3, snr_db=40.0, seed=4,
                       metadata={"plate_id": "DOORS"})


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Any:
    store = tmp_path_factory.mktemp("doors-store") / "store.sqlite"
    proc, url = start_uvicorn(store, env={"SOLITONDE_TABLE": str(TABLE)})
    try:
        yield url, store
    finally:
        stop_group(proc)


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("SOLITONDE_")}
    return subprocess.run([sys.executable, "-m", "solitonde.instrument.cli.main", *args],
                          capture_output=True, text=True, env=env, cwd=cwd, timeout=300)


def _analyze(*args: str) -> dict[str, Any]:
    result = CliRunner().invoke(build_app(), ["analyze", *args, "--invert", "--table",
                                              str(TABLE), "--json"])
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)


def _measured(url: str, measurement_id: int) -> dict[str, Any]:
    return httpx.get(f"{url}/v1/measurements/{measurement_id}", timeout=60).json()


def _features(shots: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [{k: s[k] for k in COMPARED} for s in shots]


def _estimate(est: dict[str, Any]) -> dict[str, Any]:
    return {k: est.get(k) for k in ESTIMATED}


def _doors(url: str, recording: Path, tag: str, given: dict[str, str]) -> dict[str, Any]:
    """The recording through the upload, the JSON body, post and watch; each door's stored
    measurement by name. ``given``: the form fields every door states (the size, or a set-up)."""
    folder = recording.parent
    out: dict[str, Any] = {}
    with recording.open("rb") as f:
        r = httpx.post(f"{url}/v1/measurements", files={"file": ("scope.csv", f)},
                       data={**given, "position": f"{tag}-upload", "allow_duplicate": "true"},
                       timeout=120)
    assert r.status_code == 201, r.text
    out["upload"] = r.json()
    waves = list(signal_io.read(recording))
    meta = {"plate_id": "DOORS", "position": f"{tag}-json"}
    if "sphere_diameter" in given:
        meta["sphere_diameter"] = float(given["sphere_diameter"])
    body: dict[str, Any] = {"shots": [{"t0": w.t0, "dt": w.dt, "samples": w.samples.tolist()}
                                      for w in waves],
                            "metadata": meta, "allow_duplicate": True}
    if "setup" in given:
        body["setup"] = given["setup"]
    r = httpx.post(f"{url}/v1/measurements", json=body, timeout=120)
    assert r.status_code == 201, r.text
    out["json"] = r.json()
    flags = [x for k, v in given.items() for x in (f"--{k.replace('_', '-')}", v)]
    run = _cli("post", str(recording), "--server", url, "--position", f"{tag}-post",
               "--allow-duplicate", "--json", *flags, cwd=folder)
    assert run.returncode == 0, run.stderr
    out["post"] = _measured(url, json.loads(run.stdout)["id"])
    watched = folder / f"watched-{tag}"
    watched.mkdir()
    (watched / "scope.csv").write_bytes(recording.read_bytes())
    run = _cli("watch", str(watched), "--server", url, "--position", f"{tag}-watch",
               "--allow-duplicate", "--once", "--settle", "0", *flags, cwd=folder)
    assert run.returncode == 0, run.stderr
    items = httpx.get(f"{url}/v1/measurements", params={"plate_id": "DOORS", "limit": 500},
                      timeout=60).json()["items"]
    watch_id = next(m["id"] for m in items if m["position"] == f"{tag}-watch")
    out["watch"] = _measured(url, watch_id)
    return out


def _same_everywhere(analyzed: dict[str, Any], doors: dict[str, Any]) -> None:
    features = _features(analyzed["shots"])
    estimate = _estimate(analyzed["estimates"][0]["estimate"])
    for door, m in doors.items():
        assert _features([s["features"] for s in m["shots"]]) == features, door
        assert m["estimate"] is not None, (door, m["estimate_reason"])
        assert _estimate(m["estimate"]) == estimate, door


def _map_agrees(url: str, doors: dict[str, Any]) -> None:
    """The plate map's entry of each door's position is that measurement's estimate."""
    positions = {p["position"]: p for p in httpx.get(
        f"{url}/v1/plates/{quote('DOORS', safe='')}/map", timeout=120).json()["positions"]}
    for m in doors.values():
        entry = positions[m["position"]]
        for key in ("thickness_m", "distance_m"):
            want = {k: m["estimate"][key].get(k) for k in entry[key]}
            assert entry[key] == want, (m["position"], key)


def test_every_door_gives_the_same_answer_without_a_setup(server: Any, recording: Path) -> None:
    url, store = server
    analyzed = _analyze(str(recording), "--sphere-diameter", str(D))
    assert analyzed["estimates"][0]["estimate"]["thickness_m"]["status"] == "constrained"
    doors = _doors(url, recording, "plain", {"sphere_diameter": str(D)})
    _same_everywhere(analyzed, doors)
    _map_agrees(url, doors)
    # a reanalysis walks the same road: the newest result is the first one again
    run = _cli("store", "reanalyze", str(store), "--plate-id", "DOORS", cwd=recording.parent)
    assert run.returncode == 0, run.stderr
    again = _measured(url, doors["upload"]["id"])
    assert len(again["earlier_results"]) >= 1
    assert _estimate(again["estimate"]) == _estimate(doors["upload"]["estimate"])


def test_every_door_gives_the_same_calibrated_answer_with_a_setup(server: Any,
                                                                   recording: Path,
                                                                   tmp_path: Path) -> None:
    url, _ = server
    r = httpx.post(f"{url}/v1/setups", json={"id": "doors/rig 1", "sphere_diameters_m": [D],
                                             "table": "default_table"}, timeout=60)
    assert r.status_code == 201, r.text
    r = httpx.put(f"{url}/v1/setups/{quote('doors/rig 1', safe='')}/calibration",
                  json=CHAIN_CALIBRATION, timeout=60)
    assert r.status_code == 201, r.text
    assert r.json()["revision"] == 2
    saved = tmp_path / "rig.json"
    saved.write_text(httpx.get(f"{url}/v1/setups/{quote('doors/rig 1', safe='')}",
                               timeout=60).text)
    analyzed = _analyze(str(recording), "--setup", str(saved))
    # the same numbers as the chain calibration file itself gives offline
    cal_file = tmp_path / "cal.json"
    cal_file.write_text(json.dumps(CHAIN_CALIBRATION))
    by_file = _analyze(str(recording), "--sphere-diameter", str(D), "--calibration-file",
                       str(cal_file))
    assert _estimate(by_file["estimates"][0]["estimate"]) == \
        _estimate(analyzed["estimates"][0]["estimate"])
    plain = _analyze(str(recording), "--sphere-diameter", str(D))
    assert analyzed["estimates"][0]["estimate"]["thickness_m"] != \
        plain["estimates"][0]["estimate"]["thickness_m"], "the calibration changed nothing"
    doors = _doors(url, recording, "rig", {"setup": "doors/rig 1"})
    _same_everywhere(analyzed, doors)
    _map_agrees(url, doors)
    for m in doors.values():
        assert m["provenance"]["setup"] == {"id": "doors/rig 1", "revision": 2}
        assert m["provenance"]["chain_calibration"]["per_diameter"][0]["damping_s"] == 9.0e-8


def test_setup_commands_create_list_show_and_calibrate(server: Any, tmp_path: Path) -> None:
    """`solitonde setup` against the server: a set-up made, listed, saved as a file that
    `analyze --setup` reads, and calibrated from a file `calibrate` wrote (its job waited on)."""
    url, _ = server
    run = _cli("setup", "create", "cli-rig", "--sphere-diameter", str(D), "--table",
               "default_table", "--label", "operator=kim", "--server", url, cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert run.stdout.startswith("cli-rig  revision 1  D 9.53 mm  table default_table  "
                                 "not calibrated")
    refused = _cli("setup", "create", "cli-rig-2", "--sphere-diameter", "9.53", "--table",
                   "default_table", "--server", url, cwd=tmp_path)
    assert refused.returncode == 2 and "sizes are in metres" in refused.stderr
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(CHAIN_CALIBRATION))
    run = _cli("setup", "calibrate", "cli-rig", "--file", str(cal), "--server", url,
               cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert "cli-rig  revision 2" in run.stdout and "damping 9e-08 s" in run.stdout
    assert "job " in run.stdout and ": done, 0 of 0 measurements re-estimated" in run.stdout
    # a revision states only what changes: the labels merge, the rest carries over
    run = _cli("setup", "create", "cli-rig", "--revise", "--label", "instrument=HNSW-3",
               "--server", url, "--json", cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    revised = json.loads(run.stdout)
    assert revised["revision"] == 3 and revised["labels"] == {"operator": "kim",
                                                              "instrument": "HNSW-3"}
    assert revised["sphere_diameters_m"] == [D] and revised["chain_calibration"] is not None
    listed = _cli("setup", "list", "--server", url, cwd=tmp_path)
    assert any(line.startswith("cli-rig  revision 3") for line in listed.stdout.splitlines())
    run = _cli("setup", "show", "cli-rig", "--server", url, "--out", "rig.json", cwd=tmp_path)
    assert run.returncode == 0 and "revision 3" in run.stdout
    saved = json.loads((tmp_path / "rig.json").read_text())
    assert saved["chain_calibration"]["per_diameter"][0]["damping_s"] == 9.0e-8
    missing = _cli("setup", "show", "no-such-rig", "--server", url, cwd=tmp_path)
    assert missing.returncode == 1 and "404: setup_id: no set-up 'no-such-rig'" in missing.stderr
