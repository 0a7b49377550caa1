"""The measurement store: SQLite in WAL mode, one transaction per measurement.

Why SQLite: embedded, one file, concurrent readers with one writer at a time across worker
processes, and atomic commits. A measurement and all its shots are written inside one
``BEGIN IMMEDIATE ... COMMIT``: a reader (or a restart after ``kill -9``) sees all of it or none of
it. With ``synchronous=NORMAL`` a committed transaction is in the WAL file before ``COMMIT``
returns, so it survives the death of the process; ``FULL`` adds an fsync per commit for power loss.

Traces are stored losslessly and compressed: float32 when that represents every sample exactly
(any ADC of up to 24 bits), else float64; compressed with zstd (pyarrow's codec: a third of
zlib's time at the same ratio on quantised traces); a SHA-256 of the raw samples is stored and
checked on every read (:mod:`.trace_codec`). Its errors live in :mod:`.store_errors`.
"""

from __future__ import annotations

import contextlib
import json
import os
import sqlite3
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypedDict

import numpy as np

from solitonde.instrument.service.measurement_json import EarlierEntry, StoredResult
from solitonde.instrument.service.store_errors import (
    KeyTaken,
    SchemaTooOld,
    SetupConflict,
    SetupGone,
    StoreError,
    StoreFull,
)
from solitonde.instrument.service.trace_codec import (
    CODEC,
    decode_samples,
    encode_samples,
)
from solitonde.instrument.service.trace_codec import samples_digest as samples_digest
from solitonde.signal.features import FeatureDict

_SCHEMA = """
CREATE TABLE IF NOT EXISTS measurements (
    id          INTEGER PRIMARY KEY AUTOINCREMENT,
    created_at  REAL NOT NULL,
    plate_id    TEXT,
    position    TEXT,
    n_shots     INTEGER NOT NULL,
    source      TEXT NOT NULL,
    result      TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS measurements_by_plate ON measurements (plate_id, id);
CREATE TABLE IF NOT EXISTS shots (
    measurement_id    INTEGER NOT NULL REFERENCES measurements (id) ON DELETE CASCADE,
    shot_index        INTEGER NOT NULL,
    t0                REAL NOT NULL,
    dt                REAL NOT NULL,
    units             TEXT NOT NULL,
    calibration       REAL,
    metadata          TEXT NOT NULL,
    n_samples         INTEGER NOT NULL,
    dtype             TEXT NOT NULL,
    codec             TEXT NOT NULL,
    sha256            TEXT NOT NULL,
    samples           BLOB NOT NULL,
    features          TEXT NOT NULL,
    PRIMARY KEY (measurement_id, shot_index)
);
CREATE TABLE IF NOT EXISTS idempotency (
    key             TEXT PRIMARY KEY,
    digest          TEXT NOT NULL,
    measurement_id  INTEGER NOT NULL,
    created_at      REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS earlier_results (
    measurement_id  INTEGER NOT NULL REFERENCES measurements (id) ON DELETE CASCADE,
    superseded_at   REAL NOT NULL,
    result          TEXT NOT NULL,
    shot_features   TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS earlier_results_by_measurement
    ON earlier_results (measurement_id, superseded_at);
CREATE INDEX IF NOT EXISTS shots_by_content ON shots (sha256, shot_index);
CREATE TABLE IF NOT EXISTS setups (
    id          TEXT NOT NULL,
    revision    INTEGER NOT NULL,
    created_at  REAL NOT NULL,
    body        TEXT NOT NULL,
    PRIMARY KEY (id, revision)
);
CREATE TABLE IF NOT EXISTS setup_uses (
    measurement_id  INTEGER PRIMARY KEY REFERENCES measurements (id) ON DELETE CASCADE,
    setup_id        TEXT NOT NULL,
    revision        INTEGER NOT NULL
);
CREATE INDEX IF NOT EXISTS setup_uses_by_setup ON setup_uses (setup_id, measurement_id);
CREATE TABLE IF NOT EXISTS jobs (
    id          TEXT PRIMARY KEY,
    created_at  REAL NOT NULL,
    updated_at  REAL NOT NULL,
    body        TEXT NOT NULL
);
"""


