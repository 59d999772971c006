"""A report's tables in a terminal of 100 columns: one line per row, names whole, no empty column."""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd
from rich.console import Console

from fftool.reporting.summaries import report_tables

REPORT = Path(__file__).parents[1] / "docs" / "results" / "cpu_all" / "all_fair"


def _rendered(report: Path) -> str:
    console = Console(width=100, record=True, file=open("/dev/null", "w"))  # noqa: SIM115
    for table in report_tables(report):
        console.print(table)
    return console.export_text()


def test_every_row_fits_100_columns_with_its_whole_name() -> None:
    text = _rendered(REPORT)
    assert "…" not in text and max(len(line.rstrip()) for line in text.splitlines()) <= 100
    methods = pd.read_csv(REPORT / "table2_ade_fde.csv")["method"]
    for name in methods:
        shown = name.removesuffix(", published, not re-run")
        assert any(line.strip().startswith(shown) for line in text.splitlines()), name
    assert "Table II: minADE (m)" in text and "Table VI, variant minus AgentFormer (paired): ΔNC" in text
    assert "0.253" in text and "[0.241, 0.277]" not in text  # the estimate, its interval left to the files


def test_a_one_benchmark_report_shows_no_empty_average(tmp_path: Path) -> None:
    one = tmp_path / "report"
    shutil.copytree(REPORT, one)
    for csv in one.glob("table*.csv"):
        frame = pd.read_csv(csv)
        keep = [c for c in frame.columns if not c.startswith(("eth", "hotel", "univ", "zara2", "average", "sum"))]
        frame[keep].to_csv(csv, index=False)
    text = _rendered(one)
    header = next(line for line in text.splitlines() if line.strip().startswith("method"))
    assert header.split() == ["method", "zara1"]
    assert "average" not in text and "sum" not in text
