"""Keeping the measurement store as a record: online backup, integrity check, schema migration.

* :func:`backup` uses SQLite's online backup API: one read transaction copies every page, so the
  copy is one consistent state of the store while the server goes on writing (WAL lets writers
  commit beside a reader). The copy is written under a temporary name, checked, synced and then
  renamed: a destination that exists is a complete, checked backup.
* :func:`check` runs SQLite's ``integrity_check`` and ``foreign_key_check``, compares the schema
  version and, unless told not to, decodes every stored trace and verifies its SHA-256.
* :func:`migrate` backs the store up beside itself, then applies
  :data:`~.store.MIGRATIONS` in one transaction: all of them or none.
"""

from __future__ import annotations

import contextlib
import os
import sqlite3
import time
from pathlib import Path
from typing import Literal, TypedDict

from solitonde.instrument.service.store import (
    MIGRATIONS,
    SCHEMA_VERSION,
    StoreError,
    decode_samples,
)


def _connect(path: Path) -> sqlite3.Connection:
    """A connection to an existing store (never creates one: a typo must not make a new file)."""
    if not path.is_file():
        raise StoreError(f"no store at {str(path)!r}")
    try:
        conn = sqlite3.connect(path, timeout=30.0, isolation_level=None)
        conn.execute("PRAGMA busy_timeout = 30000")
        conn.execute("SELECT COUNT(*) FROM sqlite_master").fetchone()
    except sqlite3.Error as exc:
        raise StoreError(f"cannot read the store at {str(path)!r}: {exc}") from None
    return conn


class Counts(TypedDict, total=False):
    """Rows of the store's main tables (a table the store lacks is left out)."""

    measurements: int
    shots: int
    earlier_results: int


_COUNTED: tuple[Literal["measurements", "shots", "earlier_results"], ...] = (
    "measurements", "shots", "earlier_results")


class Backup(Counts):
    """What :func:`backup` made: the copy, its schema and counts, its size, the time taken."""

    store: str
    backup: str
    schema_version: int
    bytes: int
    seconds: float


class Check(Counts):
    """What :func:`check` found; ``ok`` when ``problems`` is empty."""

    store: str
    ok: bool
    schema_version: int
    schema_current: int
    integrity: str | list[str]
    """``"ok"``, or SQLite's first messages."""
    foreign_key_violations: int
    traces_checked: int
    problems: list[str]


Migration = TypedDict("Migration", {"store": str, "from": int, "to": int,
                                     "backup": str | None})
"""What :func:`migrate` did: the schema versions, and the backup made first (None where the
store was current)."""


def _counts(conn: sqlite3.Connection) -> Counts:
    tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    counts: Counts = {}
    for name in _COUNTED:
        if name in tables:
            counts[name] = int(conn.execute(f"SELECT COUNT(*) FROM {name}").fetchone()[0])
    return counts


def backup(store: Path, dest: Path) -> Backup:
    """Copy ``store`` to ``dest`` with SQLite's online backup; safe while the server writes.

    Refuses an existing ``dest``. Returns the copy's counts and how long it took."""
    store, dest = Path(store), Path(dest)
    if dest.exists():
        raise StoreError(f"{str(dest)!r} exists; give a new file name for the backup")
    dest.parent.mkdir(parents=True, exist_ok=True)
    partial = dest.with_name(f".{dest.name}.partial-{os.getpid()}")
    started = time.perf_counter()
    source = _connect(store)
    try:
        target = sqlite3.connect(partial, isolation_level=None)
        try:
            source.backup(target)  # every page in one step: one consistent snapshot
            target.execute("PRAGMA journal_mode = DELETE")  # one self-contained file
            result = target.execute("PRAGMA integrity_check").fetchall()
            counts = _counts(target)
            version = int(target.execute("PRAGMA user_version").fetchone()[0])
        finally:
            target.close()
        if [r[0] for r in result] != ["ok"]:
            raise StoreError(f"the backup of {str(store)!r} fails its integrity check: "
                             f"{[r[0] for r in result][:5]}")
        with open(partial, "rb") as fh:
            os.fsync(fh.fileno())
        os.replace(partial, dest)
    except sqlite3.Error as exc:
        raise StoreError(f"backup of {str(store)!r} to {str(dest)!r} failed: {exc}") from None
    finally:
        source.close()
        with contextlib.suppress(FileNotFoundError):
            partial.unlink()
    return {"store": str(store), "backup": str(dest), "schema_version": version, **counts,
            "bytes": dest.stat().st_size, "seconds": round(time.perf_counter() - started, 3)}


