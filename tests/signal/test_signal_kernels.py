"""The fast building blocks of signal.kernels give exactly what the plain formulas give.

Detection results are kept bit for bit by the speed-ups (vectorised extrema, one running sum
shared by every smoother, two running sums in one loop, the peak search skipping quiet blocks),
so each is checked here for equality, not closeness, against the straightforward version.
"""

from __future__ import annotations

import numpy as np
import pytest

from solitonde.signal import kernels as K
from solitonde.signal.robust import heapsort


def _peaks_reference(v: np.ndarray, thr: float, delta: float) -> list[int]:
    """Billauer's peakdet with a floor, one sample at a time (what find_peaks_hysteresis does)."""
    out, seeking_max, cur, icur = [], True, v[0], 0
    for i in range(1, v.size):
        x = v[i]
        if seeking_max:
            if x > cur:
                cur, icur = x, i
            elif x < cur - delta:
                if cur > thr:
                    out.append(icur)
                    seeking_max = False
                cur, icur = x, i
        elif x < cur:
            cur, icur = x, i
        elif x > cur + delta:
            seeking_max, cur, icur = True, x, i
    if seeking_max and cur > thr:
        out.append(icur)
    return out


@pytest.mark.parametrize("n", [1, 2, 7, 64, 1001])
def test_extrema_equal_numpy(n):
    rng = np.random.default_rng(n)
    for x in (rng.normal(size=n), np.round(rng.normal(size=n)), np.full(n, -3.0)):
        assert K.vmax(x) == x.max()
        assert K.vmin(x) == x.min()
        assert K.vargmax(x) == int(np.argmax(x))  # first of equal maxima, as numpy
        assert K.vargmin(x) == int(np.argmin(x))


@pytest.mark.parametrize("n", [40, 41, 333, 5000])
@pytest.mark.parametrize("h", [0, 1, 2, 7, 20, 45])
def test_shared_running_sum_smoothers_equal_triangle(n, h):
    x = np.cumsum(np.random.default_rng(n + h).normal(size=n)) + 1e3
    c, s = K.prefix_and_triangle(x, h)
    np.testing.assert_array_equal(c, K.prefix_sum(x))
    np.testing.assert_array_equal(c[1:], np.cumsum(x))
    np.testing.assert_array_equal(s, K.triangle(x, h))
    np.testing.assert_array_equal(K.triangle_prefix(x, c, h, 1.0), K.triangle(x, h))
    np.testing.assert_array_equal(K.triangle_prefix(x, c, h, -1.0), K.triangle(-x, h))


def test_triangle_is_the_moving_average_twice():
    x = np.random.default_rng(3).normal(size=300)
    h = 4
    box = np.convolve(x, np.ones(2 * h + 1) / (2 * h + 1), mode="same")
    twice = np.convolve(box, np.ones(2 * h + 1) / (2 * h + 1), mode="same")
    inner = slice(2 * h, x.size - 2 * h)  # away from the shrinking ends
    np.testing.assert_allclose(K.triangle(x, h)[inner], twice[inner], rtol=0, atol=1e-13)


@pytest.mark.parametrize("seed", range(6))
def test_peak_search_with_block_skipping_equals_the_sample_walk(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(20, 4000))
    v = K.triangle(np.cumsum(rng.normal(size=n)), int(rng.integers(0, 30)))
    if seed % 2:
        v = np.round(v)  # ties at the band edges
    for thr, delta in ((0.0, 0.5), (np.median(v), 2.0), (v.max() - 1.0, 5.0)):
        assert K.find_peaks_hysteresis(v, thr, delta).tolist() == _peaks_reference(v, thr, delta)


def test_trend_fit_is_least_squares_on_the_quiet_samples():
    n = 2000
    rng = np.random.default_rng(7)
    ramp = np.arange(n) / n
    y = 3.0 - 2.0 * ramp + 5.0 * ramp**2 + rng.normal(0, 0.01, n)
    mask = np.ones(n, dtype=np.bool_)
    mask[300:700] = False
    mask[1500:1510] = False
    runs = np.array([[0, 300], [700, 1500], [1510, n]])
    coef, count = K.quadratic_fit(y, runs, 2)
    expected = np.polynomial.polynomial.polyfit(ramp[mask], y[mask], 2)
    assert count == mask.sum()
    np.testing.assert_allclose(coef, expected, rtol=1e-9, atol=1e-11)


