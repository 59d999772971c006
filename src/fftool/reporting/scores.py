"""Every table number with its uncertainty: the spread over grid seeds and a bootstrap over test windows.

Each evaluation's per-agent metrics are recomputed from its saved predictions (`rescoring.rescored_columns`),
so COL and Col-II reach evaluations built before they existed and nothing is sampled again. One matrix of
window draws per benchmark (science/bootstrap.py) serves every predictor, seed and metric, so a difference
between two predictors is a paired bootstrap. A score's replicates are those of its mean over seeds: the
interval says how much the test windows move the seed-averaged number; the standard deviation says how
much training and sampling seeds move it.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any, Final

import numpy as np

from fftool.artifacts.store import ArtifactStore
from fftool.config import ReportConfig
from fftool.dataset.scenes import BENCHMARKS
from fftool.errors import FftoolError
from fftool.science.bootstrap import percentile_interval, replicate_means, replicate_sums, window_draws, windows_of

METRICS: Final = ("min_ade", "min_fde", "nc", "col", "col_gt", "jade", "jfde")
MEANS: Final = frozenset({"min_ade", "min_fde", "col", "jade", "jfde"})  # means over agent-windows; the rest count


@dataclass(frozen=True)
class Score:
    """One number of a table: its value per grid seed and the bootstrap replicates of their mean."""

    per_seed: np.ndarray  # (S,) value on the whole test part, one per seed
    replicates: np.ndarray  # (R,) the seed mean on each window resample

    @property
    def estimate(self) -> float:
        return float(self.per_seed.mean())

    @property
    def sd(self) -> float:
        """Sample standard deviation over seeds; NaN for one seed (no spread is measured)."""
        return float(self.per_seed.std(ddof=1)) if len(self.per_seed) > 1 else float("nan")

    def interval(self, level: float) -> tuple[float, float]:
        return percentile_interval(self.replicates, level)

    def __sub__(self, other: Score) -> Score:
        """The paired difference: same seeds, same window resamples."""
        return Score(self.per_seed - other.per_seed, self.replicates - other.replicates)


def combine(scores: Iterable[Score], how: str) -> Score:
    """Scenes into one number ('mean': the Average column, 'sum': the Sum column); scenes resample independently."""
    stacked = list(scores)
    reduce = np.mean if how == "mean" else np.sum
    return Score(reduce([s.per_seed for s in stacked], 0), reduce([s.replicates for s in stacked], 0))


def _metric_values(columns: Mapping[str, np.ndarray], pairs: str, sample: str) -> dict[str, np.ndarray]:
    """Per agent-window values whose mean or sum over agent-windows is each metric of the tables."""
    contacts = columns["collisions" if sample == "best_ade" else "joint_collisions"].astype(np.float64)
    return {
        "min_ade": columns["min_ade"],
        "min_fde": columns["min_fde"],
        "nc": contacts if pairs == "ordered" else contacts / 2,  # every contact is counted at both agents
        "col": columns["col"],
        "col_gt": columns["col_gt"],
        "jade": columns["joint_ade"],
        "jfde": columns["joint_fde"],
    }


def score(
    store: ArtifactStore, results: list[dict[str, Any]], report: ReportConfig, threshold_m: float, block: int = 1
) -> tuple[dict[tuple[str, str, str], Score], list[dict[str, Any]]]:
    """Scores per (benchmark, predictor, metric), and one row per evaluation (seed) with its own intervals.

    results: the ablation's cells, each an evaluate manifest's stats with `artifact` and `grid_seed`; block: the
    moving-block bootstrap's windows per block (1: windows resampled one by one).
    """
    from fftool.reporting.rescoring import rescored_columns  # torch: only when scores are computed

    cells: dict[tuple[str, str, str], list[tuple[float, np.ndarray]]] = {}
    rows = []
    draws: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # benchmark -> (window ids, (R, W) draws)
    for r in results:
        columns = rescored_columns(store, store.resolve(r["artifact"]), threshold_m)
        ids, window = windows_of(columns["window_id"])
        benchmark = r["benchmark"]
        if benchmark not in draws:
            seed = [report.bootstrap_seed, _benchmark_index(benchmark)]
            draws[benchmark] = ids, window_draws(len(ids), report.bootstrap_resamples, seed, block)
        known, drawn = draws[benchmark]
        if not np.array_equal(known, ids):
            raise FftoolError(f"{r['artifact']}: its test windows differ from the other {benchmark} evaluations")
        row = {key: r[key] for key in ("benchmark", "variant", "protocol", "grid_seed", "k", "agent_windows")}
        for metric, values in _metric_values(columns, report.collision_pairs, report.collision_sample).items():
            mean = metric in MEANS
            value = float(values.mean() if mean else values.sum())
            replicates = (replicate_means if mean else replicate_sums)(drawn, values, window)
            cells.setdefault((benchmark, r["variant"], metric), []).append((value, replicates))
            low, high = percentile_interval(replicates, report.confidence)
            row |= {metric: value, f"{metric} low": low, f"{metric} high": high}
        rows.append(row | {"artifact": r["artifact"]})
    scores = {
        key: Score(np.array([v for v, _ in runs]), np.mean([rep for _, rep in runs], 0)) for key, runs in cells.items()
    }
    return scores, rows


def _benchmark_index(benchmark: str) -> int:
    """A benchmark's number in bootstrap seeds: its ETH/UCY index, or a stable one from a dataset's name."""
    if benchmark in BENCHMARKS:
        return BENCHMARKS.index(benchmark)
    return int.from_bytes(hashlib.sha256(benchmark.encode()).digest()[:4], "little")
