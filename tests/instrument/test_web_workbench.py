"""The web page as a workbench, driven in Debian's headless Chromium by Playwright for Python.

Playwright drives the system's chromium through its executable path (no browser is downloaded);
where either is missing the tests are skipped with the reason printed. Against a real uvicorn
process with the bundled table: upload a file with its fields through the page's file input, see
its estimate, open its second shot's trace, see a measurement posted from elsewhere appear
without a reload, and find the estimates' downloads and the table and plate material used.
Set SOLITONDE_FIGURES to a folder to keep the screenshot (the README's is
data_samples/figures/web_workbench.png).
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import httpx
import pytest
from service_support import start_uvicorn, stop_group

from solitonde.signal import io as signal_io

ROOT = Path(__file__).resolve().parents[2]
TABLE = ROOT / "data_samples" / "default_table.h5"
SAMPLE = ROOT / "data_samples" / "waveforms" / "synthetic_D9.53_t4.83_snr40.csv"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


def _playwright():
    if CHROMIUM is None:
        print("SKIP: no chromium on this machine (apt-get install chromium)")
        pytest.skip("no chromium (apt-get install chromium)")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        print("SKIP: playwright is not installed (pip install -e '.[dev]')")
        pytest.skip("playwright not installed (pip install -e '.[dev]')")
    return sync_playwright


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    _playwright()
    proc, url = start_uvicorn(tmp_path_factory.mktemp("workbench") / "store.sqlite",
                              env={"SOLITONDE_TABLE": str(TABLE)})
    try:
        yield url
    finally:
        stop_group(proc)


def _watched_page(browser, errors: list[str], height: int):
    """A page whose console errors and uncaught exceptions are collected in ``errors``."""
    page = browser.new_page(viewport={"width": 1280, "height": height})
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: errors.append(str(e)))
    return page


def _recording(folder: Path) -> Path:
    """The bundled recording without its plate and position: what a scope saves."""
    from solitonde.signal.waveform import Waveform

    shots = [Waveform(w.t0, w.dt, w.samples, w.units, w.calibration, {})
             for w in signal_io.read(SAMPLE)]
    return signal_io.write(folder / "scope_0001.csv", shots)


def test_upload_see_the_estimate_open_the_second_shot_and_see_live_updates(server, tmp_path):
    sync_playwright = _playwright()
    recording = _recording(tmp_path)
    errors: list[str] = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM,
                                    args=["--no-sandbox", "--disable-gpu"])
        try:
            page = _watched_page(browser, errors, 1500)
            page.on("response", lambda r: errors.append(f"{r.status} {r.url}")
                    if r.status >= 400 else None)
            page.goto(server + "/")
            page.wait_for_selector("#upload-form")
            # the file picker and the fields
            assert page.locator("input[type=file]#file").count() == 1
            page.set_input_files("#file", str(recording))
            page.fill("#f-plate_id", "WEB-1")
            page.fill("#f-position", "A1")
            page.fill("#f-x_m", "0.1")
            page.fill("#f-y_m", "0.2")
            page.fill("#f-sphere_diameter", "0.00953")
            page.click("#upload")
            result = page.locator("#upload-result")
            result.filter(has_text="thickness").wait_for(timeout=60_000)
            text = result.inner_text()
            m = re.match(r"scope_0001\.csv: measurement (\d+), 2 shots; thickness (\S+) mm "
                         r"\(95 %", text)
            assert m, text
            measurement_id = int(m.group(1))
            assert abs(float(m.group(2)) - 4.83) < 0.1, text  # the sample's plate: 4.83 mm
            # the page went to the plate and the measurement: one estimate per position
            page.locator("#positions tbody tr").first.wait_for()
            positions = page.locator("#positions tbody tr")
            assert positions.count() == 1 and positions.first.inner_text().startswith("A1")
            assert "constrained" not in positions.first.inner_text()  # read as mm, not a status
            # both are filled once /v1/tables answers (after the position's row, on a busy machine)
            page.locator("#plate-tables").filter(has_text="plate al_6061").wait_for(timeout=30_000)
            page.locator("#measurement-table").filter(has_text="plate al_6061").wait_for(
                timeout=30_000)
            # every shot listed; the second one opened: its trace with the picks
            page.locator("#shot-1").wait_for()
            assert page.locator("#shots tbody tr").count() == 2
            page.click("#shot-1")
            page.locator("#trace-title", has_text="shot 1").wait_for()
            page.locator("#shots tr.current", has_text="shot 1").wait_for()
            trace = page.locator("#trace")
            for _ in range(200):  # the PNG drawn and decoded
                if trace.evaluate("e => e.src.startsWith('blob:') && e.naturalWidth > 0"):
                    break
                page.wait_for_timeout(100)
            else:
                raise AssertionError("the second shot's trace was not shown")
            assert f"#plate=WEB-1&m={measurement_id}&shot=1" in page.url
            # the downloads point at the estimates export of this plate, and answer
            href = page.get_attribute("#dl-estimates-csv", "href")
            assert href == "/v1/measurements/export?kind=estimates&format=csv&plate_id=WEB-1"
            csv_text = page.request.get(server + href).text()
            assert csv_text.count("\n") == 2 and "thickness_m_median" in csv_text
            parquet = page.request.get(server + page.get_attribute("#dl-estimates-parquet",
                                                                   "href"))
            assert parquet.ok and parquet.body()[:4] == b"PAR1"
            # live: a measurement posted by another client appears without a reload
            shots = [{**w.to_dict(), "metadata": {}} for w in signal_io.read(recording)]
            # (the same recording: stored again only because the request says so)
            r = httpx.post(f"{server}/v1/measurements", timeout=120, json={
                "shots": shots, "allow_duplicate": True,
                "metadata": {"plate_id": "WEB-1", "position": "A2", "x_m": 0.15, "y_m": 0.2,
                             "sphere_diameter": 9.53e-3}})
            assert r.status_code == 201, r.text
            page.locator("#positions tbody tr", has_text="A2").wait_for(timeout=20_000)
            page.locator("#measurements tbody tr", has_text="A2").wait_for(timeout=20_000)
            assert page.locator("#measurements tbody tr").count() == 2
            figures = os.environ.get("SOLITONDE_FIGURES")
            shot = Path(figures) if figures else tmp_path
            shot.mkdir(parents=True, exist_ok=True)
            page.screenshot(path=str(shot / "web_workbench.png"), full_page=True)
        finally:
            browser.close()
    assert not errors, errors


def test_a_refused_upload_says_why_on_the_page(server, tmp_path):
    sync_playwright = _playwright()
    empty = tmp_path / "empty.csv"
    empty.write_text("time_s,force_N\n")
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        try:
            page = browser.new_page()
            page.goto(server + "/")
            page.set_input_files("#file", str(empty))
            page.click("#upload")
            result = page.locator("#upload-result.error")
            result.wait_for(timeout=30_000)
            assert result.inner_text().startswith("empty.csv: 422: ")
        finally:
            browser.close()


def test_a_shot_left_out_as_an_outlier_is_marked_on_the_page(server):
    """Five shots at one position, the fifth's reflection 10 us late (its gap held 20 samples
    longer): the service leaves it out of the mean, and the page's measurement row says so,
    with the shot and the level in the mark's title."""
    import numpy as np

    sync_playwright = _playwright()
    rng = np.random.default_rng(5)
    w = signal_io.read(SAMPLE)[0]
    gap = round((400e-6 - w.t0) / w.dt)  # between the incident (137 us) and the reflection
    noise = 0.003 * float(np.max(w.samples))
    shots = []
    for k in range(5):
        samples = w.samples + rng.normal(0.0, noise, w.samples.size)
        if k == 4:
            samples = np.concatenate([samples[:gap], np.repeat(samples[gap], 20),
                                      samples[gap:-20]])
        shots.append({"t0": w.t0, "dt": w.dt, "samples": samples.tolist(), "units": "N"})
    r = httpx.post(f"{server}/v1/measurements", timeout=120, json={
        "shots": shots, "metadata": {"plate_id": "OUT-1", "position": "B1",
                                     "sphere_diameter": 9.53e-3}})
    assert r.status_code == 201, r.text
    rejected = r.json()["aggregates"][0]["rejected"]
    assert [(x["index"], x["feature"]) for x in rejected] == [(4, "tof_s")], rejected
    errors: list[str] = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        try:
            page = _watched_page(browser, errors, 900)
            page.goto(server + "/#plate=OUT-1")
            mark = page.locator("#measurements tbody tr span.outlier")
            mark.wait_for(timeout=30_000)
            assert mark.inner_text() == "outlier x1"
            title = mark.get_attribute("title")
            assert title.startswith("shot 4: TOF modified z-score > 26.6"), title
        finally:
            browser.close()
    assert not errors, errors


