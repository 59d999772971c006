"""The window bootstrap on hand-made cases whose answers are known exactly."""

from __future__ import annotations

import numpy as np
import pytest

from fftool.science.bootstrap import (
    binned_mean_intervals,
    percentile_interval,
    replicate_means,
    replicate_sums,
    window_draws,
    windows_of,
)


def test_every_resample_draws_as_many_windows_as_there_are() -> None:
    draws = window_draws(7, 500, seed=3)
    assert draws.shape == (500, 7) and (draws.sum(1) == 7).all() and draws.min() >= 0
    np.testing.assert_array_equal(draws, window_draws(7, 500, seed=3))  # the seed fixes the resamples
    assert not np.array_equal(draws, window_draws(7, 500, seed=4))


def test_two_windows_give_the_binomial_answer() -> None:
    """Window sums 0 and 1: a resample of 2 draws sums to 0, 1, 2 with probabilities 1/4, 1/2, 1/4, so the
    95 % percentile interval is [0, 2] and the bootstrap standard deviation is sqrt(1/2)."""
    draws = window_draws(2, 40_000, seed=0)
    sums = replicate_sums(draws, np.array([0.0, 1.0]), np.array([0, 1]))
    shares = np.bincount(sums.astype(int), minlength=3) / len(sums)
    np.testing.assert_allclose(shares, [0.25, 0.5, 0.25], atol=0.01)
    assert percentile_interval(sums) == (0.0, 2.0)
    assert sums.std() == pytest.approx(0.5**0.5, rel=0.02)


def test_the_variance_of_a_resampled_sum_is_w_times_the_window_variance() -> None:
    """Multinomial draws: Var(Σ c_w s_w) = W · var(s) (population variance of the window sums)."""
    s = np.array([0.0, 3.0, 1.0, 7.0, 2.0])
    sums = replicate_sums(window_draws(5, 50_000, seed=1), s, np.arange(5))
    assert sums.mean() == pytest.approx(s.sum(), rel=0.01)
    assert sums.var() == pytest.approx(5 * s.var(), rel=0.03)


def test_windows_not_agents_are_resampled() -> None:
    """Window 0 holds three agents that collided (1 each), windows 1-3 one agent each (0). Resampling windows
    moves the three together: sums are multiples of 3, and 0 comes with probability (3/4)^4 = 0.316; resampling
    six agents would give 0 with probability 1/64 and any count from 0 to 6."""
    ids, window = windows_of(np.array([10, 10, 10, 11, 12, 13]))
    assert ids.tolist() == [10, 11, 12, 13] and window.tolist() == [0, 0, 0, 1, 2, 3]
    sums = replicate_sums(window_draws(4, 40_000, seed=2), np.array([1, 1, 1, 0, 0, 0]), window)
    assert set(np.unique(sums % 3)) == {0.0}
    assert (sums == 0).mean() == pytest.approx(0.75**4, abs=0.01)


def test_a_mean_is_a_ratio_of_sums_over_the_drawn_agent_windows() -> None:
    """Window 0: two agents with 1; window 1: one agent with 4. Resamples (0,0), (0,1), (1,1) give means 1, 2, 4
    (not the mean of window means, 2.5, for the mixed one) with probabilities 1/4, 1/2, 1/4."""
    means = replicate_means(window_draws(2, 40_000, seed=5), np.array([1.0, 1.0, 4.0]), np.array([0, 0, 1]))
    values, counts = np.unique(means, return_counts=True)
    assert values.tolist() == [1.0, 2.0, 4.0]
    np.testing.assert_allclose(counts / len(means), [0.25, 0.5, 0.25], atol=0.01)


def test_a_paired_difference_resamples_the_same_windows() -> None:
    """Predictor b has one collision more than a in every window: the paired difference is exactly W in every
    resample, though each predictor's own interval is wide."""
    rng = np.random.default_rng(0)
    a = rng.poisson(5, size=50).astype(float)
    draws = window_draws(50, 2000, seed=0)
    window = np.arange(50)
    rep_a, rep_b = replicate_sums(draws, a, window), replicate_sums(draws, a + 1, window)
    low, high = percentile_interval(rep_a)
    assert high - low > 20
    assert percentile_interval(rep_b - rep_a) == (50.0, 50.0)


def test_a_block_of_all_windows_draws_each_once_and_block_one_is_the_window_bootstrap() -> None:
    whole = window_draws(5, 100, seed=1, block=5)  # one start only: every resample is the sample itself
    assert (whole == 1).all()
    np.testing.assert_array_equal(window_draws(9, 50, seed=2, block=1), window_draws(9, 50, seed=2))
    blocks = window_draws(103, 400, seed=0, block=10)
    assert (blocks.sum(1) == 103).all()  # 11 blocks of 10, the last one cut to 3


def test_blocks_widen_the_interval_of_a_time_correlated_metric() -> None:
    """A metric that drifts slowly over time (runs of 20 equal windows, as overlapping windows share their
    steps): resampling single windows treats 1,000 windows as independent; blocks of 20 see 50 runs."""
    rng = np.random.default_rng(0)
    values = np.repeat(rng.normal(size=50), 20)  # (1000,) one value per window, constant over runs of 20
    window = np.arange(1000)
    widths = {}
    for block in (1, 20):
        means = replicate_means(window_draws(1000, 2000, seed=5, block=block), values, window)
        low, high = percentile_interval(means)
        widths[block] = high - low
    assert widths[20] / widths[1] > 3  # about sqrt(20) ≈ 4.5: the effective sample is 50, not 1,000


def test_binned_mean_intervals_equal_a_loop_over_resamples() -> None:
    rng = np.random.default_rng(3)
    window = np.sort(rng.integers(0, 30, 200))
    values = rng.normal(size=200)
    bins = rng.integers(-1, 3, 30)  # -1: a window in no bin
    draws = window_draws(30, 300, 1, block=5)
    low, high = binned_mean_intervals(draws, values, window, bins, 3, 0.9)
    for b in range(3):
        means = []
        for counts in draws:
            weight = counts[window] * (bins[window] == b)
            if weight.sum():
                means.append((weight * values).sum() / weight.sum())
        np.testing.assert_allclose([low[b], high[b]], np.quantile(means, [0.05, 0.95]))
