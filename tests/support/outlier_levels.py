"""Derive the outlier levels of ``signal/outliers.py``: per number of shots n, the modified
z-score that the largest of n good shots' scores (independent Gaussian values, one feature)
exceeds with probability ``1 - sqrt(0.99)``, so that a set read on two independent features
(TOF and ARR) loses a good shot in 1 % of sets.

    python tests/support/outlier_levels.py [--sets 1000000] [--seed 0]

Monte Carlo over ``--sets`` sets per n; prints the table the module holds (three significant
digits; the quantile's own sampling error at a million sets is about 1 %).
"""

from __future__ import annotations

import argparse

import numpy as np

from solitonde.signal.outliers import PER_FEATURE_RATE

N_MAX = 40


def largest_scores(rng: np.random.Generator, n: int, sets: int, chunk: int = 200_000) -> np.ndarray:
    """The largest modified z-score in each of ``sets`` sets of ``n`` standard normal values."""
    out = []
    for start in range(0, sets, chunk):
        x = rng.standard_normal((min(chunk, sets - start), n))
        dev = np.abs(x - np.median(x, axis=1, keepdims=True))
        out.append((0.6745 * dev / np.median(dev, axis=1, keepdims=True)).max(axis=1))
    return np.concatenate(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sets", type=int, default=1_000_000)
    parser.add_argument("--seed", type=int, default=0)
    opts = parser.parse_args()
    rng = np.random.default_rng(opts.seed)
    for n in range(4, N_MAX + 1):
        level = float(np.quantile(largest_scores(rng, n, opts.sets), 1.0 - PER_FEATURE_RATE))
        print(f"    {n}: {level:.3g},", flush=True)


if __name__ == "__main__":
    main()
