"""The web page at / in a real browser: Debian's headless Chromium against a running server.

Skipped, with the reason printed, where no Chromium is installed (`apt-get install chromium`).
The page must list a plate posted through the API, show its map and measurements, and log no
console error; with an API key set it asks for the key instead of failing. The joint map and its
suggested next positions are driven by Playwright for Python (through the same Chromium; skipped
with the reason printed where Playwright is missing).
"""

from __future__ import annotations

import csv
import os
import shutil
import subprocess
from pathlib import Path

import httpx
import pytest
from fastapi.testclient import TestClient
from service_support import start_uvicorn, stop_group

from solitonde.instrument.service.app import build_app
from solitonde.instrument.service.settings import Settings
from solitonde.signal import io as signal_io

ROOT = Path(__file__).resolve().parents[2]
SCAN = ROOT / "data_samples" / "scan"
TABLE = ROOT / "data_samples" / "default_table.h5"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--enable-logging=stderr", "--v=0", "--virtual-time-budget=20000"]


def test_the_page_and_its_files_are_served_without_anything_from_outside(tmp_path):
    with TestClient(build_app(Settings(store_path=tmp_path / "s.sqlite"))) as client:
        page = client.get("/")
        assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
        assert '<script src="/static/app.js"' in page.text and "http" not in page.text
        for name, kind in (("app.js", "javascript"), ("style.css", "css")):
            r = client.get(f"/static/{name}")
            assert r.status_code == 200 and kind in r.headers["content-type"]
            assert "://" not in r.text  # nothing fetched from another host
        assert client.get("/static/../app.py").status_code == 404
        assert client.get("/static/secrets.txt").status_code == 404


def _browse(url: str, profile: Path, *extra: str) -> tuple[str, list[str]]:
    """The DOM after the page's scripts ran, and the console lines Chromium logged."""
    if CHROMIUM is None:
        print("SKIP: no chromium on this machine (apt-get install chromium)")
        pytest.skip("no chromium (apt-get install chromium)")
    out = subprocess.run([CHROMIUM, *FLAGS, f"--user-data-dir={profile}", *extra, "--dump-dom",
                          url], capture_output=True, text=True, timeout=180)
    assert out.returncode == 0, out.stderr[-2000:]
    console = [line for line in out.stderr.splitlines() if "CONSOLE" in line]
    return out.stdout, console


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    if CHROMIUM is None:
        print("SKIP: no chromium on this machine (apt-get install chromium)")
        pytest.skip("no chromium (apt-get install chromium)")
    store = tmp_path_factory.mktemp("web") / "store.sqlite"
    proc, url = start_uvicorn(store, env={"SOLITONDE_TABLE": str(TABLE)})
    try:
        with (SCAN / "campaign.csv").open() as fh:
            for row in csv.DictReader(fh):  # a position's three shots as one measurement
                meta = {"plate_id": row["plate_id"], "position": row["position"],
                        "x_m": float(row["x_m"]), "y_m": float(row["y_m"]),
                        "sphere_diameter": float(row["sphere_diameter_m"])}
                shots = [w.to_dict() for path in sorted(SCAN.glob(row["file"]))
                         for w in signal_io.read(path)]
                r = httpx.post(f"{url}/v1/measurements", timeout=120,
                               json={"shots": [{**s, "metadata": {}} for s in shots],
                                     "metadata": meta})
                assert r.status_code == 201, r.text
        yield url
    finally:
        stop_group(proc)


def test_the_page_lists_the_plate_and_shows_its_map_with_no_console_error(server, tmp_path):
    """Also takes the README's screenshot: set SOLITONDE_SCREENSHOT to the PNG's path."""
    dom, console = _browse(f"{server}/#plate=SCAN-A", tmp_path / "profile")
    shot = os.environ.get("SOLITONDE_SCREENSHOT")
    if shot:
        _browse(f"{server}/#plate=SCAN-A", tmp_path / "profile2", "--window-size=1280,1180",
                f"--screenshot={shot}")
    assert ">SCAN-A</button>" in dom
    assert 'id="map"' in dom and 'src="blob:' in dom.split('id="map"')[1].split(">")[0]
    assert "Located support" in dom or "Support not located" in dom
    assert dom.count(">delete</button>") == 8  # one measurement per position
    assert not [line for line in console if "rror" in line or "Uncaught" in line], console


def test_with_an_api_key_the_page_asks_for_it(tmp_path):
    if CHROMIUM is None:
        print("SKIP: no chromium on this machine (apt-get install chromium)")
        pytest.skip("no chromium (apt-get install chromium)")
    proc, url = start_uvicorn(tmp_path / "k.sqlite", env={"SOLITONDE_API_KEY": "k" * 24})
    try:
        dom, _ = _browse(f"{url}/", tmp_path / "profile")
    finally:
        stop_group(proc)
    form = dom.split('id="key-form"')[1].split(">")[0]
    assert "hidden" not in form and "needs its API key" in dom


def test_the_joint_map_marks_the_next_positions(server, tmp_path):
    """Ticking "invert jointly" and asking for two next positions: the map is redrawn from
    map.png?joint=true&suggest=2, the two suggestions are listed with their gain, the joint fit
    is shown, and the browser logs no error. SOLITONDE_FIGURES keeps the screenshot."""
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        print("SKIP: playwright is not installed (pip install -e '.[dev]')")
        pytest.skip("playwright not installed (pip install -e '.[dev]')")
    errors: list[str] = []
    pictures: list[str] = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM,
                                    args=["--no-sandbox", "--disable-gpu"])
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 1400})
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.on("response", lambda r: (errors.append(f"{r.status} {r.url}")
                                           if r.status >= 400 else
                                           pictures.append(r.url) if "map.png" in r.url
                                           else None))
            page.goto(f"{server}/#plate=SCAN-A")
            page.locator("#support", has_text="Located support").wait_for(timeout=60_000)
            assert page.locator("#suggestions-panel").is_hidden()
            page.check("#joint")
            page.fill("#suggest", "2")
            page.dispatch_event("#suggest", "change")
            rows = page.locator("#suggestions tbody tr")
            rows.nth(1).wait_for(timeout=120_000)
            assert rows.count() == 2
            first = rows.first.inner_text()
            assert first.startswith("next 1") and "," in first, first
            page.locator("#support", has_text="(joint)").wait_for(timeout=60_000)
            assert "Joint fit: chi2" in page.locator("#joint-notes").inner_text()
            assert "joint=1" in page.url and "suggest=2" in page.url
            for _ in range(300):  # the redrawn map decoded
                if any("joint=true" in u and "suggest=2" in u for u in pictures) and \
                        page.locator("#map").evaluate("e => e.complete && e.naturalWidth > 0"):
                    break
                page.wait_for_timeout(100)
            else:
                raise AssertionError(f"the joint map was not drawn: {pictures}")
            figures = os.environ.get("SOLITONDE_FIGURES")
            if figures:
                Path(figures).mkdir(parents=True, exist_ok=True)
                page.screenshot(path=str(Path(figures) / "web_joint_map.png"), full_page=True)
        finally:
            browser.close()
    assert not errors, errors
