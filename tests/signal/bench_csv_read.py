"""Benchmark: reading a large scope CSV costs about what parsing its numbers costs.

Prints the time of ``signal.io.read`` on a 2,000,000-row Tektronix-style CSV against
``pandas.read_csv`` of the same data block (the C parser alone, no layout detection, no checks),
measured in the same run. Run with ``-m bench -s``.
"""

from __future__ import annotations

import io as _io
import time

import numpy as np
import pandas as pd
import pytest

from solitonde.signal import io

pytestmark = pytest.mark.bench
ROWS = 2_000_000


def test_large_scope_csv_reads_near_the_parsers_own_speed(tmp_path):
    t = -1e-4 + 5e-7 * np.arange(ROWS)
    v = 0.1 * np.sin(t * 1e4) + 1e-3 * np.random.default_rng(0).standard_normal(ROWS)
    head = "Model,MSO54\r\nHorizontal Units,s\r\nVertical Units,V\r\nLabel,\r\nTIME,CH1\r\n"
    buf = _io.StringIO()
    np.savetxt(buf, np.column_stack([t, v]), delimiter=",", fmt="%.10e", newline="\r\n")
    data = buf.getvalue()
    path = tmp_path / "big.csv"
    path.write_text(head + data, newline="")
    best_read = best_pandas = np.inf
    for _ in range(3):
        started = time.perf_counter()
        (wave,) = io.read(path, calibration=10.0)
        best_read = min(best_read, time.perf_counter() - started)
        started = time.perf_counter()
        pd.read_csv(_io.StringIO(path.read_text()[len(head):]), header=None, dtype=np.float64)
        best_pandas = min(best_pandas, time.perf_counter() - started)
    assert wave.n == ROWS
    size = path.stat().st_size / 1e6
    print(f"\n{size:.0f} MB, {ROWS:,} rows: signal.io.read {best_read:.2f} s, pandas.read_csv of "
          f"the data block {best_pandas:.2f} s, ratio {best_read / best_pandas:.2f} (best of 3)")
