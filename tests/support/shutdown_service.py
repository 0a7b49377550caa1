"""How the service behaves when clients leave and when it is stopped (prints seconds).

Starts ``solitonde serve`` twice on loopback:

1. posts a 47 MB CSV and sends SIGTERM 1.5 s later, while the file is being read;
2. stores a 1.99 M-sample shot, times one plot of it, fires eleven plot requests that give up
   after 50 ms (the clients leave while their plots wait), times a plot after them, fires eleven
   more and sends SIGTERM.

    .venv/bin/python tests/support/shutdown_service.py
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
from service_support import free_port, shot_json, wait_ready  # noqa: E402


def start(store: Path) -> tuple[subprocess.Popen, str]:
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("SOLITONDE_")}
    env["SOLITONDE_STORE"] = str(store)
    proc = subprocess.Popen([str(ROOT / ".venv" / "bin" / "solitonde"), "serve", "--port",
                             str(port), "--log-level", "warning"], env=env,
                            start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}"
    wait_ready(url, proc, timeout=60)
    return proc, url


def terminate(proc: subprocess.Popen) -> tuple[float, int | str]:
    """SIGTERM the server's process group; seconds until it exited, and its exit code."""
    began = time.monotonic()
    os.killpg(proc.pid, signal.SIGTERM)
    try:
        code = proc.wait(timeout=60)
        return time.monotonic() - began, code
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        return 60.0, "killed after 60 s"


def abandon_plots(url: str, path: str, n: int = 11) -> None:
    for _ in range(n):
        with contextlib.suppress(httpx.TimeoutException):
            httpx.get(f"{url}{path}", timeout=0.05)


def main() -> None:
    work = Path(tempfile.mkdtemp(prefix="solitonde-shutdown-"))
    big = work / "big.csv"
    t = np.arange(1_900_000) * 5e-7
    with big.open("w") as fh:
        fh.write("time_s,force_N\n")
        np.savetxt(fh, np.column_stack([t, np.sin(t * 1e4)]), delimiter=",", fmt="%.12g")
    print(f"CSV of {big.stat().st_size / 1e6:.1f} MB")

    proc, url = start(work / "upload.sqlite")

    answer: list[str] = []

    def post() -> None:
        try:
            with big.open("rb") as fh:
                r = httpx.post(f"{url}/v1/measurements", files={"file": ("big.csv", fh)},
                               timeout=60)
            answer.append(f"{r.status_code} after {time.monotonic() - sent:.2f} s")
        except httpx.HTTPError as exc:
            answer.append(f"{type(exc).__name__} after {time.monotonic() - sent:.2f} s")

    sent = time.monotonic()
    poster = threading.Thread(target=post, daemon=True)
    poster.start()
    time.sleep(1.0)
    print(f"upload answered before SIGTERM: {answer or 'no'}")
    seconds, code = terminate(proc)
    print(f"SIGTERM during the upload: exit after {seconds:.2f} s, code {code}")
    poster.join(timeout=30)
    print(f"the upload's client got: {answer}")

    proc, url = start(work / "plots.sqlite")
    r = httpx.post(f"{url}/v1/measurements", json={"shots": [shot_json(n=1_990_000)]}, timeout=60)
    path = f"/v1/measurements/{r.json()['id']}/plot.png"
    start_s = time.monotonic()
    httpx.get(f"{url}{path}", timeout=60)
    print(f"one plot of a 1.99 M-sample shot: {time.monotonic() - start_s:.2f} s")
    abandon_plots(url, path)
    start_s = time.monotonic()
    httpx.get(f"{url}{path}", timeout=120)
    print(f"a plot right after 11 abandoned ones: {time.monotonic() - start_s:.2f} s")
    abandon_plots(url, path)
    seconds, code = terminate(proc)
    print(f"SIGTERM with abandoned plots queued: exit after {seconds:.2f} s, code {code}")


if __name__ == "__main__":
    main()
