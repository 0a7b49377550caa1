"""Per-shot time of feature extraction, this checkout against another, alternately.

    .venv/bin/python tests/support/extract_speed.py /other/checkout/.venv/bin/python [--rounds 4]

Runs the same timing (the best of 15 repeats over 100 noisy 10,000-sample shots, on one core:
``extract_many`` per shot and ``extract_batch``) with each interpreter in turn, ``--rounds``
times, and prints every round and the ratio of the best times (other / this: above 1 means this
checkout is faster). Alternating rounds and best-of-repeats keep a shared machine's load out of
the ratio as far as possible. Not a test: it asserts nothing and is not collected by pytest.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys

TIMING = r"""
import os, time
import numpy as np
if hasattr(os, "sched_setaffinity"):
    os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
import numba
numba.set_num_threads(1)
import solitonde.instrument  # the checkout's compiled-code cache folder
from solitonde.signal.batch import extract_batch
from solitonde.signal.features import extract_many
from solitonde.signal.synth import degrade, pulse_train
from solitonde.signal.waveform import Waveform
N, DT, SHOTS = 10_000, 1e-7, 100
rng = np.random.default_rng(0)
shots = []
for _ in range(SHOTS):
    tof = rng.uniform(400e-6, 600e-6)
    x = pulse_train(N, DT, [(150e-6, 30.0, 90e-6), (150e-6 + tof, 15.0, 95e-6)])
    shots.append(Waveform(0.0, DT, degrade(x, 30.0, rng, 30.0, drift=0.02, bits=12)))
block = np.stack([w.samples for w in shots])
extract_many(shots[:3])
extract_batch(block[:3], DT)

def best(fn, repeats=15):
    b = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        b = min(b, time.perf_counter() - t)
    return b / SHOTS * 1e6

print(best(lambda: extract_many(shots)), best(lambda: extract_batch(block, DT)))
"""


def _time(python: str) -> tuple[float, float]:
    out = subprocess.run([python, "-c", TIMING], capture_output=True, text=True, check=True)
    per_shot, batch = (float(v) for v in out.stdout.split()[-2:])
    return per_shot, batch


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("other", help="the other checkout's Python interpreter")
    parser.add_argument("--rounds", type=int, default=4)
    args = parser.parse_args()
    best = {"this": [float("inf")] * 2, "other": [float("inf")] * 2}
    for k in range(args.rounds):
        for name, python in (("other", args.other), ("this", sys.executable)):
            times = _time(python)
            best[name] = [min(a, b) for a, b in zip(best[name], times, strict=True)]
            load = " ".join(f"{x:.2f}" for x in os.getloadavg())
            print(f"round {k + 1} {name:5s}: per shot {times[0]:6.1f} us, batch {times[1]:6.1f} "
                  f"us per shot, load {load}", flush=True)
    for i, what in enumerate(("per shot (extract_many)", "batch (extract_batch)")):
        print(f"best {what}: this {best['this'][i]:.1f} us, other {best['other'][i]:.1f} us, "
              f"speed ratio this/other {best['other'][i] / best['this'][i]:.3f}")


if __name__ == "__main__":
    main()
