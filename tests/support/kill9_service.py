"""kill -9 under load, several rounds, on one store: is every acknowledged measurement kept?

Each round starts the service (2 workers) on the same SQLite store, lets 16 clients post (JSON
shots, raw binary shots and CSV uploads, each with an Idempotency-Key) until at least
``--per-round`` measurements are acknowledged, then SIGKILLs the whole process group. After the
last round it opens the store and checks every acknowledged measurement (same samples, same
features), that nothing half-written is visible, SQLite's integrity check, and that retrying
every acknowledged request with its key after a restart returns the first id, not a new one.

    .venv/bin/python tests/support/kill9_service.py --rounds 4 --per-round 150
"""

from __future__ import annotations

import argparse
import signal
import sqlite3
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
from service_support import DT, shot_samples, start_uvicorn, stop_group  # noqa: E402

from solitonde.instrument.service.store import Store  # noqa: E402

UNEXPECTED: list[str] = []
"""Answers other than 201 (or 503 while stopping): each one fails the run."""


def request_for(k: int, seq: int) -> tuple[str, dict, np.ndarray]:
    """Client ``k``'s request number ``seq``: (kind, httpx keyword arguments, samples sent)."""
    samples = shot_samples(seed=10_000 * k + seq, n=2000).astype(np.float32).astype(np.float64)
    key = {"Idempotency-Key": str(uuid.uuid4())}
    kind = ("json", "raw", "csv")[seq % 3]
    if kind == "json":
        body = {"shots": [{"t0": 0.0, "dt": DT, "samples": samples.tolist(), "units": "N",
                           "metadata": {"plate_id": f"K{k}", "position": str(seq),
                                        "sphere_diameter": 9.53e-3}}]}
        return kind, {"url": "/v1/measurements", "json": body, "headers": key}, samples
    if kind == "raw":
        query = {"dtype": "float32", "dt": DT, "units": "N", "plate_id": f"K{k}",
                 "position": str(seq), "sphere_diameter": 9.53e-3}
        return kind, {"url": "/v1/measurements/raw", "params": query,
                      "content": samples.astype("<f4").tobytes(),
                      "headers": {**key, "content-type": "application/octet-stream"}}, samples
    rows = "".join(f"{i * DT:.9g},{float(v)!r}\n" for i, v in enumerate(samples))  # exact
    text = f"time_s,force_N\n{rows}".encode()
    return kind, {"url": "/v1/measurements", "files": {"file": (f"k{k}_{seq}.csv", text)},
                  "data": {"plate_id": f"K{k}", "position": str(seq),
                           "sphere_diameter": "0.00953"}, "headers": key}, samples


def one_round(store: Path, per_round: int, clients: int, acked: list, seq0: int) -> int:
    proc, url = start_uvicorn(store, workers=2)
    lock, stop = threading.Lock(), threading.Event()
    count = [0]

    def client(k: int) -> None:
        seq = seq0
        with httpx.Client(base_url=url, timeout=60) as http:
            while not stop.is_set():
                seq += 1
                kind, kwargs, samples = request_for(k, seq)
                try:
                    r = http.post(**kwargs)
                except httpx.HTTPError:
                    continue  # the server is gone: nothing was promised
                if r.status_code == 201:
                    with lock:
                        acked.append((r.json()["id"], kind, kwargs, samples, r.json()))
                        count[0] += 1
                elif r.status_code != 503:
                    with lock:
                        UNEXPECTED.append(f"{r.status_code}: {r.text[:200]}")

    threads = [threading.Thread(target=client, args=(k,)) for k in range(clients)]
    for t in threads:
        t.start()
    deadline = time.monotonic() + 120
    while count[0] < per_round and time.monotonic() < deadline:
        time.sleep(0.02)
    time.sleep(np.random.default_rng(seq0).uniform(0.0, 0.3))  # kill at no particular moment
    stop_group(proc, signal.SIGKILL)
    stop.set()
    for t in threads:
        t.join(timeout=90)
    return count[0]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--rounds", type=int, default=4)
    p.add_argument("--per-round", type=int, default=150)
    p.add_argument("--clients", type=int, default=16)
    args = p.parse_args()
    store_path = Path(tempfile.mkdtemp(prefix="solitonde-kill9-")) / "store.sqlite"
    acked: list = []
    for r in range(args.rounds):
        n = one_round(store_path, args.per_round, args.clients, acked, 1000 * r)
        print(f"round {r + 1}: {n} acknowledged, then kill -9")

    store = Store(store_path, background_checkpoint=False)
    missing = differ = 0
    try:
        for mid, _kind, _kwargs, samples, answer in acked:
            record = store.get(mid, with_samples=True)
            if record is None:
                missing += 1
                continue
            shot = record.shots[0]
            if not (np.array_equal(shot.samples, samples)
                    and shot.features == answer["shots"][0]["features"]):
                differ += 1
        partial = sum(1 for rec in store.list(limit=10**6)
                      if len(store.get(rec.id, with_samples=True).shots) != rec.n_shots)
        stored = store.count()
    finally:
        store.close()
    with sqlite3.connect(store_path) as conn:
        integrity = conn.execute("PRAGMA integrity_check").fetchone()[0]
    print(f"{len(acked)} acknowledged over {args.rounds} rounds "
          f"({', '.join(f'{k} {sum(a[1] == k for a in acked)}' for k in ('json', 'raw', 'csv'))})"
          f"; missing {missing}, different {differ}; {stored} stored, {partial} half-written; "
          f"integrity_check {integrity}")

    proc, url = start_uvicorn(store_path, workers=2)
    try:
        replayed_same = 0
        with httpx.Client(base_url=url, timeout=60) as http:
            for mid, _kind, kwargs, _samples, _answer in acked:
                r = http.post(**kwargs)
                replayed_same += (r.status_code == 201 and r.json()["id"] == mid
                                  and r.headers.get("Idempotent-Replayed") == "true")
    finally:
        stop_group(proc)
    store = Store(store_path, background_checkpoint=False)
    try:
        after = store.count()
    finally:
        store.close()
    print(f"retried every acknowledged request with its key after a restart: {replayed_same} of "
          f"{len(acked)} answered with the first id (Idempotent-Replayed); measurements stored "
          f"{stored} before, {after} after")
    if UNEXPECTED:
        print(f"{len(UNEXPECTED)} unexpected answers, the first: {UNEXPECTED[0]}")
    ok = (missing == differ == partial == 0 and integrity == "ok" and not UNEXPECTED
          and replayed_same == len(acked) and after == stored)
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
