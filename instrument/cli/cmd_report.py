"""`solitonde report`: an inspection report a reviewer signs (PDF or HTML), and its check.

``report build`` makes one plate's report from a service (``--server``), a measurement store
(``--store``) or the recordings themselves (``--manifest``: analysed as ``analyze`` analyses
them, through the upload's road into a temporary store). ``report verify`` reads the data a
report carries (the PDF's attached report.json, the HTML's embedded block), checks them against
the digest it prints, and recomputes the digest from the same source: exit 0 where it matches,
1 naming what changed (a measurement added, reanalysed or deleted since), 2 for usage or a file
that is no report.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn
from urllib.parse import quote

import typer

from solitonde.instrument.cli.cmd_post import API_KEY_ENV

if TYPE_CHECKING:
    from solitonde.instrument.reports.content import DigestEntry, Report
    from solitonde.instrument.reports.digest import DigestItem

report_app = typer.Typer(help="Inspection reports: build one (PDF, HTML or its JSON) and verify "
                         "one against the stored data.", no_args_is_help=True)

FORMATS = {".pdf": "pdf", ".html": "html", ".htm": "html", ".json": "json"}


def _fail(message: str, code: int = 2) -> NoReturn:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(code)


_STARTED = [0.0]


def _say(text: str) -> None:
    """A step's progress on stderr, with the seconds since the command started."""
    import time

    if not _STARTED[0]:
        _STARTED[0] = time.perf_counter()
    typer.echo(f"report: {time.perf_counter() - _STARTED[0]:5.1f} s  {text}", err=True)


SERVER = typer.Option(None, "--server", help="the service's base URL")
STORE = typer.Option(None, "--store", help="a measurement store (SQLite file)")
MANIFEST = typer.Option(None, "--manifest", help="a campaign manifest: the recordings, "
                        "analysed here")
TABLES = typer.Option([], "--table", help="model table (or folder) for --manifest; repeat")
SETUP = typer.Option(None, "--setup", help="an instrument set-up saved from a service, for "
                     "--manifest")
CALIBRATION = typer.Option(None, "--calibration-file", help="a chain calibration (solitonde "
                           "calibrate) for --manifest")
MATERIAL = typer.Option(None, "--plate-material", help="the plate's material for --manifest: a "
                        "library name or its properties as JSON")


def _one_source(server: str | None, store: Path | None, manifest: Path | None) -> str:
    given = [name for name, v in (("--server", server), ("--store", store),
                                  ("--manifest", manifest)) if v is not None]
    if len(given) != 1:
        _fail("give one of --server, --store, --manifest" if not given else
              f"give one source, not {' and '.join(given)}")
    return given[0]


