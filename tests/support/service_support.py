"""Shared helpers for the service tests: synthetic shots with known truth, servers on free ports."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np

from solitonde.signal.synth import degrade, pulse_train

ROOT = Path(__file__).resolve().parents[2]
DT = 5e-7
INCIDENT_S, REFLECTED_S = 300e-6, 900e-6
INCIDENT_N, REFLECTED_N = 50.0, 30.0
SUPPORT_S = 115e-6
"""Full duration of the cos^6 pulses: 34.5 us at half height, the width of a 50 N solitary wave in
a chain of 9.53 mm 440C spheres (1.92 D / V_s(F)); a narrower pulse of that force and size would
be flagged implausible_units."""


def shot_samples(seed: int = 0, n: int = 4000, snr_db: float = 40.0) -> np.ndarray:
    """Incident (50 N at 300 us) and reflected (30 N at 900 us) solitary pulses, noise, 12 bits.

    True TOF 600 us, true ARR 0.6.
    """
    clean = pulse_train(n, DT, [(INCIDENT_S, INCIDENT_N, SUPPORT_S),
                                (REFLECTED_S, REFLECTED_N, SUPPORT_S)])
    return degrade(clean, snr_db, np.random.default_rng(seed), INCIDENT_N, bits=12)


def shot_json(seed: int = 0, n: int = 4000, plate_id: str = "P1", position: str = "A1",
              diameter: float = 9.53e-3, shot: int = 0, **extra: Any) -> dict[str, Any]:
    """One shot in the REST body shape."""
    body = {"t0": 0.0, "dt": DT, "samples": shot_samples(seed, n).tolist(), "units": "N",
            "metadata": {"plate_id": plate_id, "position": position,
                         "sphere_diameter": diameter, "shot": shot}}
    body.update(extra)
    return body


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_ready(url: str, proc: subprocess.Popen, timeout: float = 180.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            out = proc.stdout.read() if proc.stdout else ""
            raise RuntimeError(f"server exited with {proc.returncode}: {out}")
        try:
            if httpx.get(f"{url}/readyz", timeout=1.0).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        time.sleep(0.1)
    raise RuntimeError(f"server at {url} not ready after {timeout} s")


def start_uvicorn(store: Path, workers: int = 1, env: dict[str, str] | None = None,
                  port: int | None = None,
                  prefix: tuple[str, ...] = ()) -> tuple[subprocess.Popen, str]:
    """uvicorn running the app factory in its own process group (so killpg reaches workers);
    ``prefix`` runs it under a wrapper that execs it (``prlimit --fsize=...``)."""
    port = port or free_port()
    full_env = {k: v for k, v in os.environ.items() if not k.startswith("SOLITONDE_")}
    full_env.update({"SOLITONDE_STORE": str(store), **(env or {})})
    cmd = [*prefix, sys.executable, "-m", "uvicorn", "--factory",
           "solitonde.instrument.service.app:build_app_from_env", "--host", "127.0.0.1", "--port",
           str(port), "--workers", str(workers), "--no-access-log", "--log-level", "warning"]
    proc = subprocess.Popen(cmd, cwd=ROOT, env=full_env, start_new_session=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    url = f"http://127.0.0.1:{port}"
    try:
        wait_ready(url, proc)
    except Exception:
        stop_group(proc, signal.SIGKILL)
        raise
    return proc, url


def stop_group(proc: subprocess.Popen, sig: int = signal.SIGTERM, timeout: float = 30.0) -> int:
    """Send ``sig`` to the server's process group and wait; returns the exit code."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, sig)
    try:
        return proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        return proc.wait(timeout=timeout)


TABLE_DIAMETER = 9.53e-3
TABLE_THICKNESSES = (2.0e-3, 2.5e-3, 3.18e-3, 4.0e-3, 4.83e-3)
TABLE_DISTANCES = (0.3, 0.4)


def build_tiny_table(path: Path) -> Path:
    """A 1 x 5 x 2 model table (D 9.53 mm, t 2-4.83 mm, L 0.3-0.4 m, infinite plate): about a
    second to build, enough to exercise the estimate path end to end."""
    from solitonde.instrument.tables.table_build import Sweep, build_table

    sweep = Sweep([TABLE_DIAMETER], list(TABLE_THICKNESSES), list(TABLE_DISTANCES),
                  scene={"effects": {"plate_model": "infinite"}})
    build_table(sweep, path, workers=1)
    return path


def simulated_shots(thickness: float, n_shots: int = 3, snr_db: float = 40.0,
                    distance: float = 0.35) -> list[dict[str, Any]]:
    """Shots of the model itself at ``thickness`` (infinite plate), as an acquisition records
    them (pre-trigger, noise, 12 bits), in the REST body shape."""
    from solitonde.instrument.tables.measured import as_measured
    from solitonde.model.scene import scene_from_dict
    from solitonde.model.simulate import simulate

    scene = scene_from_dict({"chain": {"diameter": TABLE_DIAMETER},
                             "plate": {"thickness": thickness, "distance_to_support": distance},
                             "effects": {"plate_model": "infinite"}})
    result = simulate(scene)
    clean = as_measured(result)
    peak = float(result.truth["incident_peak_N"] - result.truth["static_sensor_N"])
    shots = []
    for k in range(n_shots):
        noisy = degrade(clean.samples, snr_db, np.random.default_rng(100 + k), peak, bits=12)
        shots.append({"t0": clean.t0, "dt": clean.dt, "samples": noisy.tolist(),
                      "metadata": {"plate_id": "sim", "position": "L350",
                                   "sphere_diameter": TABLE_DIAMETER, "shot": k}})
    return shots
