"""The docs' generated tables compute what they claim: a hand-made results.csv, its numbers worked out by hand."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from fftool.reporting.doc_tables import gap_table, stage_seconds, training_times_table


def test_the_gap_to_agentformer_is_each_variant_minus_the_baseline(tmp_path: Path) -> None:
    rows = [
        ("zara1", "baseline", 0.200, 0.400),
        ("zara1", "re", 0.190, 0.380),  # ahead on both: -0.010 / -0.020
        ("hotel", "baseline", 0.100, 0.200),
        ("hotel", "re", 0.130, 0.190),  # behind on minADE: +0.030 / -0.010
        ("hotel", "cv", 0.500, 0.900),  # reads no goal: no row
    ]
    results = tmp_path / "results.csv"
    pd.DataFrame(rows, columns=["benchmark", "variant", "min_ade", "min_fde"]).to_csv(results, index=False)
    table = gap_table(results).splitlines()
    assert table[0] == "| variant − AgentFormer (m) | hotel | zara1 | average | ahead on both |"
    assert table[2:] == ["| ForceFormer-Re | +0.030 / -0.010 | -0.010 / -0.020 | **+0.010 / -0.015** | zara1 |"]


def test_stage_seconds_sums_the_named_builds(tmp_path: Path) -> None:
    times = tmp_path / "times.csv"
    times.write_text("stage,benchmark,seconds,threads\ntracks,,0.2,2\nwindows,,0.5,2\ncvae dr,zara1,135.1,2\n")
    assert stage_seconds(times, ingest="tracks+windows", dr="cvae dr") == "ingest 0.7 s, dr 135 s"


def test_training_times_count_threads_and_schedule_two_jobs(tmp_path: Path) -> None:
    times = tmp_path / "times.csv"
    times.write_text(
        "stage,benchmark,seconds,threads,ranks\n"
        "goal,zara1,600,1,1\ncvae dr,zara1,1200,2,1\n"  # 10 + 40: run as one-thread jobs, the 40 bounds
        "goal,hotel,1800,1,1\ncvae dr,hotel,60,2,1\n"  # 30 + 2: two one-thread jobs take 30
    )
    table = training_times_table(times).splitlines()
    assert table[0] == "| stage | hotel | zara1 | all |"
    assert table[2:] == [
        "| cvae dr | 2.0 | 40.0 | 42.0 |",
        "| goal | 30.0 | 10.0 | 40.0 |",
        "| **sum (thread-minutes)** | **32.0** | **50.0** | **82.0** |",
        "| 2-job wall, ideal (min) | 30.0 | 40.0 | 70.0 |",
    ]