def _manifest_store(manifest: Path, folder: Path, tables_given: list[Path],
                    setup_file: Path | None, calibration_file: Path | None,
                    plate_material: str | None) -> tuple[Any, Any]:
    """A temporary store holding the manifest's recordings, one measurement per file, each
    measured and estimated by the upload's road (the set-up's or the file's chain
    calibration applied); and the tables."""
    from solitonde.instrument.cli import manifest as campaign
    from solitonde.instrument.cli.common import parse_material, setup_tables, table_set
    from solitonde.instrument.inference import measured_shots
    from solitonde.instrument.inference.calibration import Calibration, CalibrationError
    from solitonde.instrument.inference.setups import Setup, SetupError
    from solitonde.instrument.service.ingest import measure_and_store
    from solitonde.instrument.service.problems import Problem
    from solitonde.instrument.service.store import Store
    from solitonde.instrument.tables.table import TableError
    from solitonde.signal import channels as signal_channels
    from solitonde.signal.errors import WaveformError
    from solitonde.signal.io import EXTENSIONS

    setup = calibration = material = None
    try:
        if setup_file is not None:
            setup = Setup.load(setup_file)
        if calibration_file is not None:
            if setup is not None and setup.chain_calibration is not None:
                _fail("--calibration-file: the set-up has its own chain calibration; give one")
            calibration = Calibration.load(calibration_file)
        if plate_material is not None:
            material = parse_material(plate_material)
        tables = table_set(tables_given) if setup is None else setup_tables(setup, tables_given)
        rows = campaign.load(manifest)
        files = campaign.match(rows, manifest.parent, EXTENSIONS)
    except (SetupError, CalibrationError, TableError, campaign.ManifestError,
            ValueError) as exc:
        _fail(str(exc))
    from solitonde.instrument.service import setup_book

    store = Store(folder / "recordings.sqlite", background_checkpoint=False)
    if setup is not None:
        setup_book.keep(store, setup)
    for path, row in files:
        named = row.metadata.get("setup")
        if named is not None and (setup is None or named != setup.id):
            _fail(f"--manifest: {row.where}: setup {named!r}: give that set-up's file with "
                  "--setup" + ("" if setup is None else f" (--setup is {setup.id!r})"))
        try:
            row_material = row.metadata.get("plate_material")
            stated = {**row.metadata, "plate_material": parse_material(str(row_material))
                      } if row_material is not None else dict(row.metadata)
            stated.pop("setup", None)
        except ValueError as exc:
            _fail(f"--manifest: {row.where}: plate_material: {exc}")
        try:
            waves, _ = measured_shots.read_shots(path, None, {}, accepted_only=True,
                                                 fallback_calibration=row.calibration)
            waves, _ = signal_channels.select(waves, None, None, path.name)
            metas = [measured_shots.located(w.metadata, [(row.where, stated)], path.name)
                     for w in waves]
            if material is not None:  # the command line's, where the row and file say none
                metas = [{"plate_material": material, **m} if m.get("plate_material") is None
                         else m for m in metas]
            waves = [w.with_metadata(**{**m, "source": path.name}) for w, m in
                     zip(waves, metas, strict=True)]
            measure_and_store(waves, store, tables, f"file:{path.name}", "file.shots",
                              allow_duplicate=True, setup=setup, calibration=calibration)
        except (WaveformError, measured_shots.ShotInputError) as exc:
            _fail(f"{path}: {exc}", 1)
        except Problem as exc:
            _fail(f"{path}: {exc.detail}", 1)
    return store, tables


def _fetch(server: str, path: str, api_key_env: str) -> bytes:
    """A GET's body; the server's refusal or absence exits 1 in one line."""
    from solitonde.instrument.cli.uploader import ServerError, call

    try:
        return call(server, api_key_env, "GET", path, timeout_s=600.0).content
    except ServerError as exc:
        _fail(exc.message, 1)


@report_app.command("build")
def build(
    plate_id: str = typer.Option(..., "--plate-id", help="the plate"),
    out: Path = typer.Option(..., "--out", help="report.pdf, report.html or report.json"),
    server: str | None = SERVER,
    store: Path | None = STORE,
    manifest: Path | None = MANIFEST,
    table: list[Path] = typer.Option([], "--table", help="model table (or folder) for "
                                     "--store or --manifest (default: the bundled); repeat"),
    setup: Path | None = SETUP,
    calibration_file: Path | None = CALIBRATION,
    plate_material: str | None = MATERIAL,
    joint: bool = typer.Option(True, "--joint/--no-joint", help="invert the scan jointly"),
    suggest: int | None = typer.Option(None, "--suggest", min=0, max=20, help="the next "
                                       "positions to suggest (default: 3 up to 50 positions, "
                                       "none beyond)"),
    api_key_env: str = API_KEY_ENV,
) -> None:
    """Build one plate's inspection report (PDF, HTML, or the JSON they show)."""
    import time

    fmt = FORMATS.get(out.suffix.lower())
    if fmt is None:
        _fail(f"--out: {out.name} must end in .pdf, .html or .json")
    if out.is_dir():
        _fail(f"--out: {str(out)!r} is a folder; give the report's file name")
    source = _one_source(server, store, manifest)
    if source != "--manifest" and (setup or calibration_file or plate_material):
        _fail("--setup, --calibration-file and --plate-material go with --manifest (a service "
              "or a store holds its own)")
    if server is not None and table:
        _fail("--table goes with --store or --manifest (a service has its own tables)")
    started = _STARTED[0] = time.perf_counter()
    if server is not None:
        query = f"joint={'true' if joint else 'false'}"
        if suggest is not None:
            query += f"&suggest={suggest}"
        _say(f"asking {server} for plate {plate_id!r}")
        data = _fetch(server, f"/v1/plates/{quote(plate_id, safe='')}/report.{fmt}?{query}",
                      api_key_env)
    else:
        data = _local(plate_id, fmt, store, manifest, table, setup, calibration_file,
                      plate_material, joint, suggest)
    from solitonde.signal.atomic import write_bytes

    write_bytes(out, data)
    typer.echo(f"wrote {out} ({len(data) / 1e3:.0f} kB, {time.perf_counter() - started:.1f} s)")