def _stored_with_readings(store_path: Path) -> int:
    """A store holding one measurement whose estimate is ``ambiguous``: two readings along the
    thickness-distance ridge and their warning, as the inversion writes them (a real shot of the
    bundled scan, its estimate as the service would store it)."""
    from solitonde.instrument.service.store import ShotRecord, Store

    wave = signal_io.read(ROOT / "data_samples" / "scan" / "scan_P04_shot0.csv")[0]
    reading = {"thickness_m": {"map": 2.9e-3, "median": 2.95e-3, "ci68": [2.85e-3, 3.05e-3],
                               "ci95": [2.7e-3, 3.1e-3], "status": "constrained"},
               "distance_m": {"map": 0.016, "median": 0.016, "ci68": [0.015, 0.017],
                              "ci95": [0.013, 0.019], "status": "constrained"}, "weight": 0.2}
    far = {"thickness_m": {**reading["thickness_m"], "median": 3.4e-3, "ci95": [3.3e-3, 3.6e-3]},
           "distance_m": {"map": None, "median": None, "ci68": [0.05, None],
                          "ci95": [0.04, None], "status": "lower_bound_only"}, "weight": 0.8}
    estimate = {"thickness_m": {"map": None, "median": None, "ci68": None,
                                "ci95": [2.7e-3, 3.6e-3], "status": "ambiguous"},
                "distance_m": {"map": None, "median": None, "ci68": None,
                               "ci95": [0.013, None], "status": "ambiguous"},
                "readings": [far, reading], "reason": None, "fit": {},
                "warnings": ["another reading fits as well: the data fit separate readings along "
                             "the thickness-distance ridge"]}
    store = Store(store_path)
    try:
        new_id, _ = store.add([ShotRecord(wave.t0, wave.dt, wave.samples, "N", None,
                                          {"plate_id": "RIDGE", "position": "P04"}, {})],
                              {"aggregates": [], "estimate": estimate, "table": None},
                              source="test", plate_id="RIDGE", position="P04")
    finally:
        store.close()
    return new_id


