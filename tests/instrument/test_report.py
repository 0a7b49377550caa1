"""The inspection report: the bundled scan's report from the service read back from its PDF
(pypdf), its HTML opened in headless chromium, `report verify` against the store and the
recordings, and what the digest covers."""

from __future__ import annotations

import csv
import io
import json
import re
import shutil
import time
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from pypdf import PdfReader
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app
from solitonde.instrument.reports import digest
from solitonde.instrument.service import plate_report

ROOT = Path(__file__).resolve().parents[2]
TABLE = ROOT / "data_samples" / "default_table.h5"
SCAN = ROOT / "data_samples" / "scan"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


def _scan_rows() -> list[tuple[Path, dict[str, str]]]:
    """Each file of the bundled scan with its manifest row's metadata."""
    out = []
    with (SCAN / "campaign.csv").open() as fh:
        for row in csv.DictReader(fh):
            for path in sorted(SCAN.glob(row["file"])):
                out.append((path, {"plate_id": row["plate_id"], "position": row["position"],
                                   "x_m": row["x_m"], "y_m": row["y_m"],
                                   "sphere_diameter": row["sphere_diameter_m"]}))
    return out


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Any:
    """The service on the bundled table with the scan posted, one measurement per file."""
    from solitonde.instrument.service.app import build_app as build_service
    from solitonde.instrument.service.settings import Settings

    folder = tmp_path_factory.mktemp("report")
    store = folder / "store.sqlite"
    with TestClient(build_service(Settings(store_path=store, table_path=TABLE))) as client:
        for path, fields in _scan_rows():
            with path.open("rb") as fh:
                r = client.post("/v1/measurements", files={"file": (path.name, fh)},
                                data=fields)
            assert r.status_code == 201, r.text
        yield client, store, folder


def _pdf_text(data: bytes) -> tuple[PdfReader, str]:
    reader = PdfReader(io.BytesIO(data))
    return reader, "\n".join(page.extract_text() for page in reader.pages)


def test_the_scans_pdf_read_back(service: Any) -> None:
    """Pages, every position, each thickness median as the joint map JSON has it, the table's
    hash, the software version, the attached report.json and its digests."""
    client, _, _ = service
    r = client.get("/v1/plates/SCAN-A/report.pdf")
    assert r.status_code == 200 and r.headers["content-type"] == "application/pdf"
    reader, text = _pdf_text(r.content)
    assert len(reader.pages) >= 3
    squeezed = re.sub(r"\s+", "", text)
    the_map = client.get("/v1/plates/SCAN-A/map?joint=true&suggest=3").json()
    for p in the_map["positions"]:
        assert p["position"] in text
        t = p["thickness_m"]
        if t["status"] == "constrained":
            shown = f"{t['median'] * 1e3:.2f}({t['ci95'][0] * 1e3:.2f}..{t['ci95'][1] * 1e3:.2f})"
            assert shown in squeezed, (p["position"], shown)
    table = client.get("/v1/tables").json()["items"][0]
    sha = client.get("/v1/measurements/1").json()["provenance"]["table"]["sha256"]
    assert table["id"] in text and sha in squeezed
    assert f"solitonde {plate_report.version()}" in text
    attached = json.loads(reader.attachments["report.json"][0])
    assert len(attached["measurements"]) == 24
    assert all(len(m["digest"]) == 64 for m in attached["measurements"])
    assert attached["digest"]["value"] in squeezed
    assert attached["digest"] == client.get("/v1/plates/SCAN-A/digest").json()["digest"]
    assert [s["x_m"] for s in attached["map"]["suggestions"]] == \
        [s["x_m"] for s in the_map["suggestions"]]
    for words in ("Where to measure next", "Joint fit", "Review", "signature", "name",
                  "No chain calibration"):
        assert words in text, words


