"""The on-disk queue of `solitonde watch`: which file versions are waiting, sent, or refused.

One JSON document, ``queue.json`` in the state folder, rewritten whole to a temporary name and
renamed over the old one after every change (fsynced), so a crash or a power cut leaves either
the old queue or the new one, never half of one. A file version is its path relative to the
watched folder with its size and modification time; its content's SHA-256 tells a touched file
from a changed one. A lock file keeps two watchers off one state folder.
"""

from __future__ import annotations

import contextlib
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from solitonde.instrument.errors import MessageError
from solitonde.signal.atomic import write_text

QUEUED, DONE, FAILED = "queued", "done", "failed"
VERSION = 1


@dataclass
class Entry:
    """One file version in the queue."""

    size: int
    mtime_ns: int
    sha256: str
    fields: dict[str, Any]
    seq: int
    state: str = QUEUED
    attempts: int = 0
    id: int | None = None
    error: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)


class QueueLocked(MessageError, RuntimeError):
    """Another `watch` holds this state folder."""

    subject = "--state"


class Queue:
    """The queue of one state folder; :meth:`save` after each change."""

    def __init__(self, state: Path) -> None:
        self.state = state
        self.path = state / "queue.json"
        state.mkdir(parents=True, exist_ok=True)
        self._lock = self._take_lock(state / "lock")
        self.entries: dict[str, Entry] = {}
        if self.path.exists():
            doc = json.loads(self.path.read_text())
            if doc.get("version") != VERSION:
                raise ValueError(f"{self.path}: queue version {doc.get('version')!r}; this "
                                 f"watch reads version {VERSION}")
            self.entries = {rel: Entry(**e) for rel, e in doc["files"].items()}

    @staticmethod
    def _take_lock(path: Path) -> Any:
        """An exclusive lock on ``path`` held while the file stays open (flock on POSIX, a
        byte-range lock on Windows, where acquisition PCs often run)."""
        fh = path.open("a+")
        try:
            try:
                import fcntl
            except ImportError:  # Windows
                import msvcrt

                fh.seek(0)
                msvcrt.locking(fh.fileno(), msvcrt.LK_NBLCK, 1)  # type: ignore[attr-defined]
            else:
                fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            fh.close()
            raise QueueLocked(f"--state: {path.parent} is in use by another watch") from None
        return fh

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self._lock.close()

    def next_seq(self) -> int:
        return 1 + max((e.seq for e in self.entries.values()), default=0)

    def waiting(self) -> list[tuple[str, Entry]]:
        """Queued versions, oldest first."""
        return sorted(((rel, e) for rel, e in self.entries.items() if e.state == QUEUED),
                      key=lambda item: item[1].seq)

    def save(self) -> None:
        doc = {"version": VERSION, "files": {rel: asdict(e) for rel, e in self.entries.items()}}
        write_text(self.path, json.dumps(doc, indent=1, sort_keys=True), durable=True)
