"""benchmarks/goal_hedge.py: which validation windows a place holds, and the min over the variant's K − m samples
and the baseline's first m."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from fftool.learning.batches import AgentWindows, SceneSet

BENCHMARKS_DIR = Path(__file__).parents[1] / "benchmarks"


@pytest.fixture
def hedge(monkeypatch: pytest.MonkeyPatch) -> ModuleType:
    monkeypatch.syspath_prepend(str(BENCHMARKS_DIR))  # the script imports goal_levers beside it
    spec = importlib.util.spec_from_file_location("goal_hedge", BENCHMARKS_DIR / "goal_hedge.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_hedged_min_takes_the_variants_samples_and_the_baselines_picked_m(hedge: ModuleType) -> None:
    variant = np.array([[0.5, 0.4], [0.3, 0.6]])  # K − m = 2 samples per agent-window
    baseline = np.array([[0.9, 0.1, 0.0], [0.2, 0.8, 0.0]])  # the baseline's samples 1, 2, 3

    def first(m: int) -> np.ndarray:
        return np.broadcast_to(np.arange(m), (2, m))

    assert hedge.hedged_min(variant, baseline, first(0)) == pytest.approx((0.4 + 0.3) / 2)
    assert hedge.hedged_min(variant, baseline, first(1)) == pytest.approx((0.4 + 0.2) / 2)  # sample 1 only: not 0.1
    assert hedge.hedged_min(variant, baseline, first(2)) == pytest.approx((0.1 + 0.2) / 2)
    assert hedge.hedged_min(np.empty((2, 0)), baseline, first(3)) == pytest.approx(0.0)  # the baseline alone
    assert hedge.hedged_min(variant, baseline, np.array([[2], [1]])) == pytest.approx((0.0 + 0.3) / 2)


def test_spread_picks_add_the_end_points_farthest_from_all_kept_so_far(hedge: ModuleType) -> None:
    variant = np.array([[[0.0, 0.0]]])  # one agent-window, the variant's one end point
    baseline = np.array([[[0.1, 0.0], [5.0, 0.0], [5.1, 0.0], [0.0, 3.0]]])
    # farthest from (0, 0): (5.1, 0); then farthest from both: (0, 3), 3 m away, not (5, 0), 0.1 m from the pick
    assert hedge.spread_picks(variant, baseline, 2).tolist() == [[2, 3]]
    assert hedge.spread_picks(variant, baseline, 0).shape == (1, 0)
    # without the variant's end points the first pick is sample 1, then the farthest from it; no sample twice
    assert hedge.spread_picks(np.zeros((1, 0, 2)), baseline, 4).tolist() == [[0, 2, 3, 1]]


def test_a_place_holds_the_windows_of_its_files_only(hedge: ModuleType) -> None:
    sources = np.array(["biwi_hotel", "biwi_hotel", "students003", "crowds_zara02", "crowds_zara03", "crowds_zara03"])
    minus = np.full(len(sources), -1)
    data = AgentWindows(np.zeros((len(sources), 20, 2)), sources, minus, np.array([0, 0, 1, 2, 3, 3]), minus, minus)
    scenes = SceneSet(data, {}, np.array([0, 2, 3, 4, 6]))  # four windows: hotel, univ, zara, zara
    assert hedge.place_windows(scenes, "zara").tolist() == [2, 3]
    assert hedge.place_windows(scenes, "hotel").tolist() == [0]
    assert hedge.place_windows(scenes, None).tolist() == [0, 1, 2, 3]