def test_the_html_stands_alone_in_chromium(service: Any, tmp_path: Path) -> None:
    if CHROMIUM is None:
        print("SKIP: no chromium on this machine (apt-get install chromium)")
        pytest.skip("no chromium (apt-get install chromium)")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.skip("playwright not installed (pip install -e '.[dev]')")
    client, _, _ = service
    r = client.get("/v1/plates/SCAN-A/report.html?suggest=0")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    page_file = tmp_path / "report.html"
    page_file.write_bytes(r.content)
    errors: list[str] = []
    outside: list[str] = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM,
                                    args=["--no-sandbox", "--disable-gpu"])
        try:
            page = browser.new_page()
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.on("request", lambda q: outside.append(q.url)
                    if not q.url.startswith(("file:", "data:")) else None)
            page.goto(page_file.as_uri())
            page.wait_for_load_state("load")
            images = page.eval_on_selector_all(
                "img", "els => els.map(e => [e.complete, e.naturalWidth, e.alt])")
            assert len(images) == 1 + 8  # the maps and one trace per position
            assert all(done and width > 0 for done, width, _ in images), images
            assert "Inspection report: plate SCAN-A" in page.inner_text("h1")
            assert page.locator("table.positions tbody tr").count() == 8
        finally:
            browser.close()
    assert not errors, errors
    assert not outside, outside


def _verify(*args: str) -> Any:
    return CliRunner().invoke(build_app(), ["report", "verify", *args])


def test_verify_finds_a_measurement_added_deleted_or_reanalysed(service: Any,
                                                                tmp_path: Path) -> None:
    client, store, _ = service
    report = tmp_path / "report.json"
    report.write_bytes(client.get("/v1/plates/SCAN-A/report.json?joint=false&suggest=0")
                       .content)
    fresh = _verify(str(report), "--store", str(store))
    assert fresh.exit_code == 0, fresh.output
    assert "matches plate 'SCAN-A' (24 measurements" in fresh.output
    path, fields = _scan_rows()[0]
    with path.open("rb") as fh:
        r = client.post("/v1/measurements", files={"file": ("again.csv", fh)},
                        data={**fields, "position": "P09", "allow_duplicate": "true"})
    added = r.json()["id"]
    changed = _verify(str(report), "--store", str(store))
    assert changed.exit_code == 1
    assert f"measurement {added} added since (position 'P09')" in changed.output
    assert client.delete(f"/v1/measurements/{added}").status_code == 204
    assert _verify(str(report), "--store", str(store)).exit_code == 0
    assert client.delete("/v1/measurements/3").status_code == 204
    gone = _verify(str(report), "--store", str(store))
    assert gone.exit_code == 1 and "measurement 3 deleted since (position 'P01')" in gone.output
    # an edited answer: the report's content no longer hashes to its content digest
    original = json.loads(report.read_text())
    answer = json.loads(report.read_text())
    answer["positions"][0]["thickness_m"] = {**answer["positions"][0]["thickness_m"],
                                             "median": 4.2e-3}
    report.write_text(json.dumps(answer))
    edited_answer = _verify(str(report), "--store", str(store))
    assert edited_answer.exit_code == 1 and "content digest" in edited_answer.output
    report.write_text(json.dumps(original))
    # an edited measurement: its data no longer hash to the digest it prints
    edited = json.loads(report.read_text())
    edited["measurements"][0]["result"]["estimate"]["thickness_m"]["median"] = 9e-3
    report.write_text(json.dumps(edited))
    tampered = _verify(str(report), "--store", str(store))
    assert tampered.exit_code == 1 and "differ from its digest" in tampered.output


def test_an_upgrade_alone_changes_no_digest(service: Any, monkeypatch: pytest.MonkeyPatch
                                            ) -> None:
    """The digest covers stored data only: a report made by another version (or at another
    time) of the same store prints the same one."""
    client, _, _ = service
    first = json.loads(client.get("/v1/plates/SCAN-A/report.json?joint=false").content)
    monkeypatch.setattr(plate_report, "version", lambda: "99.0")
    time.sleep(1.1)
    again = json.loads(client.get("/v1/plates/SCAN-A/report.json?joint=false").content)
    assert again["software_version"] == "99.0" and again["generated_at"] != \
        first["generated_at"]
    assert again["digest"] == first["digest"]
    assert [m["digest"] for m in again["measurements"]] == \
        [m["digest"] for m in first["measurements"]]


