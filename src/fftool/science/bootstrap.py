"""Bootstrap confidence intervals over test windows, and paired differences between predictors.

The unit resampled is the window, not the agent: the agents of one window share their neighbours (and each
other's collisions), so they are not independent draws. Nor are neighbouring windows: a stride-1 window
shares 19 of its 20 steps with the next, so windows are resampled in blocks of consecutive windows in time
(the moving-block bootstrap, `window_draws`; docs/metrics.md gives the block-length rule). A resample holds
W of the W windows of a test part, drawn with replacement; a metric of that resample is a sum over its
windows (NC, Col-II) or a ratio of sums (minADE, minFDE, COL: the mean over the agent-windows it holds). One
(R, W) matrix of draw counts serves every metric and every predictor of a benchmark, so the difference of
two predictors' replicates is a paired bootstrap: the same windows, resampled together.

Why not scipy.stats.bootstrap: it redraws per call, so pairing across predictors and metrics would rest on
equal seeds and equal sample sizes, and its ratio statistic over paired (sum, count) arrays is no shorter.
Here a resample is one row of draw counts (index draws summed per window with np.bincount), and every
replicate is a matrix product with the per-window sums: no loop over resamples, agents or windows.
Intervals are percentile intervals (Efron's), which need no normality and keep counts non-negative.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Resampling:
    """How a report resamples its test windows: resamples, seed, windows per block, interval level."""

    resamples: int = 2000
    seed: int = 0
    block: int = 1
    level: float = 0.95


def window_draws(n_windows: int, resamples: int, seed: int | Sequence[int], block: int = 1) -> np.ndarray:
    """(R, W) int: how often each of W windows is drawn in each of R resamples of W windows.

    block = 1: W windows drawn with replacement. block = L > 1: the moving-block bootstrap (Künsch 1989) over
    the windows in time order: ceil(W / L) runs of L consecutive windows, each starting anywhere in
    [0, W − L], the last run cut so that a resample holds W windows. Overlapping windows are dependent (stride-1
    windows share 19 of their 20 steps), so resampling them one by one understates the spread; a block as long
    as the dependence keeps it.
    """
    rng = np.random.default_rng(seed)
    block = max(1, min(block, n_windows))
    if block == 1:
        draws = rng.integers(0, n_windows, size=(resamples, n_windows))  # (R, W) window indices
    else:
        runs = -(-n_windows // block)
        starts = rng.integers(0, n_windows - block + 1, size=(resamples, runs))  # (R, runs)
        draws = (starts[:, :, None] + np.arange(block)).reshape(resamples, -1)[:, :n_windows]
    flat = draws + np.arange(resamples)[:, None] * n_windows  # one bincount slot per (resample, window)
    return np.bincount(flat.ravel(), minlength=resamples * n_windows).reshape(resamples, n_windows)


def window_sums(values: np.ndarray, window: np.ndarray, n_windows: int) -> np.ndarray:
    """(W,) the sum of per-agent-window `values` in each window; `window` (N,) holds indices in [0, W)."""
    return np.bincount(window, weights=values.astype(np.float64), minlength=n_windows)


def replicate_sums(draws: np.ndarray, values: np.ndarray, window: np.ndarray) -> np.ndarray:
    """(R,) the sum of `values` over each resample's agent-windows (a window drawn twice counts twice)."""
    return draws @ window_sums(values, window, draws.shape[1])


def replicate_means(draws: np.ndarray, values: np.ndarray, window: np.ndarray) -> np.ndarray:
    """(R,) the mean of `values` over each resample's agent-windows: a ratio of sums, not a mean of window
    means, so each agent-window weighs the same as in the full-sample mean."""
    return replicate_sums(draws, values, window) / replicate_sums(draws, np.ones(len(values)), window)


def percentile_interval(replicates: np.ndarray, level: float = 0.95) -> tuple[float, float]:
    """The (1 − level)/2 and (1 + level)/2 quantiles of the bootstrap replicates."""
    low, high = np.quantile(replicates, [(1 - level) / 2, (1 + level) / 2])
    return float(low), float(high)


def windows_of(window_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct window ids (W,) in sorted order and each agent-window's index into them (N,)."""
    ids, index = np.unique(window_ids, return_inverse=True)
    return ids, index


def binned_mean_intervals(
    draws: np.ndarray, values: np.ndarray, window: np.ndarray, bins: np.ndarray, n_bins: int, level: float = 0.95
) -> tuple[np.ndarray, np.ndarray]:
    """(n_bins,) low and high ends of each bin's mean of `values` (N,) over the resamples `draws` (R, W).

    window (N,): each value's window index; bins (W,): each window's bin, -1 for none. A resample's bin mean is a
    ratio of sums over the windows it drew, as `replicate_means`; a bin a resample did not draw is left out.
    """
    W = draws.shape[1]
    member = np.zeros((W, n_bins))
    member[np.flatnonzero(bins >= 0), bins[bins >= 0]] = 1.0
    sums = window_sums(values, window, W)[:, None] * member
    counts = window_sums(np.ones(len(values)), window, W)[:, None] * member
    with np.errstate(invalid="ignore", divide="ignore"):
        replicates = (draws @ sums) / (draws @ counts)  # (R, n_bins)
    low, high = np.full(n_bins, np.nan), np.full(n_bins, np.nan)
    held = ~np.isnan(replicates).all(0)  # a bin no window falls in has no interval
    low[held], high[held] = np.nanquantile(replicates[:, held], [(1 - level) / 2, (1 + level) / 2], axis=0)
    return low, high
