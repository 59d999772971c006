"""tools/stage_times.py and tools/budget_curves.py count thread-seconds: build seconds × the threads recorded."""

from __future__ import annotations

from pathlib import Path

import pytest

from fftool.artifacts.store import Manifest
from tests.tool_scripts import run_tool


def manifest(kind: str, stats: dict, environment: dict | None = None) -> Manifest:
    return Manifest(kind, 1, "0" * 64, {}, {}, {}, stats=stats, environment=environment or {})


def test_thread_seconds_multiplies_build_seconds_by_threads_and_ranks() -> None:
    assert manifest("cvae", {"build_seconds": 60.0, "torch_threads": 2}).thread_seconds() == 120.0
    assert manifest("cvae", {"build_seconds": 60.0, "torch_threads": 2, "world_size": 2}).thread_seconds() == 240.0
    # no threads in the stats: the environment's, recorded whenever the process had imported torch
    assert manifest("goals", {"build_seconds": 10.0}, {"torch_threads": 4}).thread_seconds() == 40.0
    assert manifest("tracks", {"build_seconds": 10.0}).thread_seconds() == 10.0
    assert manifest("tracks", {}).thread_seconds() == 0.0


def write_model(root: Path, kind: str, name: str, stats: dict, log: str) -> None:
    folder = root / kind / name
    folder.mkdir(parents=True)
    (folder / "manifest.json").write_text(manifest(kind, stats).to_json())
    (folder / "log.csv").write_text(log)


@pytest.fixture()
def store(tmp_path: Path) -> Path:
    """Two baseline CVAEs of one benchmark's budget: one trained on one thread, one on two, 60 s each."""
    log = "epoch,val_min_ade@20_m\n1,0.4\n2,0.3\n3,0.25\n4,0.2\n"
    for name, threads in (("a", 1), ("b", 2)):
        stats = {"benchmark": f"zara{threads}", "variant": "baseline", "build_seconds": 60.0,
                 "torch_threads": threads, "best_val_min_ade@20_m": 0.2}  # fmt: skip
        write_model(tmp_path, "cvae", name, stats, log)
    return tmp_path


def test_stage_times_sums_thread_minutes(store: Path, monkeypatch, capsys) -> None:
    out = run_tool("stage_times", ["--root", str(store), "--benchmarks", "zara1,zara2"], monkeypatch, capsys)
    assert "| cvae baseline | 1.0 | 2.0 | 3.0 |" in out
    assert "| **sum (thread-minutes)** | **1.0** | **2.0** | **3.0** |" in out


def test_budget_curves_counts_thread_minutes(store: Path, monkeypatch, capsys) -> None:
    out = run_tool("budget_curves", ["--models", str(store), "--fraction", "0.5"], monkeypatch, capsys)
    # half the epochs kept: best 0.3 against 0.2 (+50 %), half of each model's thread-minutes saved
    assert "| zara2/baseline | val_min_ade@20_m | 0.200 | 0.300 | +0.100 (+50%) | 1.0 |" in out
    assert "3 thread-minutes trained; the smaller budget saves about 2." in out
