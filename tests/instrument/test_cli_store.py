"""The measurement store refuses what it cannot safely use: a damaged file, another program's
SQLite database, a store written by a newer solitonde; `solitonde serve` says so in one line."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app
from solitonde.instrument.service.store import SCHEMA_VERSION, ShotRecord, Store, StoreError


def _shot() -> ShotRecord:
    return ShotRecord(0.0, 1e-6, np.arange(10.0), "N", None, {}, {})


def test_a_damaged_file_is_a_store_error(tmp_path: Path) -> None:
    path = tmp_path / "s.sqlite"
    path.write_bytes(b"x" * 5000)
    with pytest.raises(StoreError, match="not a database"):
        Store(path, background_checkpoint=False)


def test_another_programs_database_is_refused_untouched(tmp_path: Path) -> None:
    path = tmp_path / "s.sqlite"
    with sqlite3.connect(path) as conn:
        conn.execute("CREATE TABLE measurements (a TEXT)")
    with pytest.raises(StoreError, match="not a solitonde measurement store"):
        Store(path, background_checkpoint=False)
    with sqlite3.connect(path) as conn:
        tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master")}
    assert tables == {"measurements"}


def test_a_store_from_a_newer_schema_is_refused(tmp_path: Path) -> None:
    """It opened, and every write then failed (or wrote rows in a layout it did not know)."""
    path = tmp_path / "s.sqlite"
    store = Store(path, background_checkpoint=False)
    store.add([_shot()], {}, "test", "P", "A")
    store.close()
    with sqlite3.connect(path) as conn:
        assert conn.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION
        conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    with pytest.raises(StoreError, match="newer solitonde"):
        Store(path, background_checkpoint=False)


def test_a_store_without_a_version_is_adopted_with_its_data(tmp_path: Path) -> None:
    path = tmp_path / "s.sqlite"
    store = Store(path, background_checkpoint=False)
    new_id, _ = store.add([_shot()], {"k": 1}, "test", "P", "A")
    store.close()
    with sqlite3.connect(path) as conn:  # as stores written before the version was recorded
        conn.execute("PRAGMA user_version = 0")
    store = Store(path, background_checkpoint=False)
    try:
        record = store.get(new_id, with_samples=True)
        assert record is not None and record.result == {"k": 1}
        assert np.array_equal(record.shots[0].samples, np.arange(10.0))
    finally:
        store.close()


def test_serve_with_an_unusable_store_is_one_error_line(tmp_path: Path) -> None:
    path = tmp_path / "s.sqlite"
    path.write_bytes(b"x" * 5000)
    res = CliRunner().invoke(build_app(), ["serve", "--port", "18999", "--store", str(path)])
    assert res.exit_code == 2 and isinstance(res.exception, SystemExit), res.output
    assert "error: store: " in res.output and "not a database" in res.output
