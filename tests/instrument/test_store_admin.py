"""The store as a record of inspections: a store written by the released version (schema 1,
``tests/data/store_v1.sqlite``) migrates without loss; backup, check and reanalyze from the
command line; reanalysis keeps every earlier result and records what each result came from."""

from __future__ import annotations

import hashlib
import json
import shutil
import sqlite3
from pathlib import Path

import pytest
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app
from solitonde.instrument.service.settings import DEFAULT_TABLE
from solitonde.instrument.service.store import SCHEMA_VERSION, SchemaTooOld, Store, StoreError
from solitonde.instrument.service.store_admin import backup, check

FIXTURE = Path(__file__).resolve().parents[1] / "data" / "store_v1.sqlite"
"""Written by the release before schema 2 (commit 1c27ca4's service): two bundled sample files
with estimates (plate ``fixture``) and one scan file with its position (plate ``scan``)."""

runner = CliRunner()


def _cli(*args: str) -> tuple[int, str]:
    result = runner.invoke(build_app(), list(args))
    return result.exit_code, result.output


def _rows(path: Path) -> dict[str, list[tuple]]:
    """Every row of the data tables, in key order (blobs included)."""
    with sqlite3.connect(path) as conn:
        return {
            "measurements": conn.execute("SELECT * FROM measurements ORDER BY id").fetchall(),
            "shots": conn.execute("SELECT * FROM shots ORDER BY measurement_id, shot_index"
                                  ).fetchall(),
            "idempotency": conn.execute("SELECT * FROM idempotency ORDER BY key").fetchall(),
        }


@pytest.fixture
def released(tmp_path: Path) -> Path:
    """A copy of the released store (the fixture itself is never written)."""
    path = tmp_path / "released.sqlite"
    shutil.copyfile(FIXTURE, path)
    return path


def test_the_fixture_is_a_released_store() -> None:
    with sqlite3.connect(FIXTURE) as conn:
        assert conn.execute("PRAGMA user_version").fetchone()[0] == 1
        assert conn.execute("SELECT COUNT(*) FROM measurements").fetchone()[0] == 3


def test_a_released_store_is_refused_until_migrated_then_opens_without_loss(
        released: Path) -> None:
    """The server refuses the old schema with the command that fixes it; `store migrate` backs
    it up, migrates in one transaction, and every row and trace is as it was."""
    before = _rows(released)
    with pytest.raises(SchemaTooOld, match="solitonde store migrate"):
        Store(released, background_checkpoint=False)
    code, out = _cli("store", "check", str(released))
    assert code == 1 and "store migrate" in out
    code, out = _cli("store", "migrate", str(released), "--json")
    assert code == 0, out
    report = json.loads(out)
    assert (report["from"], report["to"]) == (1, SCHEMA_VERSION)
    assert _rows(Path(report["backup"])) == before  # the backup is the store as it was
    assert _rows(released) == before  # nothing lost, nothing changed
    with sqlite3.connect(released) as conn:
        assert conn.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION
    store = Store(released, background_checkpoint=False)
    try:
        for m in store.list(limit=10):
            record = store.get(m.id, with_samples=True)
            assert record is not None and record.result == m.result
            assert all(s.samples.size == s.n_samples > 0 for s in record.shots)
            assert record.earlier == []
    finally:
        store.close()
    code, out = _cli("store", "check", str(released))
    assert code == 0 and " ok " in out, out
    code, out = _cli("store", "migrate", str(released))
    assert code == 0 and "already current" in out


def test_check_finds_a_damaged_trace(released: Path) -> None:
    """One flipped byte in a stored trace: `store check` names the shot and exits 1."""
    _cli("store", "migrate", str(released))
    with sqlite3.connect(released) as conn:
        blob = bytearray(conn.execute("SELECT samples FROM shots WHERE measurement_id = 2 AND "
                                      "shot_index = 0").fetchone()[0])
        blob[len(blob) // 2] ^= 0xFF
        conn.execute("UPDATE shots SET samples = ? WHERE measurement_id = 2 AND shot_index = 0",
                     (bytes(blob),))
    code, out = _cli("store", "check", str(released))
    assert code == 1 and "measurement 2 shot 0" in out, out
    assert check(released, traces=False)["ok"]  # the SQLite structure itself is intact


def test_backup_refuses_to_overwrite_and_never_creates_a_store(tmp_path: Path,
                                                                released: Path) -> None:
    _cli("store", "migrate", str(released))
    dest = tmp_path / "b.sqlite"
    assert backup(released, dest)["measurements"] == 3
    with pytest.raises(StoreError, match="exists"):
        backup(released, dest)
    code, out = _cli("store", "backup", str(tmp_path / "nope.sqlite"), str(tmp_path / "c"))
    assert code == 2 and "no store" in out
    assert not (tmp_path / "nope.sqlite").exists() and not (tmp_path / "c").exists()
    assert not list(tmp_path.glob(".*partial*"))


def test_reanalyze_recomputes_every_measurement_and_keeps_the_earlier_results(
        released: Path) -> None:
    """A store made with the released version and its table: reanalysis with the current one
    gives each measurement a result with provenance (version, extractor settings, table id and
    SHA-256 of its file); the released result stays, listed by the API."""
    from fastapi.testclient import TestClient

    from solitonde.instrument.service.app import build_app as build_service
    from solitonde.instrument.service.settings import Settings

    _cli("store", "migrate", str(released))
    old = {m["id"]: m["result"] for m in _results(released)}
    code, out = _cli("store", "reanalyze", str(released), "--table", str(DEFAULT_TABLE),
                     "--json")
    assert code == 0, out
    report = json.loads(out)
    assert sorted(r["id"] for r in report["reanalyzed"]) == sorted(old) and not report["failed"]
    sha = hashlib.sha256(DEFAULT_TABLE.read_bytes()).hexdigest()
    app = build_service(Settings(store_path=released, table_path=DEFAULT_TABLE))
    with TestClient(app) as client:
        for mid, before in old.items():
            got = client.get(f"/v1/measurements/{mid}").json()
            prov = got["provenance"]
            assert prov["software_version"] and prov["extractor"]["options"]
            assert prov["table"] == {"id": "default_table", "sha256": sha}
            (earlier,) = got["earlier_results"]
            assert earlier["estimate"] == before["estimate"]
            assert earlier["provenance"] is None  # the released version recorded none
            assert len(earlier["shot_features"]) == got["n_shots"]
            if before.get("location"):
                assert got["location"] == before["location"]
    # once more, with the plate filter: one more earlier result, the others untouched
    code, out = _cli("store", "reanalyze", str(released), "--table", str(DEFAULT_TABLE),
                     "--plate-id", "scan")
    assert code == 0 and "reanalyzed 1 measurements" in out, out
    counts = {m["id"]: m["earlier"] for m in _results(released)}
    assert sorted(counts.values()) == [1, 1, 2]
    assert check(released)["ok"]


def _results(path: Path) -> list[dict]:
    store = Store(path, background_checkpoint=False)
    try:
        return [{"id": m.id, "result": m.result, "earlier": len(store.earlier_results(m.id))}
                for m in store.list(limit=100)]
    finally:
        store.close()
