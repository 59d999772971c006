"""Tables II-IV render the right numbers, averages only over all five scenes, paper numbers beside ours."""

from __future__ import annotations

from pathlib import Path

from fftool.dataset.scenes import BENCHMARKS
from fftool.reporting import tables


def _result(benchmark: str, variant: str, ade: float, fde: float, nc: int) -> dict:
    return {
        "benchmark": benchmark,
        "variant": variant,
        "protocol": "paper",
        "k": 20,
        "min_ade": ade,
        "min_fde": fde,
        "nc": {"best_ade": {"ordered": nc, "unordered": nc // 2}, "joint": {"ordered": 0, "unordered": 0}},
        "agent_windows": 10,
        "seconds": 1.0,
    }


def test_tables_show_our_numbers_the_papers_and_the_average(tmp_path: Path) -> None:
    results = [
        _result(b, v, 0.1 * (i + 1), 0.2 * (i + 1), 2 * i) for i, b in enumerate(BENCHMARKS) for v in ("dr", "baseline")
    ]
    frame = tables.results_frame(results, "ordered", "best_ade")
    assert list(frame["predictor"].unique()) == ["baseline", "dr"]  # the paper's row order
    t2 = tables.table2(frame, "caption").frame.set_index("method")
    assert t2.loc["ForceFormer-Dr", "zara1"] == "0.40/0.80"
    assert t2.loc["ForceFormer-Dr", "zara1 (paper)"] == "0.14/0.20"
    assert t2.loc["AgentFormer", "average"] == "0.30/0.60"  # mean of 0.1..0.5 and 0.2..1.0
    t4 = tables.table4(tables.results_frame(results, "unordered", "best_ade"), "c").frame.set_index("method")
    assert t4.loc["ForceFormer-Dr", "univ"] == "2" and t4.loc["ForceFormer-Dr", "sum"] == str(sum(i for i in range(5)))
    assert t4.loc["AgentFormer", "sum (paper)"] == "683"
    report = tables.write([tables.table2(frame, "K = 20, protocol paper")], tmp_path / "r", "# report\n")
    text = report.read_text()
    assert "| ForceFormer-Dr | 0.10/0.20 | 0.43/0.58 |" in text and "_K = 20, protocol paper_" in text
    assert "\\begin{tabular}" in (tmp_path / "r" / "table2_ade_fde.tex").read_text()


def test_a_partial_run_has_no_average() -> None:
    frame = tables.results_frame([_result("zara1", "re", 0.2, 0.4, 3)], "ordered", "best_ade")
    t3 = tables.table3(frame, "c").frame.set_index("method")
    assert list(t3.columns) == ["zara1", "zara1 (paper)", "average", "average (paper)"]
    assert t3.loc["ForceFormer-Re", "average"] == "" and t3.loc["ForceFormer-Re", "zara1"] == "0.40"
