"""`solitonde watch`: post each new waveform file in a folder once, when it is complete.

The scope (or DAQ) saves into a folder; `watch` looks at it every ``--poll`` seconds. A file is
complete when its size and modification time have not changed for ``--settle`` seconds, which
covers a file written slowly in parts as well as the scope's write-then-rename (a renamed file is
complete at once and settles). A complete file is hashed and put in a queue on disk
(instrument.cli.watch_queue) before anything is sent, then posted as `solitonde post` does, with
the ``Idempotency-Key`` of its content and metadata:

- the server down: the queue waits, retried with a doubling pause up to ``--max-backoff``;
- `watch` stopped (SIGTERM, Ctrl-C) or killed, and started again: the queue is read back; a file
  that was sent but not yet marked is sent again and the server replays the first answer, so
  nothing is lost and nothing is stored twice;
- a file touched but unchanged is not sent again; a file rewritten with new content is a new
  version and is sent.

SIGTERM or Ctrl-C lets the file being sent finish, saves the queue and exits 0. One status line
per file (queued, stored or replayed with its id and estimate, failed with the server's reason);
the server's refusal of the API key (401/403) stops `watch` with exit code 1, its queue kept.
"""

from __future__ import annotations

import hashlib
import random
import signal
import threading
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import typer

from solitonde.instrument.cli.cmd_post import (
    ALLOW_DUPLICATE,
    API_KEY_ENV,
    CALIBRATION,
    CHANNEL,
    FORMAT,
    GROUP,
    MANIFEST,
    MATERIAL,
    PLATE_ID,
    POSITION,
    SAMPLE_RATE,
    SERVER,
    SETUP,
    SPHERE,
    TABLE,
    UNITS,
    UploadForm,
    X,
    Y,
    given_fields,
    load_manifest,
)
from solitonde.instrument.cli.uploader import (
    Client,
    api_key_from,
    fields_for,
    manifest_row_for,
    status_line,
)
from solitonde.instrument.cli.watch_queue import DONE, FAILED, Entry, Queue, QueueLocked

STATE_NAME = ".solitonde-watch"


def say(text: str) -> None:
    """A status line, flushed at once (a log or a pipe sees it when it happens)."""
    typer.echo(text)


class Watcher:
    """One watched folder, its queue and its client; :meth:`step` does one round."""

    def __init__(self, folder: Path, queue: Queue, client: Client, given: UploadForm,
                 rows: list[Any], base: Path | None, pattern: str | None, settle_s: float,
                 max_backoff_s: float, stop: threading.Event) -> None:
        self.folder, self.queue, self.client = folder, queue, client
        self.given, self.rows, self.base, self.pattern = given, rows, base, pattern
        self.settle_s, self.max_backoff_s, self.stop = settle_s, max_backoff_s, stop
        self.observed: dict[str, tuple[int, int, float]] = {}
        self.server_wait_until = 0.0
        self.server_failures = 0
        self.fatal: str | None = None

    def candidates(self) -> list[Path]:
        """Files of the folder that match, the state folder and dot files left out."""
        from solitonde.signal.formats.registry import EXTENSIONS  # what the upload reads

        found = self.folder.rglob(self.pattern) if self.pattern else self.folder.rglob("*")
        out = []
        for p in found:
            rel = p.relative_to(self.folder)
            if any(part.startswith(".") for part in rel.parts) or not p.is_file():
                continue
            if self.queue.state in p.parents:
                continue
            if self.pattern is None and p.suffix.lower() not in EXTENSIONS:
                continue
            out.append(p)
        return sorted(out)

    def scan(self) -> None:
        """Queue every file version that has settled and is not in the queue yet."""
        now = time.monotonic()
        seen = set()
        for path in self.candidates():
            rel = path.relative_to(self.folder).as_posix()
            seen.add(rel)
            try:
                st = path.stat()
            except OSError:  # gone meanwhile
                continue
            version = (st.st_size, st.st_mtime_ns)
            entry = self.queue.entries.get(rel)
            if entry is not None and (entry.size, entry.mtime_ns) == version:
                continue
            obs = self.observed.get(rel)
            if obs is None or obs[:2] != version:
                self.observed[rel] = (*version, now)
                continue
            if now - obs[2] < self.settle_s or st.st_size == 0:
                continue
            self._enqueue(rel, path, version, entry)
            self.observed.pop(rel, None)
        for rel in set(self.observed) - seen:
            del self.observed[rel]

    def _enqueue(self, rel: str, path: Path, version: tuple[int, int],
                 old: Entry | None) -> None:
        try:
            content = path.read_bytes()
        except OSError:
            return
        if (path.stat().st_size, path.stat().st_mtime_ns) != version:
            return  # written to while read: observe again
        sha = hashlib.sha256(content).hexdigest()
        if old is not None and old.sha256 == sha:  # touched, not changed
            old.size, old.mtime_ns = version
            self.queue.save()
            return
        row = (manifest_row_for(self.rows, self.base, path)
               if self.rows and self.base is not None else None)
        entry = Entry(*version, sha, {}, self.queue.next_seq())
        if self.rows and row is None:
            entry.state, entry.error = FAILED, "no row of --manifest matches it"
        else:
            try:
                entry.fields = fields_for(self.given, row)
            except ValueError as exc:
                entry.state, entry.error = FAILED, str(exc)
        self.queue.entries[rel] = entry
        self.queue.save()
        if entry.state == FAILED:
            say(f"failed: {rel}: {entry.error}")
        else:
            say(f"queued: {rel}" + (" (a new version)" if old is not None else ""))

    def send(self) -> None:
        """Post the waiting versions, oldest first, until the server stops answering."""
        if time.monotonic() < self.server_wait_until:
            return
        for rel, entry in self.queue.waiting():
            if self.stop.is_set():
                return
            path = self.folder / rel
            try:
                st = path.stat()
            except OSError:
                entry.state, entry.error = FAILED, "the file was removed before it was sent"
                self.queue.save()
                say(f"failed: {rel}: {entry.error}")
                continue
            if (st.st_size, st.st_mtime_ns) != (entry.size, entry.mtime_ns):
                continue  # changed since it was queued: scan queues the new version
            outcome = self.client.upload(path, entry.fields)
            outcome.source = rel
            entry.attempts += 1
            if outcome.ok:
                entry.state, entry.error = DONE, None
                answer: Mapping[str, Any] = outcome.measurement or {}
                entry.id = answer.get("id")
                self.server_failures = 0
                self.queue.save()
                say(status_line(outcome))
                continue
            if outcome.transient:
                self.server_failures += 1
                wait = min(self.max_backoff_s, 2.0 ** (self.server_failures - 1))
                wait *= random.uniform(0.8, 1.0)  # watchers of one lab do not retry in step
                self.server_wait_until = time.monotonic() + wait
                entry.error = outcome.error
                self.queue.save()
                say(f"waiting: {rel}: {outcome.error}; retry in {wait:.1f} s "
                    f"({len(self.queue.waiting())} queued)")
                return
            if outcome.status_code in (401, 403):
                self.fatal = f"{rel}: {outcome.error} (see --api-key-env)"
                self.queue.save()
                return
            entry.state, entry.error = FAILED, outcome.error
            self.queue.save()
            say(status_line(outcome))

    def idle(self) -> bool:
        """Nothing observed that may still settle, nothing waiting."""
        return not self.observed and not self.queue.waiting()


