"""The store under a running server: a full disk is a 507 the client can act on, and a backup
and a check run while clients post, losing nothing.

The full disk is a file-size limit (``prlimit --fsize``) on the server process: the store's
files cannot grow past it, which SQLite meets as a failed write, exactly as on a full disk."""

from __future__ import annotations

import shutil
import subprocess
import threading
import time
from pathlib import Path

import httpx
import pytest
from service_support import shot_json, start_uvicorn, stop_group

from solitonde.instrument.service.store_admin import backup, check

FSIZE_LIMIT = 1_000_000
"""Bytes any one file of the server may reach: room for a few dozen measurements."""


def _post(client: httpx.Client, seed: int, plate: str = "full") -> httpx.Response:
    return client.post("/v1/measurements", json={"shots": [shot_json(seed, plate_id=plate)]})


@pytest.mark.skipif(shutil.which("prlimit") is None, reason="needs util-linux prlimit")
def test_a_full_store_is_a_507_reads_go_on_and_writes_resume(tmp_path: Path) -> None:
    """Post until the store cannot grow: a 507 problem+json naming the store (Retry-After), no
    half-written measurement, reads served; once the limit is lifted the next post is stored
    and the store checks ok."""
    from solitonde.instrument.service.ingest import warm_up

    warm_up()  # the kernels' cache files exist before the server runs under the limit
    store = tmp_path / "full.sqlite"
    proc, url = start_uvicorn(store, prefix=("prlimit", f"--fsize={FSIZE_LIMIT}:unlimited"))
    stored: list[int] = []
    try:
        with httpx.Client(base_url=url, timeout=60) as client:
            for seed in range(2000):
                r = _post(client, seed)
                if r.status_code != 201:
                    break
                stored.append(r.json()["id"])
            assert r.status_code == 507, r.text
            assert r.headers["content-type"].startswith("application/problem+json")
            problem = r.json()
            assert problem["status"] == 507 and problem["field"] == "store"
            assert "full.sqlite" in problem["detail"] and "nothing was written" in problem["detail"]
            assert int(r.headers["retry-after"]) > 0
            assert len(stored) >= 5
            # The same write again: a 507 while the store is full, or, where SQLite has since
            # checkpointed its log and freed pages (it does so on its own schedule, sooner under
            # load), a 201 whose measurement is stored whole (checked below with the others).
            again = _post(client, seed)
            assert again.status_code in (507, 201), again.text
            if again.status_code == 201:
                stored.append(again.json()["id"])
            page = client.get("/v1/measurements", params={"limit": 500}).json()
            assert [m["id"] for m in page["items"]] == stored  # nothing half-written
            assert client.get(f"/v1/measurements/{stored[-1]}").status_code == 200
            assert client.get("/readyz").status_code == 200

            lifted = subprocess.run(["prlimit", "--pid", str(proc.pid),
                                     "--fsize=unlimited:unlimited"], capture_output=True,
                                    text=True, timeout=30)
            assert lifted.returncode == 0, lifted.stderr
            again = _post(client, 10_002)
            assert again.status_code == 201, again.text
            stored.append(again.json()["id"])
            page = client.get("/v1/measurements", params={"limit": 500}).json()
            assert [m["id"] for m in page["items"]] == stored
    finally:
        stop_group(proc)
    report = check(store)
    print(f"\n{len(stored) - 1} stored, then 507 ({problem['detail']}); reads served; after "
          f"the limit was lifted: 201, {report['measurements']} measurements, integrity "
          f"{report['integrity']}")
    assert report["ok"], report
    assert report["measurements"] == len(stored)


def test_backup_and_check_while_8_clients_post(tmp_path: Path) -> None:
    """8 clients post while the store is backed up and checked: the backup is one consistent
    state (checks ok, between the counts before and after), and every acknowledged
    measurement is in the store afterwards."""
    store = tmp_path / "busy.sqlite"
    proc, url = start_uvicorn(store, workers=2)
    acknowledged: list[int] = []
    failures: list[str] = []
    lock = threading.Lock()
    stop = threading.Event()

    def client_loop(k: int) -> None:
        with httpx.Client(base_url=url, timeout=120) as client:
            seed = 1000 * (k + 1)  # shots of their own: not the ones posted before
            while not stop.is_set():
                seed += 1
                r = _post(client, seed, plate=f"c{k}")
                with lock:
                    if r.status_code == 201:
                        acknowledged.append(r.json()["id"])
                    else:
                        failures.append(f"{r.status_code} {r.text[:200]}")

    try:
        with httpx.Client(base_url=url, timeout=60) as client:
            for seed in range(5):
                assert _post(client, seed, plate="before").status_code == 201
        before = check(store, traces=False)["measurements"]
        threads = [threading.Thread(target=client_loop, args=(k,)) for k in range(8)]
        for t in threads:
            t.start()
        deadline = time.monotonic() + 120
        while len(acknowledged) < 40 and time.monotonic() < deadline:
            time.sleep(0.05)
        copy = backup(store, tmp_path / "backup.sqlite")
        live = check(store)
        at_backup_end = len(acknowledged) + before
        time.sleep(1.0)
        stop.set()
        for t in threads:
            t.join(timeout=120)
        with httpx.Client(base_url=url, timeout=60) as client:
            ids = [m["id"] for m in client.get("/v1/measurements",
                                               params={"limit": 500}).json()["items"]]
    finally:
        stop.set()
        stop_group(proc)
    after = check(store)
    print(f"\nmeasurements before {before}, in the backup {copy['measurements']} (taken while "
          f"{len(acknowledged)} posts went on), after {after['measurements']}; "
          f"acknowledged {before + len(acknowledged)}; backup {copy['seconds']:.3f} s")
    assert not failures, failures[:3]
    assert live["ok"] and after["ok"], (live, after)
    backup_report = check(tmp_path / "backup.sqlite")
    assert backup_report["ok"], backup_report
    assert before <= copy["measurements"] <= at_backup_end
    assert after["measurements"] == before + len(acknowledged)
    assert set(acknowledged) <= set(ids)