def test_a_measurements_warnings_reasons_and_readings_are_on_the_page(tmp_path):
    """An inconsistent answer shows why; an ambiguous one its readings; warnings are listed; no
    unit follows a missing number."""
    import sys

    sys.path.insert(0, str(ROOT / "tests" / "support"))
    from independent_chain import sensor_trace
    from recordings import STEEL, steel_shots

    sync_playwright = _playwright()
    store_path = tmp_path / "store.sqlite"
    ambiguous_id = _stored_with_readings(store_path)
    t, force = sensor_trace(STEEL, 4.0e-3)
    steel = steel_shots(tmp_path / "steel.csv", t, force)
    proc, url = start_uvicorn(store_path, env={"SOLITONDE_TABLE": str(TABLE)})
    errors: list[str] = []
    try:
        with steel.open("rb") as fh:
            r = httpx.post(f"{url}/v1/measurements", files={"file": ("steel.csv", fh)},
                           data={"sphere_diameter": "9.53e-3", "position": "S1"}, timeout=120)
        assert r.status_code == 201, r.text
        steel_id = r.json()["id"]
        assert r.json()["estimate"]["thickness_m"]["status"] == "inconsistent"
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM,
                                        args=["--no-sandbox", "--disable-gpu"])
            try:
                page = _watched_page(browser, errors, 1400)
                page.goto(f"{url}/#plate=steel-4mm&m={steel_id}&shot=0")
                notes = page.locator("#measurement-notes li")
                notes.first.wait_for(timeout=30_000)
                texts = notes.all_inner_texts()
                assert texts[0].startswith("Why: inconsistent:"), texts
                assert any(t.startswith("Warning: inconsistent:") for t in texts), texts
                assert page.locator("#measurement-notes li.error").count() >= 2
                title = page.inner_text("#measurement-title")
                assert "thickness inconsistent, distance inconsistent" in title, title
                assert "inconsistent mm" not in title and "- mm" not in title
                page.goto(f"{url}/#plate=RIDGE&m={ambiguous_id}&shot=0")
                page.locator("#measurement-notes li", has_text="Reading 2").wait_for(
                    timeout=30_000)
                texts = page.locator("#measurement-notes li").all_inner_texts()
                assert texts[0] == ("Reading 1 (weight 0.80): thickness 3.40 mm (95 % 3.30..3.60 "
                                    "mm), distance to the support at least 40.00 mm"), texts
                assert texts[1].startswith("Reading 2 (weight 0.20): thickness 2.95 mm")
                assert texts[2].startswith("Warning: another reading fits as well")
                title = page.inner_text("#measurement-title")
                assert "ambiguous 2.70..3.60 mm (see the readings)" in title, title
                row = page.locator("#measurements tbody tr", has_text="ambiguous")
                row.wait_for(timeout=30_000)
                assert "1 note" in row.inner_text()
                body = page.inner_text("body")
                assert "- mm" not in body and "inconsistent mm" not in body
                figures = os.environ.get("SOLITONDE_FIGURES")
                shot = Path(figures) if figures else tmp_path
                shot.mkdir(parents=True, exist_ok=True)
                page.screenshot(path=str(shot / "web_readings.png"), full_page=True)
            finally:
                browser.close()
    finally:
        stop_group(proc)
    assert not errors, errors