def watch(
    folder: Path = typer.Argument(..., help="The folder the scope saves into (watched "
                                  "recursively).", show_default=False),
    server: str = SERVER,
    api_key_env: str = API_KEY_ENV,
    plate_id: str | None = PLATE_ID,
    position: str | None = POSITION,
    x: float | None = X,
    y: float | None = Y,
    sphere_diameter: float | None = SPHERE,
    calibration: float | None = CALIBRATION,
    units: str | None = UNITS,
    sample_rate: float | None = SAMPLE_RATE,
    fmt: str | None = FORMAT,
    channel: str | None = CHANNEL,
    group: str | None = GROUP,
    plate_material: str | None = MATERIAL,
    table: str | None = TABLE,
    allow_duplicate: bool = ALLOW_DUPLICATE,
    setup: str | None = SETUP,
    manifest: Path | None = MANIFEST,
    pattern: str | None = typer.Option(None, "--pattern", help="Glob of the files to post, "
                                       "e.g. '*.csv' (default: every file the upload reads)."),
    state: Path | None = typer.Option(None, "--state", help="Folder for the queue (default: "
                                      f"FOLDER/{STATE_NAME})."),
    settle: float = typer.Option(2.0, "--settle", min=0.0, max=3600.0, help="s a file's size "
                                 "and time must stay unchanged before it is complete."),
    poll: float = typer.Option(0.5, "--poll", min=0.05, max=60.0, help="s between looks at the "
                               "folder."),
    max_backoff: float = typer.Option(60.0, "--max-backoff", min=1.0, max=3600.0, help="s, the "
                                      "longest pause between retries while the server is "
                                      "down."),
    once: bool = typer.Option(False, "--once", help="Exit when every file present has been "
                              "sent or refused (for a scheduled job) instead of watching on."),
) -> None:
    """Post every new waveform file in a folder once it is complete; a queue on disk survives
    outages and restarts."""

    def usage(message: str) -> None:
        typer.echo(f"error: {message}", err=True)
        raise typer.Exit(code=2)

    if not folder.is_dir():
        usage(f"FOLDER: no such folder: {folder}")
    try:
        given = given_fields(plate_id, position, x, y, sphere_diameter, calibration, units,
                             sample_rate, fmt, channel, group, plate_material, table,
                             allow_duplicate, setup)
        rows = load_manifest(manifest)
    except typer.BadParameter as exc:
        usage(f"{exc.param_hint}: {exc.message}")
        return
    try:
        queue = Queue(state or folder / STATE_NAME)
    except (QueueLocked, ValueError, OSError) as exc:
        usage(str(exc) if not isinstance(exc, OSError) else f"--state: {exc}")
        return
    stop = threading.Event()

    def on_signal(signum: int, _frame: Any) -> None:
        if not stop.is_set():
            say(f"stopping ({signal.Signals(signum).name}): the file being sent finishes")
        stop.set()

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGTERM, signal.SIGINT)}
    waiting = len(queue.waiting())
    say(f"watching {folder} -> {server}" + (f" ({waiting} queued from before)" if waiting
                                             else ""))
    try:
        with Client(server, api_key_from(api_key_env)) as client:
            w = Watcher(folder, queue, client, given, rows,
                        manifest.parent if manifest is not None else None, pattern, settle,
                        max_backoff, stop)
            while not stop.is_set():
                w.scan()
                w.send()
                if w.fatal:
                    typer.echo(f"error: the server refuses this client: {w.fatal}", err=True)
                    raise typer.Exit(code=1)
                if once and w.idle():
                    break
                stop.wait(poll)
    finally:
        queue.save()
        queue.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    failed = sum(e.state == FAILED for e in queue.entries.values())
    raise typer.Exit(code=1 if once and failed else 0)


def register(app: typer.Typer) -> None:
    """Add `watch` to the CLI."""
    app.command("watch")(watch)