def _open_store(path: Path) -> Any:
    """The measurement store ``--store`` names (exit 2 naming the flag where it is none)."""
    from solitonde.instrument.service.store import Store, StoreError

    if not path.is_file():
        _fail(f"--store: no such file: {path}")
    try:
        return Store(path, background_checkpoint=False)
    except StoreError as exc:
        _fail(f"--store: {exc}")


def _local(plate_id: str, fmt: str, store_path: Path | None, manifest: Path | None,
           tables_given: list[Path], setup: Path | None, calibration_file: Path | None,
           plate_material: str | None, joint: bool, suggest: int | None) -> bytes:
    from solitonde.instrument.cli.common import table_set
    from solitonde.instrument.service import plate_report

    with tempfile.TemporaryDirectory(prefix="solitonde-report-") as folder:
        if manifest is not None:
            _say(f"analysing the recordings of {manifest.name}")
            store, tables = _manifest_store(manifest, Path(folder), tables_given, setup,
                                            calibration_file, plate_material)
            source = {"manifest": str(manifest)}
        else:
            assert store_path is not None
            store = _open_store(store_path)
            tables = table_set(tables_given or None)
            source = {"store": str(store_path)}
        try:
            data = plate_report.report_bytes(store, tables, plate_id, source, fmt,
                                             joint=joint, suggest=suggest, progress=_say)
            _say("done")
            return data
        except plate_report.NoSuchPlate:
            plates = [p["plate_id"] for p in store.plates()]
            _fail(f"--plate-id: no plate {plate_id!r} (plates: {', '.join(plates) or 'none'})",
                  1)
        finally:
            store.close()


def read_report(path: Path) -> Report:
    """The data a report file carries: a PDF's attached report.json, an HTML's embedded block,
    or report.json itself. ValueError where there are none."""
    import re

    from solitonde.instrument.reports.render import ATTACHMENT

    raw = path.read_bytes()
    if raw.startswith(b"%PDF"):
        import io

        from pypdf import PdfReader
        from pypdf.errors import PyPdfError

        try:
            attached = PdfReader(io.BytesIO(raw)).attachments.get(ATTACHMENT)
        except PyPdfError as exc:
            raise ValueError(f"{path.name} is not a readable PDF ({exc})") from None
        if not attached:
            raise ValueError(f"{path.name} is a PDF without an attached {ATTACHMENT}: not a "
                             "solitonde report")
        return json.loads(attached[0])
    text = raw.decode("utf-8", errors="replace")
    if text.lstrip().startswith("{"):
        return json.loads(text)
    found = re.search(r'<script type="application/json" id="report-data">(.*?)</script>', text,
                      flags=re.S)
    if found is None:
        raise ValueError(f"{path.name} holds no report data: not a solitonde report")
    return json.loads(found.group(1).replace("<\\/", "</"))


