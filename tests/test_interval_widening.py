"""tools/interval_widening.py: the ratios of two reports' interval widths, on hand-made report CSVs."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from tests.tool_scripts import load_tool

widening = load_tool("interval_widening")


def write_report(folder: Path, width: dict[str, float]) -> Path:
    """A report whose every interval of a method is [1, 1 + width]; the published row has none."""
    folder.mkdir()
    ade_fde, collisions = {}, {}
    for place in (*widening.BENCHMARKS, "average", "sum"):
        for metric in (" minADE", " minFDE"):
            ade_fde[f"{place}{metric} low"] = [1.0] * len(width) + [None]
            ade_fde[f"{place}{metric} high"] = [1.0 + w for w in width.values()] + [None]
        collisions[f"{place} low"] = [1.0] * len(width) + [None]
        collisions[f"{place} high"] = [1.0 + w for w in width.values()] + [None]
    methods = [*width, "a published method"]
    pd.DataFrame({"method": methods} | ade_fde).to_csv(folder / "table2_ade_fde.csv", index=False)
    pd.DataFrame({"method": methods} | collisions).to_csv(folder / "table4_collisions.csv", index=False)
    return folder


def test_the_table_gives_range_and_median_of_the_width_ratios(tmp_path, monkeypatch, capsys):
    wide = write_report(tmp_path / "wide", {"a": 3.0, "b": 2.0, "c": 6.0})
    narrow = write_report(tmp_path / "narrow", {"a": 1.0, "b": 2.0, "c": 2.0})
    monkeypatch.setattr("sys.argv", ["interval_widening.py", str(wide), str(narrow)])
    widening.main()
    rows = capsys.readouterr().out.splitlines()
    assert len(rows) == 2 + len(widening.METRICS)
    for row in rows[2:]:
        cells = [cell.strip() for cell in row.strip("|").split("|")]
        assert cells[1:] == ["1.0–3.0 (3.0)"] * (len(widening.BENCHMARKS) + 1)


def test_a_folder_that_is_not_a_report_is_a_usage_error(tmp_path, monkeypatch, capsys):
    report = write_report(tmp_path / "r", {"a": 1.0})
    (tmp_path / "empty").mkdir()
    monkeypatch.setattr("sys.argv", ["interval_widening.py", str(report), str(tmp_path / "empty")])
    with pytest.raises(SystemExit) as exit_info:
        widening.main()
    assert exit_info.value.code == 2
    assert "table2_ade_fde.csv" in capsys.readouterr().err