SCHEMA_VERSION = 3
"""Stored as SQLite's ``user_version``; a store with a larger one was written by a newer
solitonde and is refused rather than written in a layout this version does not know; one with a
smaller one is refused until ``solitonde store migrate`` brings it up (after a backup).

1: measurements, shots, idempotency keys.
2: ``earlier_results``: the results a reanalysis replaced (the result and each shot's features),
   kept beside the newest one.
3: ``setups`` (each revision of an instrument set-up, immutable), ``setup_uses`` (the set-up
   revision a measurement was estimated with) and ``jobs`` (background work and its progress,
   readable from any worker process)."""

MIGRATIONS: dict[int, tuple[str, ...]] = {
    1: ("""CREATE TABLE earlier_results (
               measurement_id  INTEGER NOT NULL REFERENCES measurements (id) ON DELETE CASCADE,
               superseded_at   REAL NOT NULL,
               result          TEXT NOT NULL,
               shot_features   TEXT NOT NULL)""",
        """CREATE INDEX earlier_results_by_measurement
               ON earlier_results (measurement_id, superseded_at)"""),
    2: tuple(statement.strip() for statement in _SCHEMA.split(";")
             if "setup" in statement or "jobs" in statement),
}
"""The statements that take a store from schema ``v`` to ``v + 1``; run by :func:`migrate`."""

_COLUMNS = {
    "measurements": {"id", "created_at", "plate_id", "position", "n_shots", "source", "result"},
    "shots": {"measurement_id", "shot_index", "t0", "dt", "units", "calibration", "metadata",
              "n_samples", "dtype", "codec", "sha256", "samples", "features"},
}


def _journal_mode_wal(conn: sqlite3.Connection, timeout_s: float) -> str:
    """Put the database in WAL mode (a no-op when it already is) and return the mode.

    Two workers opening the store at once, or one opening it while another recovers the WAL a
    killed process left, can get SQLITE_BUSY here without SQLite's busy handler being consulted:
    retried for up to ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            mode = str(conn.execute("PRAGMA journal_mode").fetchone()[0])
            if mode.lower() == "wal":
                return mode
            return str(conn.execute("PRAGMA journal_mode = WAL").fetchone()[0])
        except sqlite3.OperationalError as exc:
            if "locked" not in str(exc) or time.monotonic() > deadline:
                raise
            time.sleep(0.05)


@dataclass
class ShotRecord:
    """One shot as stored: the trace and what was measured on it."""

    t0: float
    dt: float
    samples: np.ndarray
    units: str
    calibration: float | None
    metadata: dict[str, Any]
    features: FeatureDict
    shot_index: int = 0
    n_samples: int = -1
    sha256: str | None = None
    """The SHA-256 of the samples as stored (:func:`samples_digest`); set on reading."""

    def __post_init__(self) -> None:
        if self.n_samples < 0:
            self.n_samples = int(np.size(self.samples))


class PlateRow(TypedDict):
    """A plate's line of :meth:`Store.plates`."""

    plate_id: str
    n_measurements: int
    n_shots: int
    n_positions: int
    last_activity: float
    """The newest measurement's time, Unix s."""


@dataclass
class MeasurementRecord:
    """One measurement as stored (shots without their samples unless asked for)."""

    id: int
    created_at: float
    plate_id: str | None
    position: str | None
    n_shots: int
    source: str
    result: StoredResult
    shots: list[ShotRecord] = field(default_factory=list)
    earlier: list[EarlierEntry] = field(default_factory=list)
    """Results a reanalysis replaced (:meth:`Store.earlier_results`); :meth:`Store.get` fills it."""


