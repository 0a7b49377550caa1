"""Load generator for the instrument service: async httpx clients posting shots on loopback.

Prints requests per second and p50/p99 latency for ``POST /v1/measurements`` with one
10,000-sample shot per request (the acquisition-PC pattern), and the same for ``GET /healthz`` as
a same-run baseline of what the server and the client cost without any work. The shot goes as
JSON (default) or as its raw float32 samples (``--body binary``, ``application/octet-stream``).

    .venv/bin/python tests/support/load_service.py                      # starts its own server
    .venv/bin/python tests/support/load_service.py --workers 2 --requests 4000
    .venv/bin/python tests/support/load_service.py --workers 2 --client raw --body binary
    .venv/bin/python tests/support/load_service.py --url http://127.0.0.1:8000

Bounded: stops after ``--requests`` requests or ``--duration`` seconds, whichever comes first.
Only loopback addresses are accepted.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from urllib.parse import urlencode, urlparse

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
LOOPBACK = ("127.0.0.1", "localhost", "::1")


def synthetic_shot(n: int = 10_000, dt: float = 5e-7, seed: int = 0) -> dict:
    """A shot like a recorded one: incident and reflected solitary pulses, noise, 12-bit steps.

    Pulse shape: the long-wave solitary wave's force profile cos^4 over about five diameters
    (Nesterenko), here 20 us wide; incident peak 50 N at 150 us, reflection 0.6 of it 330 us
    later; 0.2 N of noise; quantised to 12 bits over +-100 N.
    """
    rng = np.random.default_rng(seed)
    t = dt * np.arange(n)

    def pulse(centre: float, peak: float, width: float = 20e-6) -> np.ndarray:
        phase = np.clip((t - centre) / width * np.pi, -np.pi / 2, np.pi / 2)
        return peak * np.cos(phase) ** 4

    y = pulse(150e-6, 50.0) + pulse(480e-6, 30.0) + rng.normal(0.0, 0.2, n)
    lsb = 200.0 / 4096
    y = np.round(y / lsb) * lsb
    return {"t0": 0.0, "dt": dt, "samples": [round(float(v), 4) for v in y], "units": "N",
            "metadata": {"plate_id": "load", "position": "P1", "sphere_diameter": 9.53e-3,
                         "shot": 0}}


def shot_request(n: int = 10_000, body: str = "json") -> tuple[str, bytes, str]:
    """(path, body, content type) of one synthetic shot sent as JSON or as raw float32."""
    shot = synthetic_shot(n)
    if body == "json":
        return "/v1/measurements", json.dumps({"shots": [shot]}).encode(), "application/json"
    meta = shot["metadata"]
    query = urlencode({"dtype": "float32", "dt": shot["dt"], "t0": shot["t0"],
                       "units": shot["units"], **meta})
    samples = np.asarray(shot["samples"], dtype="<f4")  # an acquisition PC's float32 buffer
    return f"/v1/measurements/raw?{query}", samples.tobytes(), "application/octet-stream"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def group_cpu_seconds(pgid: int) -> float | None:
    """CPU seconds (user + system) used so far by the processes of a process group (Linux).

    The server's own CPU per request, unlike its throughput, does not depend on what else the
    machine is running: with it, the capacity of a quiet machine can be stated honestly.
    """
    total = 0.0
    tick = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
    proc = Path("/proc")
    if not proc.is_dir():
        return None
    for entry in proc.iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rpartition(")")[2].split()
        except OSError:
            continue
        # after the command: state ppid pgrp session ... utime(12) stime(13)
        if int(fields[2]) == pgid:
            total += (int(fields[11]) + int(fields[12])) / tick
    return total


def start_server(workers: int, store: Path, extra_env: dict[str, str] | None = None,
                 port: int | None = None) -> tuple[subprocess.Popen, str]:
    """uvicorn running the app factory on a free loopback port; returns (process, url)."""
    port = port or free_port()
    env = {**os.environ, "SOLITONDE_STORE": str(store), **(extra_env or {})}
    env.pop("SOLITONDE_TABLE", None) if "SOLITONDE_TABLE" not in (extra_env or {}) else None
    cmd = [sys.executable, "-m", "uvicorn", "--factory",
           "solitonde.instrument.service.app:build_app_from_env", "--host", "127.0.0.1",
           "--port", str(port), "--workers", str(workers), "--no-access-log",
           "--log-level", "warning"]
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, start_new_session=True)
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"server exited with {proc.returncode}")
        try:
            if httpx.get(f"{url}/readyz", timeout=1.0).status_code == 200:
                return proc, url
        except httpx.HTTPError:
            pass
        time.sleep(0.1)
    proc.kill()
    raise RuntimeError("server did not become ready in 60 s")


class RawClient:
    """Minimal HTTP/1.1 keep-alive client on asyncio streams (Content-Length bodies only).

    httpx costs about 2 ms of client CPU per request here, as much as the server's work; on a
    2-core machine the client then measures itself. This client costs a few percent of that, so
    ``--client raw`` shows what the server sustains. Same requests, same bytes on the wire.
    """

    def __init__(self, url: str) -> None:
        parsed = urlparse(url)
        self.host, self.port = parsed.hostname or "127.0.0.1", parsed.port or 80
        self._pool: list[tuple[asyncio.StreamReader, asyncio.StreamWriter]] = []

    async def connect(self) -> None:
        """Open one keep-alive connection now and use it once (``GET /healthz``)."""
        self._pool.append(await asyncio.open_connection(self.host, self.port))
        await self.request("GET", "/healthz", None, {})

    async def request(self, method: str, path: str, body: bytes | None,
                      headers: dict[str, str]) -> int:
        conn = self._pool.pop() if self._pool else await asyncio.open_connection(
            self.host, self.port)
        reader, writer = conn
        lines = [f"{method} {path} HTTP/1.1", f"Host: {self.host}:{self.port}"]
        lines += [f"{k}: {v}" for k, v in headers.items()]
        if body is not None:
            lines.append(f"Content-Length: {len(body)}")
        writer.write(("\r\n".join(lines) + "\r\n\r\n").encode() + (body or b""))
        head = await reader.readuntil(b"\r\n\r\n")
        status = int(head[9:12])
        length = 0
        keep = True
        for line in head.split(b"\r\n")[1:]:
            name, _, value = line.partition(b":")
            name = name.strip().lower()
            if name == b"content-length":
                length = int(value)
            elif name == b"transfer-encoding":
                raise RuntimeError("chunked responses are not supported by the raw client")
            elif name == b"connection" and value.strip().lower() == b"close":
                keep = False
        await reader.readexactly(length)
        if keep:
            self._pool.append(conn)
        else:
            writer.close()
        return status

    async def aclose(self) -> None:
        for _, writer in self._pool:
            writer.close()
        self._pool.clear()


async def run_load(url: str, path: str, body: bytes | None, concurrency: int, requests: int,
                   duration: float, headers: dict[str, str] | None = None,
                   client_kind: str = "httpx", content_type: str = "application/json") -> dict:
    """Fire ``requests`` requests (or for ``duration`` s) from ``concurrency`` clients."""
    host = urlparse(url).hostname
    if host not in LOOPBACK:
        raise SystemExit(f"refusing to load {host}: loopback only ({', '.join(LOOPBACK)})")
    if client_kind == "raw":
        return await _run_raw(url, path, body, concurrency, requests, duration, headers or {},
                              content_type)
    latencies: list[float] = []
    statuses: dict[int, int] = {}
    errors = 0
    issued = 0
    limits = httpx.Limits(max_connections=concurrency, max_keepalive_connections=concurrency)
    hdrs = {"content-type": content_type, **(headers or {})}
    async with httpx.AsyncClient(base_url=url, limits=limits, timeout=30.0) as client:
        start = time.perf_counter()
        stop_at = start + duration

        async def worker() -> None:
            nonlocal issued, errors
            while issued < requests and time.perf_counter() < stop_at:
                issued += 1
                t = time.perf_counter()
                try:
                    if body is None:
                        r = await client.get(path, headers=headers)
                    else:
                        r = await client.post(path, content=body, headers=hdrs)
                except httpx.HTTPError:
                    errors += 1
                    continue
                latencies.append(time.perf_counter() - t)
                statuses[r.status_code] = statuses.get(r.status_code, 0) + 1

        await asyncio.gather(*(worker() for _ in range(concurrency)))
        elapsed = time.perf_counter() - start
    return _summary(path, concurrency, latencies, statuses, errors, elapsed)


async def _run_raw(url: str, path: str, body: bytes | None, concurrency: int, requests: int,
                   duration: float, headers: dict[str, str],
                   content_type: str = "application/json") -> dict:
    latencies: list[float] = []
    statuses: dict[int, int] = {}
    errors = 0
    issued = 0
    hdrs = dict(headers)
    if body is not None:
        hdrs["Content-Type"] = content_type
    clients = [RawClient(url) for _ in range(concurrency)]
    # Connections opened one after another before the clock starts, as clients that come up at
    # different times would; TCP setup stays out of the latencies. Which uvicorn worker accepts
    # each is the kernel's choice: a burst of 16 simultaneous connects went mostly to one of two
    # workers (2/14 splits seen), one after another they spread better, though not always.
    for c in clients:
        await c.connect()
    start = time.perf_counter()
    stop_at = start + duration

    async def worker(client: RawClient) -> None:
        nonlocal issued, errors
        while issued < requests and time.perf_counter() < stop_at:
            issued += 1
            t = time.perf_counter()
            try:
                status = await client.request("POST" if body is not None else "GET", path,
                                              body, hdrs)
            except (OSError, asyncio.IncompleteReadError, ValueError):
                errors += 1
                continue
            latencies.append(time.perf_counter() - t)
            statuses[status] = statuses.get(status, 0) + 1

    await asyncio.gather(*(worker(c) for c in clients))
    elapsed = time.perf_counter() - start
    for c in clients:
        await c.aclose()
    return _summary(path, concurrency, latencies, statuses, errors, elapsed)


def _summary(path: str, concurrency: int, latencies: list[float], statuses: dict[int, int],
             errors: int, elapsed: float) -> dict:
    lat = np.array(latencies) * 1e3
    ok = sum(v for k, v in statuses.items() if 200 <= k < 300)
    return {
        "path": path, "concurrency": concurrency, "requests": len(latencies), "ok": ok,
        "errors": errors, "statuses": {str(k): v for k, v in sorted(statuses.items())},
        "elapsed_s": elapsed, "rps": ok / elapsed if elapsed > 0 else 0.0,
        "p50_ms": float(np.percentile(lat, 50)) if lat.size else float("nan"),
        "p99_ms": float(np.percentile(lat, 99)) if lat.size else float("nan"),
        "max_ms": float(lat.max()) if lat.size else float("nan"),
    }


def report(result: dict, label: str) -> str:
    return (f"{label:<28} {result['rps']:8.1f} req/s   p50 {result['p50_ms']:6.2f} ms   "
            f"p99 {result['p99_ms']:6.2f} ms   max {result['max_ms']:7.2f} ms   "
            f"({result['ok']}/{result['requests']} ok, {result['errors']} errors, "
            f"{result['elapsed_s']:.1f} s)")


def cpu_line(load: dict) -> str:
    """CPU per request and what it means for a machine with nothing else running."""
    server = load.get("server_cpu_ms")
    client = load["client_cpu_ms"]
    text = f"CPU per request: client {client:.2f} ms"
    if server:
        cores = os.cpu_count() or 1
        text += (f", server {server:.2f} ms (all workers); {cores} idle cores would sustain "
                 f"about {cores / (server + client) * 1e3:.0f} req/s")
    if load.get("loadavg_1min") is not None:
        text += f"; load average during the run {load['loadavg_1min']:.1f}"
    return text


def measure(url: str, args: argparse.Namespace, server_pgid: int | None = None) -> dict:
    """Warm up, then the baseline (healthz) and the measurement load.

    With ``server_pgid`` (a server started in its own session), also the server's CPU time per
    measurement request and the client's own.
    """
    body_kind = getattr(args, "body", "json")
    path, body, ctype = shot_request(args.samples, body_kind)
    headers = {"X-API-Key": args.api_key} if args.api_key else None
    kind = args.client
    asyncio.run(run_load(url, path, body, args.concurrency, args.warmup, 30.0, headers, kind,
                         ctype))
    base = asyncio.run(run_load(url, "/healthz", None, args.concurrency, args.requests,
                                args.duration, headers, kind))
    cpu0 = group_cpu_seconds(server_pgid) if server_pgid else None
    own0 = os.times()
    load = asyncio.run(run_load(url, path, body, args.concurrency, args.requests,
                                args.duration, headers, kind, ctype))
    own1 = os.times()
    n = max(load["requests"], 1)
    load["client_cpu_ms"] = (own1.user - own0.user + own1.system - own0.system) / n * 1e3
    if cpu0 is not None:
        cpu1 = group_cpu_seconds(server_pgid)
        load["server_cpu_ms"] = (cpu1 - cpu0) / n * 1e3 if cpu1 is not None else None
    load["loadavg_1min"] = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    return {"baseline": base, "measurements": load, "body_bytes": len(body),
            "body": body_kind, "samples": args.samples, "workers": args.workers, "client": kind}


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--url", help="running service (default: start one)")
    p.add_argument("--workers", type=int, default=1, help="uvicorn workers when starting one")
    p.add_argument("--concurrency", type=int, default=16)
    p.add_argument("--requests", type=int, default=3000)
    p.add_argument("--duration", type=float, default=20.0, help="seconds, at most")
    p.add_argument("--warmup", type=int, default=200)
    p.add_argument("--samples", type=int, default=10_000)
    p.add_argument("--client", choices=("httpx", "raw"), default="httpx",
                   help="httpx.AsyncClient, or a minimal asyncio HTTP/1.1 client (less CPU)")
    p.add_argument("--body", choices=("json", "binary"), default="json",
                   help="the shot as JSON, or as raw float32 samples (application/octet-stream)")
    p.add_argument("--api-key", default=os.environ.get("SOLITONDE_API_KEY"))
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    args = p.parse_args(argv)
    args.requests = min(args.requests, 100_000)
    args.duration = min(args.duration, 300.0)

    proc = None
    tmp = None
    url = args.url
    if url is None:
        tmp = tempfile.TemporaryDirectory(prefix="solitonde-load-")
        proc, url = start_server(args.workers, Path(tmp.name) / "load.sqlite")
    try:
        result = measure(url, args, proc.pid if proc is not None else None)
    finally:
        if proc is not None:
            proc.terminate()
            proc.wait(timeout=30)
        if tmp is not None:
            tmp.cleanup()
    what = "JSON" if args.body == "json" else "float32, application/octet-stream"
    print(f"POST /v1/measurements, one {args.samples:,}-sample shot ({result['body_bytes']:,} "
          f"bytes of {what}), {args.concurrency} concurrent clients ({args.client}), "
          f"{args.workers} worker(s), {os.cpu_count()} cores")
    print(report(result["baseline"], "GET /healthz (baseline)"))
    print(report(result["measurements"], "POST /v1/measurements"))
    ratio = result["measurements"]["rps"] / max(result["baseline"]["rps"], 1e-9)
    print(f"ratio measurements/baseline throughput: {ratio:.3f}")
    print(cpu_line(result["measurements"]))
    result["ratio"] = ratio
    if args.json:
        print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