def check(store: Path, traces: bool = True) -> Check:
    """Integrity, foreign keys, schema version and (``traces``) every trace's SHA-256.

    ``ok`` is true when all of them pass and the schema is this version's."""
    store = Path(store)
    conn = _connect(store)
    try:
        version = int(conn.execute("PRAGMA user_version").fetchone()[0])
        integrity = [r[0] for r in conn.execute("PRAGMA integrity_check").fetchall()]
        foreign = conn.execute("PRAGMA foreign_key_check").fetchall()
        counts = _counts(conn)
        problems: list[str] = []
        checked = 0
        if "measurements" not in counts:
            problems.append("not a solitonde measurement store (no measurements table)")
        if traces and "shots" in counts:
            rows = conn.execute("SELECT measurement_id, shot_index, dtype, samples, n_samples, "
                                "sha256, codec FROM shots ORDER BY measurement_id, shot_index")
            for mid, index, dtype, blob, n, digest, codec in rows:
                try:
                    decode_samples(dtype, blob, n, digest, codec)
                except StoreError as exc:
                    problems.append(f"measurement {mid} shot {index}: {exc}")
                checked += 1
    except sqlite3.Error as exc:
        raise StoreError(f"cannot check the store at {str(store)!r}: {exc}") from None
    finally:
        conn.close()
    if version < SCHEMA_VERSION:
        problems.append(f"schema {version} is older than this version's {SCHEMA_VERSION}: run "
                        f"`solitonde store migrate {store}`")
    elif version > SCHEMA_VERSION:
        problems.append(f"schema {version} was written by a newer solitonde (this version "
                        f"knows up to {SCHEMA_VERSION})")
    if integrity != ["ok"]:
        problems.append("integrity_check: " + "; ".join(integrity[:5]))
    if foreign:
        problems.append(f"{len(foreign)} rows refer to missing measurements")
    return {"store": str(store), "ok": not problems, "schema_version": version,
            "schema_current": SCHEMA_VERSION, "integrity": integrity[0] if integrity == ["ok"]
            else integrity[:5], "foreign_key_violations": len(foreign), **counts,
            "traces_checked": checked, "problems": problems}


def migrate(store: Path, backup_to: Path | None = None) -> Migration:
    """Bring ``store`` to :data:`SCHEMA_VERSION`: a backup first (``backup_to``, by default
    ``<store>.schema<v>-<UTC time>.sqlite`` beside it), then every migration in one
    transaction. A store already current is left alone (no backup)."""
    store = Path(store)
    conn = _connect(store)
    try:
        version = int(conn.execute("PRAGMA user_version").fetchone()[0])
        if version == 0 and "measurements" in _counts(conn):
            version = 1  # written before the version was recorded: schema 1's layout
    finally:
        conn.close()
    if version > SCHEMA_VERSION:
        raise StoreError(f"{str(store)!r} has schema {version}, written by a newer solitonde "
                         f"(this version knows up to {SCHEMA_VERSION})")
    if version == SCHEMA_VERSION:
        return {"store": str(store), "from": version, "to": version, "backup": None}
    if version < 1:
        raise StoreError(f"{str(store)!r} has no store schema version: not a solitonde store")
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    saved = backup(store, backup_to or store.with_name(f"{store.name}.schema{version}-{stamp}"
                                                      f".sqlite"))
    conn = _connect(store)
    try:
        conn.execute("BEGIN IMMEDIATE")
        try:
            for v in range(version, SCHEMA_VERSION):
                for statement in MIGRATIONS[v]:
                    conn.execute(statement)
            conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
            conn.execute("COMMIT")
        except BaseException:
            if conn.in_transaction:
                conn.execute("ROLLBACK")
            raise
    except sqlite3.Error as exc:
        raise StoreError(f"migration of {str(store)!r} failed, nothing changed ({exc}); the "
                         f"backup is {saved['backup']}") from None
    finally:
        conn.close()
    return {"store": str(store), "from": version, "to": SCHEMA_VERSION,
            "backup": saved["backup"]}
