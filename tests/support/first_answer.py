"""Time from the end of the install to the first answer, with an empty compiled-code cache.

Run from the repository root, after ``make run``'s or ``make test``'s install::

    .venv/bin/python tests/support/first_answer.py [--repeat 2] [--only a|b] [--sample FILE]

With another checkout's interpreter (``/elsewhere/.venv/bin/python tests/support/first_answer.py``)
it times that checkout's commands, on this checkout's table and sample file.

Two first answers, each in a fresh process pointed at a fresh, empty cache folder
(``SOLITONDE_CACHE_DIR``, see :mod:`solitonde.model.jit_cache`), so every numba kernel it needs is
compiled, as after an install or an update:

(a) ``solitonde serve --table data_samples/default_table.h5`` (what ``make run`` starts) until
    ``GET /readyz`` answers ready with the table loaded;
(b) ``solitonde analyze`` of one bundled sample file, to its exit.

Each prints the wall time, the CPU time (user + sys, of the process and the children it waited for)
and the load average when it ended: on a shared machine the wall time alone says little. A third
line per run times (b) again on the cache (a) left behind, the case of a user who started the
service first. On a fresh cache both answer with the interpreted extractor while it compiles in a
background process the command leaves running (:mod:`solitonde.signal.kernel_choice`): the CPU time
shown is the command's own, and a line per run says when the background compile ended (the next run
waits for it, not to overlap it). Not a test: it asserts nothing and is not collected by pytest.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
TABLE = ROOT / "data_samples" / "default_table.h5"
SAMPLE = ROOT / "data_samples" / "waveforms" / "synthetic_D9.53_t3.18_snr30.h5"
CLOCK = os.sysconf("SC_CLK_TCK")


def _env(cache: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_CACHE_DIR",))}
    env["SOLITONDE_CACHE_DIR"] = str(cache)
    return env


def _load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def _cpu_of(pid: int) -> float:
    """user + sys seconds of a live process and of the children it has waited for."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    utime, stime, cutime, cstime = (int(f) for f in fields[11:15])
    return (utime + stime + cutime + cstime) / CLOCK


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def serve_ready(cache: Path, work: Path, timeout: float = 600.0) -> tuple[float, float]:
    """(a): seconds from the start of ``solitonde serve`` to ``/readyz`` ready, and its CPU."""
    port = _free_port()
    cmd = [str(BIN / "solitonde"), "serve", "--port", str(port), "--table", str(TABLE),
           "--store", str(work / "store.sqlite"), "--log-level", "warning"]
    started = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=work, env=_env(cache), stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)
    try:
        while True:
            if proc.poll() is not None:
                raise RuntimeError(f"serve exited {proc.returncode}: "
                                   f"{proc.stderr.read().decode()[-2000:]}")
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/readyz", timeout=5) as r:
                    body = json.loads(r.read())
                if body.get("ready") and body.get("table_loaded"):
                    wall = time.perf_counter() - started
                    return wall, _cpu_of(proc.pid)
            except OSError:
                pass
            if time.perf_counter() - started > timeout:
                raise TimeoutError("serve not ready")
            time.sleep(0.05)
    finally:
        proc.terminate()
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def analyze_once(cache: Path, work: Path, sample: Path) -> tuple[float, float]:
    """(b): seconds and CPU of one ``solitonde analyze SAMPLE --json`` to its exit."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    done = subprocess.run([str(BIN / "solitonde"), "analyze", str(sample), "--json"], cwd=work,
                          env=_env(cache), capture_output=True, text=True)
    wall = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise RuntimeError(f"analyze exited {done.returncode}: {done.stderr[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def background_compiled(cache: Path, started: float, timeout: float = 900.0) -> float:
    """Seconds from ``started`` until the background compile has left its marker (both halves
    of the extractor in the cache) and its lock is gone; the next run must not overlap it."""
    while time.perf_counter() - started < timeout:
        if (any(cache.rglob("shot-kernels-*.compiled"))
                and not any(cache.rglob("shot-kernels-*.compiling"))):
            return time.perf_counter() - started
        time.sleep(0.2)
    raise TimeoutError("the background compile left no marker")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--sample", type=Path, default=SAMPLE)
    parser.add_argument("--only", choices=("a", "b"), help="time only (a) or only (b)")
    args = parser.parse_args()
    print(f"{BIN.parent}: cpus {os.cpu_count()}, load before {_load()}")
    names = {"a": ("serve_readyz",), "b": ("analyze",), None: ("serve_readyz", "analyze")}
    for k in range(args.repeat):
        for name in names[args.only]:
            with tempfile.TemporaryDirectory(prefix="first-answer-") as tmp:
                cache, work = Path(tmp) / "cache", Path(tmp) / "work"
                work.mkdir()
                started = time.perf_counter()
                if name == "serve_readyz":
                    wall, cpu = serve_ready(cache, work)
                    print(f"run {k + 1} (a) serve to /readyz, empty cache: wall {wall:6.2f} s, "
                          f"user+sys {cpu:6.2f} s, load {_load()}", flush=True)
                    wall, cpu = analyze_once(cache, work, args.sample)
                    print(f"run {k + 1}     analyze on the cache serve left: wall {wall:6.2f} s, "
                          f"user+sys {cpu:6.2f} s, load {_load()}", flush=True)
                else:
                    wall, cpu = analyze_once(cache, work, args.sample)
                    print(f"run {k + 1} (b) analyze {args.sample.name}, empty cache: "
                          f"wall {wall:6.2f} s, user+sys {cpu:6.2f} s, load {_load()}",
                          flush=True)
                done = background_compiled(cache, started)
                print(f"run {k + 1}     the background compile done {done:6.2f} s after the "
                      f"command started, load {_load()}", flush=True)
                if name == "analyze":
                    wall, cpu = analyze_once(cache, work, args.sample)
                    print(f"run {k + 1}     analyze again, compiled: wall {wall:6.2f} s, "
                          f"user+sys {cpu:6.2f} s, load {_load()}", flush=True)
                shutil.rmtree(cache, ignore_errors=True)


if __name__ == "__main__":
    main()
