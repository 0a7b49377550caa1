"""The service's set-ups: every revision kept in the store, immutable once written.

A revision is written in one transaction with the next number for its id (``BEGIN IMMEDIATE``
serialises concurrent writers across worker processes, so two revisions never share a number).
A measurement records the revision it used (``setup_uses``); a set-up some measurement names
cannot be deleted.
"""

from __future__ import annotations

import json
import time
from typing import TypedDict

from solitonde.instrument.inference.setups import Setup
from solitonde.instrument.service.store import SetupConflict, Store


def add_revision(store: Store, setup: Setup, based_on: int | None = None) -> Setup:
    """Store ``setup`` as the next revision of its id (1 for a new id); the stored revision.

    ``based_on``: the revision the change was made from (0: a new set-up). Where another
    revision came first meanwhile, SetupConflict and nothing is written: a calibration and a
    revision sent at once never drop one another's change."""
    with store.transaction() as c:
        row = c.execute("SELECT MAX(revision) FROM setups WHERE id = ?", (setup.id,)).fetchone()
        newest = int(row[0] or 0)
        if based_on is not None and newest != based_on:
            raise SetupConflict(
                f"set-up {setup.id!r} exists (revision {newest}); PUT /v1/setups/{{id}} makes a "
                "new revision" if based_on == 0 else
                f"set-up {setup.id!r} has revision {newest} now; this change was based on "
                f"revision {based_on}: read it again and resend")
        revision = newest + 1
        stored = Setup.from_dict({**setup.to_dict(), "revision": revision,
                                  "created_at": time.time()})
        c.execute("INSERT INTO setups (id, revision, created_at, body) VALUES (?, ?, ?, ?)",
                  (stored.id, revision, stored.created_at, json.dumps(stored.to_dict())))
    return stored


def keep(store: Store, setup: Setup) -> None:
    """Store ``setup`` under its own revision number, as read from a file (a report's
    temporary store of an offline analysis, so that it names the lab's set-up as it is)."""
    with store.transaction() as c:
        c.execute("INSERT OR REPLACE INTO setups (id, revision, created_at, body) VALUES "
                  "(?, ?, ?, ?)", (setup.id, setup.revision, setup.created_at or 0.0,
                                   json.dumps(setup.to_dict())))


def revision(store: Store, setup_id: str, number: int | None = None) -> Setup | None:
    """Revision ``number`` of a set-up (None: the newest), or None when there is none."""
    if number is None:
        rows = store.rows("SELECT body FROM setups WHERE id = ? ORDER BY revision DESC LIMIT 1",
                          (setup_id,))
    else:
        rows = store.rows("SELECT body FROM setups WHERE id = ? AND revision = ?",
                          (setup_id, number))
    return Setup.from_dict(json.loads(rows[0][0])) if rows else None


class RevisionLine(TypedDict):
    """One revision in a set-up's list: its number, time, and its calibration's origin."""

    revision: int
    created_at: float
    calibrated: bool
    calibration_source: str | None
    """The calibration's ``kind`` (``file``, ``references``), or None."""


def revisions(store: Store, setup_id: str) -> list[RevisionLine]:
    """Every revision of a set-up, oldest first: number, time, whether it is calibrated and
    where the calibration came from."""
    out: list[RevisionLine] = []
    for number, created, body in store.rows(
            "SELECT revision, created_at, body FROM setups WHERE id = ? ORDER BY revision",
            (setup_id,)):
        data = json.loads(body)
        out.append({"revision": number, "created_at": created,
                    "calibrated": data.get("chain_calibration") is not None,
                    "calibration_source": (data.get("calibration_source") or {}).get("kind")})
    return out


def newest(store: Store) -> list[Setup]:
    """The newest revision of every set-up, by id."""
    rows = store.rows("SELECT s.body FROM setups s JOIN (SELECT id, MAX(revision) AS r FROM "
                      "setups GROUP BY id) n ON s.id = n.id AND s.revision = n.r ORDER BY s.id")
    return [Setup.from_dict(json.loads(r[0])) for r in rows]


def users(store: Store, setup_id: str) -> list[tuple[int, int]]:
    """(measurement id, revision) of every measurement estimated with this set-up."""
    return [(int(m), int(r)) for m, r in store.rows(
        "SELECT measurement_id, revision FROM setup_uses WHERE setup_id = ? ORDER BY "
        "measurement_id", (setup_id,))]


def delete(store: Store, setup_id: str) -> bool:
    """Remove every revision of a set-up no measurement names; False when there was none.
    The caller checks :func:`users` first; this checks again inside the transaction and
    raises ValueError when one appeared meanwhile."""
    with store.transaction() as c:
        used = c.execute("SELECT COUNT(*) FROM setup_uses WHERE setup_id = ?",
                         (setup_id,)).fetchone()[0]
        if used:
            raise ValueError(f"{used} measurements name set-up {setup_id!r}")
        gone = c.execute("DELETE FROM setups WHERE id = ?", (setup_id,)).rowcount
    return gone > 0
