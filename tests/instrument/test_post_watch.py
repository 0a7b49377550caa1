"""`solitonde post` and `solitonde watch` against a real uvicorn server process.

post: the same file posted twice is one measurement, the second answer a replay. watch: files
written while the server is down (one written slowly, in parts), watch stopped with SIGTERM and
started again after the server came up: every file is stored exactly once and whole; a file sent
whose mark was lost (a crash between the answer and the queue's save) is replayed, not stored
again.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import h5py
import httpx
import pytest
from service_support import free_port, start_uvicorn, stop_group

from solitonde.instrument.cli.uploader import idempotency_key
from solitonde.signal import io as signal_io

ROOT = Path(__file__).resolve().parents[2]
WAVES = ROOT / "data_samples" / "waveforms"
CSV = WAVES / "synthetic_D9.53_t4.83_snr40.csv"
NPY = WAVES / "synthetic_D9.53_t2.29_snr40.npy"
H5 = WAVES / "synthetic_D9.53_t3.18_snr30.h5"


def _cli(*args: str, **kw) -> list[str]:
    return [sys.executable, "-m", "solitonde.instrument.cli.main", *args]


def _env() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if not k.startswith("SOLITONDE_")}


def _items(url: str) -> list[dict]:
    return httpx.get(f"{url}/v1/measurements", params={"limit": 500}, timeout=30).json()["items"]


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    proc, url = start_uvicorn(tmp_path_factory.mktemp("post") / "store.sqlite")
    try:
        yield url
    finally:
        stop_group(proc)


def test_the_key_follows_the_content_the_name_and_the_metadata():
    """Same file and fields: same key; any change in one of them: another key."""
    base = idempotency_key(b"1,2,3", "a.csv", {"plate_id": "P", "x_m": 0.1})
    assert base == idempotency_key(b"1,2,3", "a.csv", {"x_m": 0.1, "plate_id": "P"})
    assert len({base, idempotency_key(b"1,2,4", "a.csv", {"plate_id": "P", "x_m": 0.1}),
                idempotency_key(b"1,2,3", "b.csv", {"plate_id": "P", "x_m": 0.1}),
                idempotency_key(b"1,2,3", "a.csv", {"plate_id": "P", "x_m": 0.2}),
                idempotency_key(b"1,2,3", "a.csv", {"plate_id": "Q", "x_m": 0.1})}) == 5


def test_post_twice_stores_one_measurement_and_the_second_answer_is_a_replay(server, tmp_path):
    """Two runs of `solitonde post` on the same file: one measurement; the second says replayed
    with the same id."""
    args = _cli("post", str(CSV), "--server", server, "--plate-id", "P-POST", "--position",
                "A1", "--x", "0.1", "--y", "0.02", "--sphere-diameter", "9.53e-3", "--json")
    answers = []
    for _ in range(2):
        run = subprocess.run(args, capture_output=True, text=True, env=_env(), cwd=tmp_path,
                             timeout=120)
        assert run.returncode == 0, run.stderr
        answers.append(json.loads(run.stdout))
    assert [a["state"] for a in answers] == ["stored", "replayed"]
    assert answers[0]["id"] == answers[1]["id"] and answers[0]["n_shots"] == 2
    mine = [m for m in _items(server) if m["plate_id"] == "P-POST"]
    assert len(mine) == 1 and mine[0]["id"] == answers[0]["id"]
    # The status lines say the same in words.
    text = subprocess.run(args[:-1], capture_output=True, text=True, env=_env(), timeout=120)
    assert text.returncode == 0 and text.stdout.startswith(f"replayed: {CSV} -> measurement "
                                                            f"{answers[0]['id']} (2 shots")


def test_post_the_same_shots_under_other_metadata_are_a_duplicate_and_a_refusal_exits_1(
        server, tmp_path):
    """The same file under another plate id: the server holds its shots already, and says so
    (``duplicate``, the stored measurement's id, what the metadata says otherwise) rather than
    storing them twice; a file the server refuses is reported and exits 1."""
    bad = tmp_path / "empty.csv"
    bad.write_text("time_s,force_N\n")
    run = subprocess.run(_cli("post", str(CSV), str(bad), "--server", server, "--plate-id",
                              "P-OTHER", "--json"), capture_output=True, text=True, env=_env(),
                         timeout=120)
    assert run.returncode == 1
    good, refused = (json.loads(line) for line in run.stdout.splitlines())
    assert good["state"] == "duplicate" and good["duplicate_of"] == good["id"]
    assert {"shot": 0, "key": "plate_id", "stored": good["plate_id"], "sent": "P-OTHER"} in \
        good["metadata_differences"]
    assert refused["state"] == "refused" and refused["status_code"] == 422, refused


def test_post_usage_errors_exit_2_naming_the_flag(tmp_path):
    from typer.testing import CliRunner

    from solitonde.instrument.cli.main import build_app

    def post(*args: str):
        return CliRunner().invoke(build_app(), ["post", *args])

    for args, expected in ((["--units", "mV"], "--units: 'mV' is not N or V"),
                           (["--calibration", "-1"], "--calibration: -1 must be > 0")):
        run = post(str(CSV), "--server", "http://127.0.0.1:9", *args)
        assert run.exit_code == 2 and expected in run.output, run.output
    run = post(str(tmp_path / "nope.csv"), "--server", "http://x")
    assert run.exit_code == 2 and "no such file or folder" in run.output
    run = post(str(CSV), "--server", f"http://127.0.0.1:{free_port()}")
    assert run.exit_code == 1 and f"not sent: {CSV}: " in run.output, run.output


def _write_slowly(target: Path, data: bytes, parts: int, pause_s: float) -> None:
    """The file grows in ``parts`` writes ``pause_s`` apart, as a slow scope saves it."""
    step = -(-len(data) // parts)
    with target.open("wb") as fh:
        for k in range(parts):
            fh.write(data[k * step:(k + 1) * step])
            fh.flush()
            os.fsync(fh.fileno())
            if k < parts - 1:
                time.sleep(pause_s)


def _reader(proc: subprocess.Popen, lines: list[str]) -> threading.Thread:
    """Collect the watcher's stdout lines into ``lines`` as they come."""
    def run() -> None:
        for line in proc.stdout:
            lines.append(line.rstrip("\n"))

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def _wait_for(proc: subprocess.Popen, lines: list[str], predicate, timeout: float) -> None:
    """Wait until ``predicate(lines)`` holds."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate(list(lines)):
            return
        if proc.poll() is not None:
            break
        time.sleep(0.1)
    raise AssertionError(f"watch did not get there in {timeout} s; it said: {lines}")


def test_watch_stores_every_file_exactly_once_through_an_outage_and_a_restart(tmp_path):
    """Files written while the server is down, one slowly in parts; SIGTERM; the server
    started; watch started again: each file stored once, the slow one whole."""
    folder, state = tmp_path / "scope", tmp_path / "state"
    folder.mkdir()
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    args = _cli("watch", str(folder), "--server", url, "--state", str(state), "--plate-id",
                "P-WATCH", "--settle", "1.5", "--poll", "0.2", "--max-backoff", "2")
    watcher = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                               env=_env())
    lines: list[str] = []
    reader = _reader(watcher, lines)
    try:
        shutil.copy(NPY, folder / "shot_b.npy")
        (folder / "sub").mkdir()
        # The scope's write-then-rename: the temporary name is a dot file, never posted.
        shutil.copy(H5, folder / "sub" / ".shot_c.h5.part")
        os.replace(folder / "sub" / ".shot_c.h5.part", folder / "sub" / "shot_c.h5")
        # Four parts 0.6 s apart: the file keeps changing for 1.8 s, longer than --settle.
        _write_slowly(folder / "shot_a.csv", CSV.read_bytes(), parts=4, pause_s=0.6)
        _wait_for(watcher, lines, lambda ls: sum(s.startswith("queued: ") for s in ls) == 3
                  and any(s.startswith("waiting: ") for s in ls), timeout=120)
        watcher.send_signal(signal.SIGTERM)
        watcher.wait(timeout=60)
        reader.join(timeout=10)
    finally:
        if watcher.poll() is None:
            watcher.kill()
            watcher.wait()
    assert watcher.returncode == 0, lines
    assert any(s.startswith("stopping (SIGTERM)") for s in lines), lines
    assert not any(s.startswith(("stored: ", "replayed: ")) for s in lines)
    queued = sorted(s.split(": ", 1)[1] for s in lines if s.startswith("queued: "))
    assert queued == ["shot_a.csv", "shot_b.npy", "sub/shot_c.h5"], lines

    proc, url = start_uvicorn(tmp_path / "store.sqlite", port=port)
    try:
        run = subprocess.run([*args, "--once"], capture_output=True, text=True, env=_env(),
                             timeout=180)
        assert run.returncode == 0, run.stdout + run.stderr
        assert "(3 queued from before)" in run.stdout.splitlines()[0]
        assert sorted(s.split(": ")[1].split(" ->")[0] for s in run.stdout.splitlines()
                      if s.startswith("stored: ")) == queued, run.stdout
        items = _items(url)
        assert len(items) == 3 and {m["plate_id"] for m in items} == {"P-WATCH"}
        by_source = {m["source"]: m for m in items}
        assert sorted(by_source) == sorted(f"upload:{f}" for f in ("csv", "npy", "hdf5")), \
            by_source
        # The slow file was sent whole: the stored shots have every sample of the file.
        whole = [w.n for w in signal_io.read(CSV)]
        stored = httpx.get(f"{url}/v1/measurements/{by_source['upload:csv']['id']}",
                           timeout=30).json()
        assert [s["n_samples"] for s in stored["shots"]] == whole

        # A third run finds nothing new; a touched file is not sent again.
        os.utime(folder / "shot_b.npy")
        again = subprocess.run([*args, "--once"], capture_output=True, text=True, env=_env(),
                               timeout=180)
        assert again.returncode == 0 and again.stdout.splitlines()[1:] == [], again.stdout
        # A crash between the server's answer and the queue's save: the entry still queued.
        doc = json.loads((state / "queue.json").read_text())
        doc["files"]["shot_a.csv"]["state"] = "queued"
        (state / "queue.json").write_text(json.dumps(doc))
        crash = subprocess.run([*args, "--once"], capture_output=True, text=True, env=_env(),
                               timeout=180)
        assert crash.returncode == 0
        assert f"replayed: shot_a.csv -> measurement {by_source['upload:csv']['id']} " \
            in crash.stdout, crash.stdout
        # New content under an old name is a new version, stored once; the same samples
        # under a new name (or a file changed only in its text) are not stored twice.
        shutil.copy(NPY, folder / "shot_a.csv.npy")
        shutil.copy(CSV, folder / "shot_a.csv")
        with (folder / "shot_a.csv").open("a") as fh:
            fh.write("\n")
        shutil.copy(H5, folder / "shot_d.h5")
        with h5py.File(folder / "shot_d.h5", "r+") as fh:  # one sample of one shot changed
            samples = fh["shots/shot_000"]
            samples[0] = samples[0] + 1.0
        time.sleep(0.05)
        last = subprocess.run([*args, "--once"], capture_output=True, text=True, env=_env(),
                              timeout=180)
        assert last.returncode == 0, last.stdout
        dup = sorted(s.split(": ")[1].split(" ->")[0] for s in last.stdout.splitlines()
                     if s.startswith("duplicate: "))
        assert dup == ["shot_a.csv", "shot_a.csv.npy"], last.stdout
        assert len(_items(url)) == 4
    finally:
        stop_group(proc)


def test_two_watchers_cannot_share_a_state_folder(tmp_path):
    from solitonde.instrument.cli.watch_queue import Queue, QueueLocked

    first = Queue(tmp_path / "state")
    try:
        with pytest.raises(QueueLocked, match="in use by another watch"):
            Queue(tmp_path / "state")
    finally:
        first.close()