AL_6061_PROPERTIES = {"name": "6061 as measured", "youngs_modulus": 68.9e9,
                      "poisson_ratio": 0.33, "density": 2700.0}
"""The table's plate material stated by its properties alone: the answer carries the default
spread, and says so in a warning."""


def test_the_page_lists_setups_and_measures_with_the_one_picked(server, tmp_path):
    """A set-up made and calibrated over REST is listed with its chain calibration; an upload
    through the page with that set-up picked (no sphere size typed) is measured with it: the
    measurement names the set-up's revision and calibration and shows its warnings."""
    sync_playwright = _playwright()
    from solitonde.signal.waveform import Waveform

    # other shots than the first test's (the same ones would be answered as stored already)
    signal_io.write(tmp_path / "rig.csv", [Waveform(w.t0, w.dt, w.samples * 1.001,
                                                    w.units, w.calibration, {})
                                           for w in signal_io.read(SAMPLE)])
    r = httpx.post(f"{server}/v1/setups", json={
        "id": "rig/A 1", "sphere_diameters_m": [9.53e-3], "table": "default_table",
        "plate_material": AL_6061_PROPERTIES, "labels": {"operator": "kim"}}, timeout=30)
    assert r.status_code == 201, r.text
    r = httpx.put(f"{server}/v1/setups/rig%2FA%201/calibration", timeout=30, json={
        "arr_factor": 0.98, "tof_offset_s": 1e-6, "per_diameter": [
            {"diameter_m": 9.53e-3, "arr_factor": 0.98, "tof_offset_s": 1e-6,
             "tof_offset_std_s": 5e-7, "arr_factor_std": 0.01}]})
    assert r.status_code == 201, r.text
    errors: list[str] = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM,
                                    args=["--no-sandbox", "--disable-gpu"])
        try:
            page = _watched_page(browser, errors, 1600)
            page.goto(server + "/")
            row = page.locator("#setups tbody tr").filter(has_text="rig/A 1")
            row.wait_for(timeout=30_000)
            text = row.inner_text()
            assert "2" in text and "9.53" in text and "default_table" in text, text
            assert "TOF offset 1.00 us, ARR factor 0.980" in text and "operator: kim" in text
            page.set_input_files("#file", str(tmp_path / "rig.csv"))
            page.fill("#f-plate_id", "WEB-RIG")
            page.fill("#f-position", "R1")
            page.select_option("#f-setup", "rig/A 1")
            page.click("#upload")
            result = page.locator("#upload-result")
            result.filter(has_text="thickness").wait_for(timeout=60_000)
            assert re.match(r"rig\.csv: measurement \d+, 2 shots; thickness \d",
                            result.inner_text())
            table = page.locator("#measurement-table")
            table.filter(has_text="set-up rig/A 1, revision 2").wait_for(timeout=30_000)
            assert "TOF offset 1.00 us" in table.inner_text()
            notes = page.locator("#measurement-notes li")
            notes.first.wait_for(timeout=30_000)
            lines = [notes.nth(k).inner_text() for k in range(notes.count())]
            assert any(line.startswith("Warning: the plate material is given by its properties")
                       for line in lines), lines
            assert not any(" mm" in line and "- mm" in line for line in lines), lines
            # the plate's inspection report, one link per format
            for fmt in ("pdf", "html", "json"):
                href = page.get_attribute(f"#dl-report-{fmt}", "href")
                assert href == f"/v1/plates/WEB-RIG/report.{fmt}", href
            r = httpx.get(f"{server}/v1/plates/WEB-RIG/report.json?joint=false", timeout=120)
            assert r.status_code == 200 and r.json()["setups"][0]["labels"] == {
                "operator": "kim"}
            figures = os.environ.get("SOLITONDE_FIGURES")
            if figures:
                Path(figures).mkdir(parents=True, exist_ok=True)
                page.screenshot(path=str(Path(figures) / "web_setups.png"), full_page=True)
        finally:
            browser.close()
    assert not errors, errors