def test_offline_report_from_the_recordings_and_its_verify(tmp_path: Path) -> None:
    """`report build --manifest`: the recordings analysed here; verify checks the recordings
    (a file changed since is named)."""
    folder = tmp_path / "scan"
    shutil.copytree(SCAN, folder)
    out = tmp_path / "scan.html"
    run = CliRunner().invoke(build_app(), [
        "report", "build", "--manifest", str(folder / "campaign.csv"), "--plate-id", "SCAN-A",
        "--out", str(out), "--no-joint", "--suggest", "0"])
    assert run.exit_code == 0, run.output
    assert "report:" in run.output and "estimating each position" in run.output
    ok = _verify(str(out), "--manifest", str(folder / "campaign.csv"))
    assert ok.exit_code == 0, ok.output
    target = folder / "scan_P05_shot1.csv"
    lines = target.read_text().splitlines()
    last = lines[-1].split(",")
    lines[-1] = ",".join([last[0], repr(float(last[1]) + 0.5)])
    target.write_text("\n".join(lines) + "\n")
    changed = _verify(str(out), "--manifest", str(folder / "campaign.csv"))
    assert changed.exit_code == 1 and "its shots' samples differ" in changed.output


def test_the_digest_is_canonical_json_of_the_stored_data() -> None:
    one = digest.entry(1, "A1", ["ab" * 32], {"estimate": {"b": 1.0, "a": [0.1, 2]}})
    reordered = digest.entry(1, "A1", ["ab" * 32], {"estimate": {"a": [0.1, 2], "b": 1.0}})
    assert digest.entry_digest(one) == digest.entry_digest(reordered)
    assert digest.canonical({"b": 1.0, "a": 1e21}) == b'{"a":1e+21,"b":1}'
    assert digest.data_digest([one, digest.entry(2, "A2", [], {})]) == \
        digest.data_digest([digest.entry(2, "A2", [], {}), one])
    assert digest.changes([one], []) == ["measurement 1 deleted since (position 'A1')"]


def test_a_report_names_what_is_missing(service: Any, tmp_path: Path) -> None:
    client, store, _ = service
    assert client.get("/v1/plates/NOPE/report.pdf").status_code == 404
    run = CliRunner().invoke(build_app(), ["report", "build", "--store", str(store),
                                           "--plate-id", "NOPE", "--out",
                                           str(tmp_path / "x.pdf")])
    assert run.exit_code == 1 and "no plate 'NOPE' (plates: SCAN-A)" in run.output
    run = CliRunner().invoke(build_app(), ["report", "build", "--plate-id", "SCAN-A", "--out",
                                           str(tmp_path / "x.docx"), "--store", str(store)])
    assert run.exit_code == 2 and "must end in .pdf, .html or .json" in run.output
    not_a_report = tmp_path / "other.pdf"
    not_a_report.write_bytes(b"%PDF-1.4\n%%EOF\n")
    run = _verify(str(not_a_report), "--store", str(store))
    assert run.exit_code == 2


@pytest.mark.bench
def test_bench_a_plate_of_200_positions(tmp_path: Path) -> None:
    """A plate of 200 positions (the scan's shots laid over the plate), joint map included, no
    suggestions: the PDF's wall time, printed (`pytest -m bench -s`)."""
    from solitonde.instrument.inference.table_set import TableSet
    from solitonde.instrument.service.ingest import measure_and_store
    from solitonde.instrument.service.store import Store
    from solitonde.signal import io as signal_io

    tables = TableSet([TABLE], warm_up=False)
    store = Store(tmp_path / "long.sqlite", background_checkpoint=False)
    rows = [(p, f) for p, f in _scan_rows() if p.stem.endswith("shot0")]
    for k in range(200):
        path, fields = rows[k % len(rows)]
        (w,) = signal_io.read(path)
        w = type(w)(w.t0, w.dt, w.samples * (1 + 1e-6 * k), w.units, w.calibration,
                    {**w.metadata, "plate_id": "LONG", "position": f"Q{k:03d}",
                     "x_m": float(fields["x_m"]), "y_m": 0.02 + 0.87 * k / 200,
                     "sphere_diameter": 9.53e-3})
        measure_and_store([w], store, tables, "bench", "shots")
    plate_report.report_bytes(store, tables, "LONG", {}, "json", joint=False)  # warm
    started = time.perf_counter()
    data = plate_report.report_bytes(store, tables, "LONG", {}, "pdf", joint=True, suggest=0)
    wall = time.perf_counter() - started
    store.close()
    pages = len(PdfReader(io.BytesIO(data)).pages)
    print(f"\n200 positions, joint map, no suggestions: {wall:.1f} s, {pages} pages, "
          f"{len(data) / 1e6:.1f} MB")
    assert pages > 20