@report_app.command("verify")
def verify(
    report_file: Path = typer.Argument(..., metavar="REPORT", help="report.pdf, .html or .json"),
    server: str | None = SERVER,
    store: Path | None = STORE,
    manifest: Path | None = MANIFEST,
    table: list[Path] = TABLES,
    setup: Path | None = SETUP,
    calibration_file: Path | None = CALIBRATION,
    plate_material: str | None = MATERIAL,
    api_key_env: str = API_KEY_ENV,
) -> None:
    """Check a report against the data it was made from: exit 0 where they match, 1 naming
    what changed since."""
    from solitonde.instrument.reports import content, digest

    _one_source(server, store, manifest)
    if not report_file.is_file():
        _fail(f"REPORT: no such file: {report_file}")
    try:
        report = read_report(report_file)
        plate_id = report["plate_id"]
        reported = [content.without_digest(e) for e in report["measurements"]]
    except (ValueError, KeyError, TypeError) as exc:
        _fail(f"REPORT: {exc}")
        return
    try:
        tampered = content.verify_entries(report)
    except (KeyError, TypeError, ValueError) as exc:
        _fail(f"REPORT: not a solitonde report's data ({type(exc).__name__}: {exc})")
        return
    if tampered is not None:
        typer.echo(f"{report_file.name}: does not match: {tampered}")
        raise typer.Exit(1)
    if server is not None:
        body = json.loads(_fetch(server, f"/v1/plates/{quote(plate_id, safe='')}/digest",
                                 api_key_env))
        current = body["measurements"]
    else:
        current = _local_entries(plate_id, store, manifest, table, setup, calibration_file,
                                 plate_material)
    current_items = [content.without_digest(e) for e in current]
    found: list[str] = []
    if manifest is not None:
        # offline, the recordings, the table and the chain calibration are verified; today's
        # version may read the recordings anew, so the results themselves are not compared
        for e in current_items:
            then = _by_id(reported, e["id"])
            if then is None:
                continue
            found += [f"measurement {e['id']}: {what} differs from the report's"
                      for what in _made_with(then, e)]
            e["result"] = then["result"]
    found += digest.changes(reported, current_items)
    if found:
        typer.echo(f"{report_file.name}: does not match plate {plate_id!r} as it is now:")
        for line in found:
            typer.echo(f"  {line}")
        raise typer.Exit(1)
    what = ("the recordings, their positions, the table and the chain calibration are the "
            "report's (results not recomputed); " if manifest is not None else "")
    typer.echo(f"{report_file.name}: matches plate {plate_id!r} ({what}{len(current_items)} "
               f"measurements, data digest {report['digest']['value']})")


def _made_with(then: DigestItem, now: DigestItem) -> list[str]:
    """What two entries' results of the same recordings were made with that differs: the table
    (its SHA-256), the set-up revision, the chain calibration."""
    a, b = then["result"].get("provenance") or {}, now["result"].get("provenance") or {}
    out = []
    if (a.get("table") or {}).get("sha256") != (b.get("table") or {}).get("sha256"):
        out.append("the table")
    for key, name in (("setup", "the set-up"), ("chain_calibration", "the chain calibration")):
        if a.get(key) != b.get(key):
            out.append(name)
    return out


def _by_id(entries: list[DigestItem], key: Any) -> DigestItem | None:
    return next((e for e in entries if str(e["id"]) == str(key)), None)


def _local_entries(plate_id: str, store_path: Path | None, manifest: Path | None,
                   tables_given: list[Path], setup: Path | None, calibration_file: Path | None,
                   plate_material: str | None) -> list[DigestEntry]:
    from solitonde.instrument.service import plate_report

    with tempfile.TemporaryDirectory(prefix="solitonde-verify-") as folder:
        if manifest is not None:
            store, _ = _manifest_store(manifest, Path(folder), tables_given, setup,
                                       calibration_file, plate_material)
        else:
            assert store_path is not None
            store = _open_store(store_path)
        try:
            return plate_report.entries(store, plate_id)
        finally:
            store.close()


def register(app: typer.Typer) -> None:
    """Add `report` to the CLI."""
    app.add_typer(report_app, name="report")


