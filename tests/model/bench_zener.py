"""Benchmark: e and tau_c for 10,000 lambdas, fast path against a loop of scipy solve_ivp calls.

Run with ``.venv/bin/python -m pytest -m bench -s tests/model/bench_zener.py``. Prints figures;
asserts only accuracy, never time.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from solitonde.model import zener as z

N_LAMBDAS = 10_000
N_BASELINE = 200  # solve_ivp calls actually timed; the 10,000 figure is extrapolated from them


def _best_of(fn, repeats: int = 5) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


@pytest.mark.bench
def test_bench_restitution_many():
    """10,000 lambdas uniform in [0, 20]: table fast path vs solve_ivp per lambda."""
    lams = np.linspace(0.0, 20.0, N_LAMBDAS)
    start = time.perf_counter()
    z._table.cache_clear()
    z.restitution_and_contact_time_many(lams[:1])  # read the shipped table
    warm = time.perf_counter() - start
    start = time.perf_counter()
    z.build_table()  # numba load (compile when not cached) + a fresh build
    rebuild = time.perf_counter() - start
    t_fast = _best_of(lambda: z.restitution_and_contact_time_many(lams))
    e_fast, tau_fast = z.restitution_and_contact_time_many(lams)

    sample = lams[:: N_LAMBDAS // N_BASELINE]  # same lambda distribution as the 10,000
    # The compiled DOP853 alone (what builds the table and serves lambdas above 20).
    t_compiled = _best_of(lambda: z._integrate_compiled(sample), repeats=3)
    rows = {}
    for label, rtol in (("rtol 1e-12, same accuracy", 1e-12), ("rtol 1e-7, looser", 1e-7)):
        start = time.perf_counter()
        res = np.array([z.restitution_and_contact_time(lam, rtol=rtol) for lam in sample])
        rows[label] = (time.perf_counter() - start, res)
    ref = rows["rtol 1e-12, same accuracy"][1]
    idx = np.arange(0, N_LAMBDAS, N_LAMBDAS // N_BASELINE)
    err_fast = max(np.max(np.abs(e_fast[idx] / ref[:, 0] - 1)),
                   np.max(np.abs(tau_fast[idx] / ref[:, 1] - 1)))

    print(f"\nZener e, tau_c for {N_LAMBDAS} lambdas in [0, 20]")
    print(f"  first read of the shipped Chebyshev table:       {warm * 1e3:8.1f} ms (once)")
    print(f"  rebuilding it (numba cache load + integration):  {rebuild * 1e3:8.1f} ms")
    print(f"  fast path (table), best of 5:                      {t_fast * 1e3:8.3f} ms"
          f"   max rel. error vs reference {err_fast:.1e}")
    print(f"  compiled DOP853 (no table), {sample.size} lambdas:       {t_compiled * 1e3:8.1f} ms"
          f" -> {t_compiled / sample.size * N_LAMBDAS:6.2f} s per {N_LAMBDAS} (extrapolated)")
    for label, (elapsed, res) in rows.items():
        per_10k = elapsed / sample.size * N_LAMBDAS
        err = max(np.max(np.abs(res[:, 0] / ref[:, 0] - 1)),
                  np.max(np.abs(res[:, 1] / ref[:, 1] - 1)))
        print(f"  solve_ivp DOP853 {label}: {sample.size} calls {elapsed:6.2f} s ->"
              f" {per_10k:7.1f} s per {N_LAMBDAS} (extrapolated), ratio {per_10k / t_fast:,.0f}x"
              + (f", max rel. error {err:.1e}" if err > 0 else " (the reference)"))
    assert err_fast < 1e-8
