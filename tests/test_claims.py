"""The claims table on grids whose answers are known: the paper's own numbers satisfy every claim; a variant
made worse on one scene breaks the claims about it; intervals wide enough leave them unsettled."""

from __future__ import annotations

import numpy as np

from fftool.dataset.scenes import BENCHMARKS
from fftool.paper import TABLE2_ADE_FDE, TABLE3_FDE, TABLE4_COLLISIONS
from fftool.reporting.claims import CLAIMS, claims_table
from fftool.reporting.scores import Score
from fftool.reporting.tables import Grid

GOAL_ADE = {"eth": 0.40, "hotel": 0.13, "univ": 0.27, "zara1": 0.17, "zara2": 0.15}  # Table II omits Goal


def _paper_grid(noise: float = 1e-4, worse: dict[tuple[str, str, str], float] | None = None) -> Grid:
    """The paper's Tables II-IV as scores whose replicates scatter by `noise` (relative) around the value."""
    rng = np.random.default_rng(0)
    scores = {}
    for scene in BENCHMARKS:
        for predictor in ("cv", "baseline", "goal", "dr", "re"):
            values = {
                "min_ade": GOAL_ADE[scene]
                if predictor == "goal"
                else TABLE2_ADE_FDE.get(predictor, {}).get(scene, (1, 0))[0],
                "min_fde": TABLE3_FDE.get(predictor, {}).get(scene, 1.0),
                "nc": TABLE4_COLLISIONS.get(predictor, {}).get(scene, 900),
            }
            for metric, value in values.items():
                value += (worse or {}).get((scene, predictor, metric), 0.0)
                replicates = value * (1 + noise * rng.standard_normal(500))
                scores[(scene, predictor, metric)] = Score(np.array([float(value)]), replicates)
    return Grid(scores, 0.95)


def _outcomes(grid: Grid) -> dict[str, str]:
    table = claims_table(grid, "paper")
    assert table is not None
    return dict(zip(table.frame["claim"], table.frame["outcome"]))


def test_the_papers_own_numbers_satisfy_every_claim() -> None:
    outcomes = _outcomes(_paper_grid())
    assert len(outcomes) == len(CLAIMS) and set(outcomes.values()) == {"holds"}, outcomes


def test_a_variant_worse_on_one_scene_breaks_the_claims_about_it() -> None:
    outcomes = _outcomes(_paper_grid(worse={("univ", "dr", "min_fde"): 0.20}))  # Dr 0.52 on univ, AgentFormer 0.45
    broken = {claim for claim, outcome in outcomes.items() if outcome != "holds"}
    assert broken == {
        "Dr and Re beat AgentFormer on every subset (minADE and minFDE)",
        "Dr has the lowest minFDE on univ and zara2",
        "On average, Dr −26 % minFDE against AgentFormer",  # the average moves to −16.8 %
    }
    assert all(outcomes[c] == "does not hold" for c in broken)


def test_wide_intervals_leave_the_claims_unsettled_and_a_partial_grid_has_none() -> None:
    outcomes = _outcomes(_paper_grid(noise=0.5))
    assert "cannot tell" in outcomes.values() and "does not hold" not in outcomes.values()
    grid = _paper_grid()
    partial = Grid({k: v for k, v in grid.scores.items() if k[0] != "eth"}, 0.95)
    assert claims_table(partial, "paper") is None
