"""The web page at / in a real browser: Debian's headless Chromium against a running server.

Skipped, with the reason printed, where no Chromium is installed (`apt-get install chromium`).
The page must list a plate posted through the API, show its map and measurements, and log no
console error; with an API key set it asks for the key instead of failing.
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

ROOT = Path(__file__).resolve().parents[1]
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