class Store:
    """Measurement store on one SQLite file; safe to share between threads of one process.

    Several processes (uvicorn workers) may open the same file: SQLite's locks serialise the
    writers and WAL lets readers run beside them.
    """

    CHECKPOINT_INTERVAL_S = 0.1
    """Under sustained writes the WAL restarts only when it reaches :attr:`AUTOCHECKPOINT_PAGES`
    and the writer that crosses it checkpoints the frames not yet copied, with two fsyncs,
    while every other writer waits (the only commits over 20 ms measured: one per ~1,300
    measurements, none without checkpoints). Checkpointing every 0.1 s instead of 0.5 s leaves
    it fewer frames: those stalls measured 22-45 ms instead of 31-96 ms, no more often."""
    AUTOCHECKPOINT_PAGES = 16384
    """Safety net: SQLite checkpoints itself in the writer once the WAL reaches 64 MiB."""

    def __init__(self, path: str | Path, synchronous: str = "NORMAL",
                 background_checkpoint: bool = True) -> None:
        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._conn = sqlite3.connect(self.path, timeout=30.0, isolation_level=None,
                                         check_same_thread=False)
        except (OSError, sqlite3.Error) as exc:
            raise StoreError(f"cannot open the store at {str(self.path)!r}: {exc}") from None
        self._lock = threading.Lock()
        try:
            self._writer_fd = _open_writer_lock(self.path)
            with self._lock:
                c = self._conn
                c.execute("PRAGMA busy_timeout = 30000")
                mode = _journal_mode_wal(c, timeout_s=30.0)
                if str(mode).lower() != "wal":
                    raise StoreError(f"{self.path}: could not switch to WAL mode (got {mode})")
                c.execute(f"PRAGMA synchronous = {synchronous.upper()}")
                c.execute("PRAGMA foreign_keys = ON")
                self._write_schema()
        except (OSError, sqlite3.Error, StoreError) as exc:
            self._conn.close()
            fd = getattr(self, "_writer_fd", None)
            if fd is not None:
                os.close(fd)
            if isinstance(exc, StoreError):
                raise
            raise StoreError(f"cannot use the store at {str(self.path)!r}: {exc} (not a "
                             "solitonde measurement store, damaged, or not writable)") from None
        self._stop = threading.Event()
        self._checkpointer: threading.Thread | None = None
        if background_checkpoint:
            # Copying the WAL into the database (and its fsync) happens in a thread of its
            # own instead of inside whichever request crosses the WAL size threshold.
            self._conn.execute(f"PRAGMA wal_autocheckpoint = {self.AUTOCHECKPOINT_PAGES}")
            self._checkpointer = threading.Thread(target=self._checkpoint_loop,
                                                  name="store-checkpoint", daemon=True)
            self._checkpointer.start()

    def _checkpoint_loop(self) -> None:
        try:
            conn = sqlite3.connect(self.path, timeout=0.1, isolation_level=None,
                                   check_same_thread=False)
        except sqlite3.Error:
            return
        try:
            while not self._stop.wait(self.CHECKPOINT_INTERVAL_S):
                with contextlib.suppress(sqlite3.Error):
                    conn.execute("PRAGMA wal_checkpoint(PASSIVE)")
        finally:
            conn.close()

    def _write_schema(self) -> None:
        # Several workers may start at once: take the write lock before creating tables.
        c = self._conn
        c.execute("BEGIN IMMEDIATE")
        try:
            version = int(c.execute("PRAGMA user_version").fetchone()[0])
            if version > SCHEMA_VERSION:
                raise StoreError(f"{str(self.path)!r} was written by a newer solitonde (store "
                                 f"schema {version}; this version knows up to {SCHEMA_VERSION})")
            has_tables = c.execute("SELECT COUNT(*) FROM sqlite_master WHERE type = 'table' "
                                   "AND name = 'measurements'").fetchone()[0]
            if has_tables and 0 < version < SCHEMA_VERSION:
                raise SchemaTooOld(f"{str(self.path)!r} has store schema {version}; this "
                                   f"version uses {SCHEMA_VERSION}: run `solitonde store migrate "
                                   f"{self.path}` (it backs the store up first)")
            for table, columns in _COLUMNS.items():
                have = {row[1] for row in c.execute(f"PRAGMA table_info({table})")}
                if have and not columns <= have:  # an existing table of some other layout
                    raise StoreError(f"{str(self.path)!r} is not a solitonde measurement store "
                                     f"(its table {table!r} lacks "
                                     f"{', '.join(sorted(columns - have))})")
            for statement in _SCHEMA.split(";"):
                if statement.strip():
                    c.execute(statement)
            if version < SCHEMA_VERSION:
                c.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
            c.execute("COMMIT")
        except BaseException:
            c.execute("ROLLBACK")
            raise

    def close(self) -> None:
        self._stop.set()
        if self._checkpointer is not None:
            self._checkpointer.join(timeout=5)
        with self._lock:
            self._conn.close()
            if self._writer_fd is not None:
                os.close(self._writer_fd)
                self._writer_fd = None

    @contextlib.contextmanager
    def _writer(self) -> Iterator[None]:
        """Exclusive writer across processes, taken before SQLite's own lock.

        SQLite's busy handler polls a held lock with sleeps growing to 100 ms, which shows up as
        latency spikes when several uvicorn workers write at once; a blocking ``flock`` wakes
        the next writer as soon as the lock is released. SQLite's locking stays the safety net.
        """
        with self._lock:
            if self._writer_fd is None:
                yield
                return
            import fcntl

            fcntl.flock(self._writer_fd, fcntl.LOCK_EX)
            try:
                yield
            finally:
                fcntl.flock(self._writer_fd, fcntl.LOCK_UN)

    @contextlib.contextmanager
    def transaction(self) -> Iterator[sqlite3.Connection]:
        """One write transaction (``BEGIN IMMEDIATE`` under the cross-process writer lock),
        committed when the block ends and rolled back when it raises; for the records kept
        beside the measurements (set-ups, jobs: :mod:`.setup_book`, :mod:`.jobs`)."""
        with self._writer():
            c = self._conn
            c.execute("BEGIN IMMEDIATE")
            try:
                yield c
                c.execute("COMMIT")
            except sqlite3.OperationalError as exc:
                _rollback(c)
                if _out_of_space(exc):
                    raise StoreFull(f"the store at {str(self.path)!r} cannot grow ({exc}): "
                                    "nothing was written; retry when there is room") from None
                raise
            except BaseException:
                _rollback(c)
                raise

    def rows(self, sql: str, args: Sequence[Any] = ()) -> list[tuple[Any, ...]]:
        """The rows of one read-only query."""
        with self._lock:
            return [tuple(r) for r in self._conn.execute(sql, args).fetchall()]

    # Writing ------------------------------------------------------------------------------
    def add(self, shots: Sequence[ShotRecord], result: StoredResult, source: str,
            plate_id: str | None = None, position: str | None = None,
            idempotency: tuple[str, str] | None = None,
            setup: tuple[str, int] | None = None) -> tuple[int, float]:
        """Store one measurement and its shots in one transaction; returns (id, created_at).

        ``idempotency`` (key, digest of the request) is stored in the same transaction, so a
        retry finds the measurement exactly when it was committed; a key already taken raises
        :class:`KeyTaken` and writes nothing. ``setup`` (id, revision) records the set-up
        revision it was estimated with."""
        rows = []
        for i, shot in enumerate(shots):
            dtype, digest, blob = encode_samples(shot.samples)
            rows.append((i, float(shot.t0), float(shot.dt), shot.units, shot.calibration,
                         json.dumps(shot.metadata), int(np.size(shot.samples)), dtype, CODEC,
                         digest, blob, json.dumps(shot.features)))
        result_text = json.dumps(result)
        try:
            with self.transaction() as c:
                now = time.time()
                cur = c.execute(
                    "INSERT INTO measurements (created_at, plate_id, position, n_shots, source, "
                    "result) VALUES (?, ?, ?, ?, ?, ?)",
                    (now, plate_id, position, len(rows), source, result_text))
                assert cur.lastrowid is not None  # an INSERT's row
                new_id = int(cur.lastrowid)
                c.executemany(
                    "INSERT INTO shots (measurement_id, shot_index, t0, dt, units, calibration, "
                    "metadata, n_samples, dtype, codec, sha256, samples, features) "
                    "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                    [(new_id, *row) for row in rows])
                if idempotency is not None:
                    c.execute("INSERT INTO idempotency (key, digest, measurement_id, created_at) "
                              "VALUES (?, ?, ?, ?)", (*idempotency, new_id, now))
                if setup is not None:
                    if c.execute("SELECT 1 FROM setups WHERE id = ? AND revision = ?",
                                 setup).fetchone() is None:
                        raise SetupGone(f"set-up {setup[0]!r} revision {setup[1]} is no longer "
                                        "stored (deleted meanwhile); nothing was written")
                    c.execute("INSERT INTO setup_uses (measurement_id, setup_id, revision) "
                              "VALUES (?, ?, ?)", (new_id, *setup))
        except sqlite3.IntegrityError:  # the key another request stored first
            raise KeyTaken(idempotency[0] if idempotency else "") from None
        return new_id, now

    def replace_result(self, measurement_id: int, result: StoredResult,
                       shot_features: Sequence[FeatureDict],
                       setup: tuple[str, int] | None = None) -> float:
        """Make ``result`` (and each shot's ``shot_features``) the measurement's newest, keeping
        the one it replaces in ``earlier_results``; one transaction. Returns the time.
        ``setup`` (id, revision): the set-up revision the new result used."""
        with self.transaction() as c:
            now = time.time()
            row = c.execute("SELECT result FROM measurements WHERE id = ?",
                            (measurement_id,)).fetchone()
            if row is None:
                raise StoreError(f"no measurement {measurement_id}")
            old = [r[0] for r in c.execute(
                "SELECT features FROM shots WHERE measurement_id = ? ORDER BY shot_index",
                (measurement_id,))]
            if len(old) != len(shot_features):
                raise StoreError(f"measurement {measurement_id} has {len(old)} shots, "
                                 f"got features for {len(shot_features)}")
            c.execute("INSERT INTO earlier_results (measurement_id, superseded_at, result, "
                      "shot_features) VALUES (?, ?, ?, ?)",
                      (measurement_id, now, row[0], "[" + ",".join(old) + "]"))
            c.execute("UPDATE measurements SET result = ? WHERE id = ?",
                      (json.dumps(result), measurement_id))
            c.executemany("UPDATE shots SET features = ? WHERE measurement_id = ? AND "
                          "shot_index = ?", [(json.dumps(f), measurement_id, i)
                                             for i, f in enumerate(shot_features)])
            if setup is not None:
                used = c.execute("SELECT revision FROM setup_uses WHERE measurement_id = ? "
                                 "AND setup_id = ?", (measurement_id, setup[0])).fetchone()
                if used is not None and used[0] > setup[1]:
                    raise SetupConflict(f"measurement {measurement_id} was estimated with "
                                        f"set-up {setup[0]!r} revision {used[0]}, newer than "
                                        f"{setup[1]}; its result is kept")
                c.execute("UPDATE setup_uses SET revision = ? WHERE measurement_id = ? AND "
                          "setup_id = ?", (setup[1], measurement_id, setup[0]))
        return now

    def earlier_results(self, measurement_id: int) -> list[EarlierEntry]:
        """The results a reanalysis replaced, oldest first: ``superseded_at``, ``result`` and
        ``shot_features`` (each shot's features then)."""
        with self._lock:
            rows = self._conn.execute(
                "SELECT superseded_at, result, shot_features FROM earlier_results WHERE "
                "measurement_id = ? ORDER BY superseded_at, rowid", (measurement_id,)).fetchall()
        return [{"superseded_at": r[0], "result": json.loads(r[1]),
                 "shot_features": json.loads(r[2])} for r in rows]

    def same_samples(self, digests: Sequence[str]) -> int | None:
        """The first stored measurement whose shots' samples are, in order, these (their
        :func:`samples_digest`), or None."""
        if not digests:
            return None
        with self._lock:
            candidates = [row[0] for row in self._conn.execute(
                "SELECT s.measurement_id FROM shots s JOIN measurements m ON m.id = "
                "s.measurement_id WHERE s.sha256 = ? AND s.shot_index = 0 AND m.n_shots = ? "
                "ORDER BY s.measurement_id", (digests[0], len(digests)))]
            for measurement_id in candidates:
                stored = [row[0] for row in self._conn.execute(
                    "SELECT sha256 FROM shots WHERE measurement_id = ? ORDER BY shot_index",
                    (measurement_id,))]
                if stored == list(digests):
                    return int(measurement_id)
        return None

    def idempotent(self, key: str) -> tuple[str, int] | None:
        """The request digest and measurement id stored under ``key``, or None."""
        with self._lock:
            row = self._conn.execute("SELECT digest, measurement_id FROM idempotency WHERE key = ?",
                                     (key,)).fetchone()
        return None if row is None else (str(row[0]), int(row[1]))

    def delete(self, measurement_id: int) -> bool:
        """Remove one measurement and its shots in one transaction; False when there was none."""
        with self.transaction() as c:
            c.execute("DELETE FROM shots WHERE measurement_id = ?", (measurement_id,))
            c.execute("DELETE FROM idempotency WHERE measurement_id = ?", (measurement_id,))
            c.execute("DELETE FROM setup_uses WHERE measurement_id = ?", (measurement_id,))
            gone = c.execute("DELETE FROM measurements WHERE id = ?", (measurement_id,)).rowcount
        return gone > 0

    # Reading ------------------------------------------------------------------------------
    def plates(self) -> list[PlateRow]:
        """Every plate_id with its measurement and shot counts and its last activity (Unix s);
        measurements without a plate_id are left out."""
        with self._lock:
            rows = self._conn.execute(
                "SELECT plate_id, COUNT(*), SUM(n_shots), COUNT(DISTINCT position), "
                "MAX(created_at) FROM measurements WHERE plate_id IS NOT NULL "
                "GROUP BY plate_id ORDER BY plate_id").fetchall()
        return [{"plate_id": r[0], "n_measurements": r[1], "n_shots": r[2],
                 "n_positions": r[3], "last_activity": r[4]} for r in rows]

    def all_of_plate(self, plate_id: str, limit: int) -> list[MeasurementRecord]:
        """Every measurement of ``plate_id`` in id order, at most ``limit``, each with its shots
        (their metadata and features; no samples)."""
        with self._lock:  # one read transaction: the measurements and shots of one moment
            self._conn.execute("BEGIN")
            try:
                rows, shots = self._plate_rows(plate_id, limit)
            finally:
                self._conn.execute("COMMIT")
        records = {r[0]: _measurement(r) for r in rows}
        for s in shots:
            if s[0] in records:
                records[s[0]].shots.append(ShotRecord(
                    t0=s[2], dt=s[3], samples=np.empty(0), units=s[4], calibration=s[5],
                    metadata=json.loads(s[6]), features=json.loads(s[7]), shot_index=s[1],
                    n_samples=s[8], sha256=s[9]))
        return list(records.values())

    def _plate_rows(self, plate_id: str, limit: int) -> tuple[list[Any], list[Any]]:
        rows = self._conn.execute(
            "SELECT id, created_at, plate_id, position, n_shots, source, result "
            "FROM measurements WHERE plate_id = ? ORDER BY id LIMIT ?",
            (plate_id, limit)).fetchall()
        shots = self._conn.execute(
            "SELECT s.measurement_id, s.shot_index, s.t0, s.dt, s.units, s.calibration, "
            "s.metadata, s.features, s.n_samples, s.sha256 FROM shots s JOIN measurements m "
            "ON m.id = s.measurement_id WHERE m.plate_id = ? ORDER BY s.measurement_id, "
            "s.shot_index", (plate_id,)).fetchall()
        return rows, shots

    def count(self) -> int:
        with self._lock:
            return int(self._conn.execute("SELECT COUNT(*) FROM measurements").fetchone()[0])

    def get(self, measurement_id: int, with_samples: bool = False) -> MeasurementRecord | None:
        """One measurement with its shots (and their traces when ``with_samples``)."""
        with self._lock:
            row = self._conn.execute(
                "SELECT id, created_at, plate_id, position, n_shots, source, result "
                "FROM measurements WHERE id = ?", (measurement_id,)).fetchone()
            if row is None:
                return None
            columns = ("shot_index, t0, dt, units, calibration, metadata, features, n_samples, "
                       "sha256")
            if with_samples:
                columns += ", dtype, samples, codec"
            shot_rows = self._conn.execute(
                f"SELECT {columns} FROM shots WHERE measurement_id = ? ORDER BY shot_index",
                (measurement_id,)).fetchall()
        record = _measurement(row)
        record.earlier = self.earlier_results(measurement_id)
        for s in shot_rows:
            samples = (decode_samples(s[9], s[10], s[7], s[8], s[11]) if with_samples
                       else np.empty(0))
            record.shots.append(ShotRecord(
                t0=s[1], dt=s[2], samples=samples, units=s[3], calibration=s[4],
                metadata=json.loads(s[5]), features=json.loads(s[6]), shot_index=s[0],
                n_samples=s[7], sha256=s[8]))
        return record

    def get_shot(self, measurement_id: int, shot_index: int) -> ShotRecord | None:
        with self._lock:
            s = self._conn.execute(
                "SELECT shot_index, t0, dt, units, calibration, metadata, features, n_samples, "
                "dtype, sha256, samples, codec FROM shots WHERE measurement_id = ? AND "
                "shot_index = ?",
                (measurement_id, shot_index)).fetchone()
        if s is None:
            return None
        return ShotRecord(t0=s[1], dt=s[2],
                          samples=decode_samples(s[8], s[10], s[7], s[9], s[11]),
                          units=s[3], calibration=s[4], metadata=json.loads(s[5]),
                          features=json.loads(s[6]), shot_index=s[0], sha256=s[9])

    def list(self, plate_id: str | None = None, after_id: int = 0,
             limit: int = 50) -> list[MeasurementRecord]:
        """Measurements in id order, optionally of one plate, starting after ``after_id``."""
        sql = ("SELECT id, created_at, plate_id, position, n_shots, source, result "
               "FROM measurements WHERE id > ?")
        args: list[Any] = [after_id]
        if plate_id is not None:
            sql += " AND plate_id = ?"
            args.append(plate_id)
        sql += " ORDER BY id LIMIT ?"
        args.append(limit)
        with self._lock:
            rows = self._conn.execute(sql, args).fetchall()
        return [_measurement(r) for r in rows]


def _rollback(conn: sqlite3.Connection) -> None:
    """Roll back if a transaction is still open (SQLite rolls back by itself after some I/O
    errors, and a second ROLLBACK would hide the first error)."""
    if conn.in_transaction:
        with contextlib.suppress(sqlite3.Error):
            conn.execute("ROLLBACK")


def _out_of_space(exc: BaseException) -> bool:
    """SQLite could not write: the disk is full (SQLITE_FULL), or a write failed with an I/O
    error, which is how a file-size limit (EFBIG) reaches it."""
    text = str(exc).lower()
    return "disk is full" in text or "disk i/o error" in text


def _open_writer_lock(path: Path) -> int | None:
    """File descriptor of ``<store>.writer-lock`` for :meth:`Store._writer` (None off POSIX)."""
    try:
        import fcntl  # noqa: F401  (POSIX only)
    except ImportError:
        return None
    return os.open(f"{path}.writer-lock", os.O_RDWR | os.O_CREAT, 0o600)


def _measurement(row: Sequence[Any]) -> MeasurementRecord:
    return MeasurementRecord(id=row[0], created_at=row[1], plate_id=row[2], position=row[3],
                             n_shots=row[4], source=row[5], result=json.loads(row[6]))