@pytest.mark.parametrize("seed", range(8))
def test_quiet_runs_are_the_samples_outside_every_window(seed):
    """Windows may overlap, nest, start before 0 or end past n; the runs are what a mask says."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 3000))
    centres = np.sort(rng.integers(0, n, size=int(rng.integers(0, 6))))
    reach = rng.integers(0, n // 2 + 2, size=centres.size)
    mask = np.ones(n, dtype=np.bool_)
    for c, r in zip(centres, reach, strict=True):
        mask[max(0, c - r) : c + r + 1] = False
    runs = K.quiet_runs(centres, reach, n)
    rebuilt = np.zeros(n, dtype=np.bool_)
    for a, b in runs:
        assert 0 <= a < b <= n
        rebuilt[a:b] = True
    np.testing.assert_array_equal(rebuilt, mask)
    assert np.all(runs[1:, 0] > runs[:-1, 1])  # in order, none touching
    lo, hi = sorted(rng.integers(0, n + 1, size=2))
    assert K.run_count(runs, lo, hi) == mask[lo:hi].sum()


def _organ_pipe(n: int) -> np.ndarray:
    """Rising then falling: the median of three picks a near-extreme pivot round after round."""
    return np.concatenate([np.arange(n // 2), np.arange(n - n // 2)[::-1]]).astype(float)


@pytest.mark.parametrize("n", [1, 2, 3, 4, 7, 16, 17, 33, 64, 513, 1112, 4097])
def test_median_equals_numpy_on_noise_ties_flat_and_sorted_input(n):
    rng = np.random.default_rng(n)
    cases = [rng.normal(size=n), np.round(rng.normal(size=n)), np.full(n, -2.5),
             np.sort(rng.normal(size=n)), np.sort(rng.normal(size=n))[::-1],
             np.repeat(rng.normal(size=3), n)[:n], np.round(rng.normal(size=n) * 30.0) / 4096,
             _organ_pipe(n)]
    for x in cases:
        before = x.copy()
        assert K.median(x) == np.median(x)
        read_only = x.view()
        read_only.setflags(write=False)  # the kernels' samples are read-only
        assert K.median(read_only) == np.median(x)
        ranked = np.sort(x)
        for k in {0, n // 3, n // 2, n - 1, int(rng.integers(0, n))}:
            assert K.kth_smallest(x, k) == ranked[k]
        np.testing.assert_array_equal(x, before)  # only read


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf, 1.0000001e12, -1.7e308])
def test_first_invalid_finds_the_first_bad_sample(bad):
    x = np.random.default_rng(1).normal(size=(5, 200))
    x[0, :4] = (1e12, -1e12, 5e-324, -0.0)  # extreme but allowed
    assert K.first_invalid(x) == -1
    x[3, 17] = bad
    x[4, 2] = bad
    assert K.first_invalid(x) == 3 * 200 + 17
    assert K.first_invalid(x[3]) == 17


def test_huge_samples_are_refused_not_crashing_the_kernel():
    """Sums of 1e305-sized samples overflow inside the kernel (it crashed): refused up front,
    one shot at a time and in a batch, naming the sample."""
    from solitonde.signal.batch import extract_batch
    from solitonde.signal.errors import WaveformError
    from solitonde.signal.waveform import Waveform

    x = np.r_[np.zeros(2000), np.full(2000, 1e305)]
    with pytest.raises(WaveformError, match=r"samples: a value of magnitude beyond 1e\+12 .* "
                                            r"at sample 2000"):
        Waveform(0.0, 5e-7, x)
    with pytest.raises(WaveformError, match="shot 1, sample 2000"):
        extract_batch(np.stack([np.zeros(4000), x]), 5e-7)
    with pytest.raises(WaveformError, match="NaN or inf"):
        Waveform(0.0, 5e-7, np.r_[x[:100], np.nan])


@pytest.mark.parametrize("m", [1, 3, 4])
def test_spd_solve_matches_numpy_and_refuses_indefinite_systems(m):
    rng = np.random.default_rng(m)
    j = rng.normal(size=(20, m))
    a = j.T @ j + 1e-3 * np.eye(m)
    b = rng.normal(size=m)
    x = np.empty(m)
    assert K.solve_spd(a.copy(), b, x)
    np.testing.assert_allclose(x, np.linalg.solve(a, b), rtol=1e-10)
    indefinite = a.copy()
    indefinite[m - 1, m - 1] = -1.0
    assert not K.solve_spd(indefinite, b, x)
    assert not K.solve_spd(np.zeros((m, m)), b, x)


@pytest.mark.parametrize("m", [1, 2, 3])
def test_lu_solve_matches_numpy_with_its_determinant(m):
    """The least-squares fits' small solver: the solution and determinant LAPACK gives, also
    where the first pivot is zero (rows swapped), and 0 for a singular system."""
    rng = np.random.default_rng(m)
    a = rng.normal(size=(m, m))
    if m > 1:
        a[0, 0] = 0.0
    b = rng.normal(size=m)
    x = np.empty(m)
    det = K.solve_lu(a.copy(), b.copy(), x)
    np.testing.assert_allclose(x, np.linalg.solve(a, b), rtol=1e-12)
    assert det == pytest.approx(np.linalg.det(a), rel=1e-12)
    assert K.solve_lu(np.zeros((m, m)), b.copy(), x) == 0.0


@pytest.mark.parametrize("n", [0, 1, 2, 5, 64, 1001])
def test_heapsort_sorts_a_range_in_place(n):
    """select's fallback (after SELECT_ROUNDS partitions) sorts what is left: any range, ties
    and sorted or reversed input included, the rest of the array untouched."""
    rng = np.random.default_rng(n)
    for x in (rng.normal(size=n + 6), np.round(rng.normal(size=n + 6)), np.arange(n + 6.0)[::-1]):
        a = x.copy()
        heapsort(a, 3, 3 + n)
        np.testing.assert_array_equal(a[3 : 3 + n], np.sort(x[3 : 3 + n]))
        np.testing.assert_array_equal(a[:3], x[:3])
        np.testing.assert_array_equal(a[3 + n :], x[3 + n :])
