"""Tables II-VI render the right numbers with their intervals, averages only over all five scenes, the
paper's numbers beside ours, and paired differences from the same resamples."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from fftool.dataset.scenes import BENCHMARKS
from fftool.reporting import tables
from fftool.reporting.scores import METRICS, Score


def _score(values: list[float], spread: float = 0.01) -> Score:
    """A score whose replicates run evenly from mean - spread to mean + spread (so its interval is known)."""
    mean = float(np.mean(values))
    return Score(np.array(values, dtype=float), np.linspace(mean - spread, mean + spread, 1001))


def _grid(scenes: tuple[str, ...], predictors: tuple[str, ...], seeds: int = 1) -> tables.Grid:
    scores = {}
    for i, scene in enumerate(scenes):
        for j, predictor in enumerate(predictors):
            base = 0.1 * (i + 1) * (j + 1)
            for metric in METRICS:
                value = base if metric != "nc" else 10.0 * (i + 1) * (j + 1)
                scores[(scene, predictor, metric)] = _score([value + 0.002 * s for s in range(seeds)])
    return tables.Grid(scores, level=0.9)


def test_tables_show_our_numbers_with_intervals_the_papers_and_the_average(tmp_path: Path) -> None:
    grid = _grid(BENCHMARKS, ("dr", "baseline"))
    assert grid.predictors == ["baseline", "dr"]  # the paper's row order
    t2 = tables.table2(grid, "caption")
    shown = t2.frame.set_index("method")
    assert shown.loc["ForceFormer-Dr", "zara1"] == "0.400 [0.391, 0.409] / 0.400 [0.391, 0.409]"
    assert shown.loc["ForceFormer-Dr", "zara1 (paper)"] == "0.14/0.20"
    assert shown.loc["AgentFormer", "average"].startswith("0.600 [")  # mean of 0.2..1.0
    data = t2.data.set_index("method")
    assert np.isclose(data.loc["AgentFormer", "average minADE"], 0.6)
    assert np.isclose(data.loc["ForceFormer-Dr", "zara1 minFDE low"], 0.4 - 0.009)
    t4 = tables.table4(grid, "c", 0).data.set_index("method")
    assert t4.loc["ForceFormer-Dr", "univ"] == 30 and t4.loc["ForceFormer-Dr", "sum"] == 10 * 15
    assert t4.loc["AgentFormer", "sum (paper)"] == "683"
    report = tables.write([t2], tmp_path / "r", "# report\n")
    text = report.read_text()
    assert "| ForceFormer-Dr | 0.100 [0.091, 0.109] / 0.100 [0.091, 0.109] | 0.43/0.58 |" in text
    assert "_caption_" in text
    tex = (tmp_path / "r" / "table2_ade_fde.tex").read_text()
    assert "\\begin{tabular}" in tex
    csv = pd.read_csv(tmp_path / "r" / "table2_ade_fde.csv").set_index("method")
    assert {"eth minADE", "eth minADE sd", "eth minADE low", "eth minADE high", "eth minADE per seed"} <= set(csv)


def test_several_seeds_show_their_spread_and_keep_each_value() -> None:
    grid = _grid(("zara1",), ("baseline", "re"), seeds=3)
    t3 = tables.table3(grid, "c")
    assert t3.frame.set_index("method").loc["ForceFormer-Re", "zara1"] == "0.202 ±0.002 [0.193, 0.211]"
    data = t3.data.set_index("method")
    assert data.loc["ForceFormer-Re", "zara1 per seed"] == "0.2;0.202;0.204"
    assert np.isclose(data.loc["ForceFormer-Re", "zara1 sd"], 0.002)


def test_a_partial_run_has_no_average() -> None:
    t3 = tables.table3(_grid(("zara1",), ("re",)), "c")
    assert list(t3.frame.columns) == ["method", "zara1", "zara1 (paper)", "average", "average (paper)"]
    assert t3.frame.set_index("method").loc["ForceFormer-Re", "average"] == ""


def test_the_paired_table_subtracts_replicates_of_the_same_resamples() -> None:
    """Re has exactly 5 collisions fewer than the baseline in every resample: the interval is [-5, -5],
    though each of the two counts alone is uncertain."""
    replicates = np.random.default_rng(0).normal(50, 8, 1000)
    scores = {("zara1", p, m): _score([1.0]) for p in ("baseline", "re") for m in METRICS}
    scores[("zara1", "baseline", "nc")] = Score(np.array([50.0]), replicates)
    scores[("zara1", "re", "nc")] = Score(np.array([45.0]), replicates - 5)
    t6 = tables.table6(tables.Grid(scores, 0.95), "c")
    row = t6.frame.set_index("metric").loc["ΔNC"]
    assert row["method"] == "ForceFormer-Re" and row["zara1"] == "-5.0 [-5.0, -5.0]"
    assert "ΔCOL" in set(t6.frame["metric"]) and "ΔCol-II" in set(t6.frame["metric"])
    assert "$\\Delta$NC" in tables.latex(t6)


def test_rows_say_how_a_cvae_drew_its_samples() -> None:
    """With a DLow sampler or the mean code in the grid, each CVAE row names its codes; with prior draws alone,
    the names are the paper's."""
    grid = tables.Grid({}, 0.95, {"baseline": "dlow", "re": "mean", "goal": "prior"})
    assert grid.method("baseline") == "AgentFormer (DLow)" and grid.method("dr") == "ForceFormer-Dr (CVAE samples)"
    assert (
        grid.method("re") == "ForceFormer-Re (mean code)" and grid.method("goal") == "ForceFormer-Goal (CVAE samples)"
    )
    assert grid.method("cv") == "constant velocity" and tables.Grid({}, 0.95).method("baseline") == "AgentFormer"
    assert tables.Grid({}, 0.95, {"baseline": "prior", "dr": "prior"}).method("dr") == "ForceFormer-Dr"
