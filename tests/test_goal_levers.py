"""benchmarks/goal_levers.py's held-out validation: which windows train and which validate, and the tracks
resampled to another step. Choices are made on these windows, so a test window must never reach them."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

import numpy as np
import pyarrow.parquet as pq
import pytest
import torch

from fftool.artifacts.schema import TRACKS_FILE
from fftool.artifacts.store import ArtifactStore
from fftool.config import GoalConfig, GoalsConfig
from fftool.learning import batches, goal_model
from fftool.learning.batches import SceneMaps
from fftool.learning.scene_prior import goal_scene_index
from fftool.stages import goal as goal_stage

SCRIPT = Path(__file__).parents[1] / "benchmarks" / "goal_levers.py"


@pytest.fixture
def levers(monkeypatch: pytest.MonkeyPatch) -> ModuleType:
    """The script as a module; what `--holdout` patches is put back after the test."""
    spec = importlib.util.spec_from_file_location("goal_levers", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    monkeypatch.setattr(goal_stage, "load_agent_windows", goal_stage.load_agent_windows)
    return module


def test_a_held_out_place_leaves_training_and_is_the_validation(levers: ModuleType, built_store: ArtifactStore) -> None:
    windows = built_store.list("windows")[0]
    place = levers.HOLDOUT["eth"]
    assert place == "hotel"
    levers._hold_out(place)
    train = goal_stage.load_agent_windows(windows, "eth", "train")
    val = goal_stage.load_agent_windows(windows, "eth", "val")
    parts = {part: batches.load_agent_windows(windows, "eth", part) for part in ("train", "val")}
    assert "biwi_hotel" not in set(train.source) and len(train) > 0
    assert set(train.source) == set(parts["train"].source) - {"biwi_hotel"}
    assert set(val.source) == {"biwi_hotel"}
    held = [w.source == "biwi_hotel" for w in parts.values()]
    assert len(val) == sum(int(h.sum()) for h in held)  # the place's windows of both parts, nothing else
    assert sorted(val.row) == sorted(np.concatenate([w.row[h] for w, h in zip(parts.values(), held)]))
    windows_of = [set(w.window_id[h]) for w, h in zip(parts.values(), held)]
    assert len(set(val.window_id)) == sum(map(len, windows_of))  # the two parts' windows stay apart
    with pytest.raises(SystemExit, match="no test part"):
        goal_stage.load_agent_windows(windows, "eth", "test")


def test_another_held_out_place_is_any_place_a_benchmark_trains_on(levers: ModuleType) -> None:
    assert levers.held_out_place("zara1", None) == "hotel"  # HOLDOUT's
    assert levers.held_out_place("zara1", "univ") == "univ"
    assert levers.held_out_place("zara1", "zara") == "zara"  # crowds_zara02 and 03 train it; zara01 is its test
    for benchmark, place in (("eth", "eth"), ("hotel", "hotel")):  # its test scene is all of the place
        with pytest.raises(SystemExit, match="does not train there"):
            levers.held_out_place(benchmark, place)
    assert levers._store_name("recipe_s0", "univ", True) == "recipe_s0@holdout-univ-in-scene"
    assert levers._validation("univ", 1, True) == "held-out univ (best epoch by the val part)"
    assert levers._validation(None, 1) == "val part"
    assert levers._label("recipe_s0", [], 1, True, "univ") == "recipe_s0 best_epoch=val_part place=univ"
    assert levers._label("recipe_s0", [], 1, True) == "recipe_s0 best_epoch=val_part"


def test_tracks_resampled_at_another_step_interpolate_within_each_track(
    levers: ModuleType, built_store: ArtifactStore
) -> None:
    windows = built_store.list("windows")[0]
    like = batches.load_agent_windows(windows, "eth", "train")
    like = like.subset(np.flatnonzero(like.source == "biwi_hotel"))
    resampled = levers._resampled(windows, like, 1.5)
    tracks = pq.read_table(built_store.lookup("tracks", windows.manifest.sources["tracks"]).file(TRACKS_FILE))
    tracks = tracks.to_pandas()
    hotel = tracks[(tracks["source"] == "biwi_hotel") & tracks["split"].isin(["train", "val"])]
    # 20 steps of 1.5 recorded steps span 28.5 steps: of the synthetic walkers' train tracks (30, 29 and 28 steps)
    # only the longest holds one window, from its first step; the 20-step val tracks hold none.
    lengths = hotel.groupby(["split", "ped_id"]).size()
    assert lengths.max() == 30 and (lengths == 30).sum() == 1
    assert len(resampled) == 1 and set(resampled.source) == {"biwi_hotel"}
    (split, ped), _ = next((key, n) for key, n in lengths.items() if n == 30)
    points = hotel[(hotel["split"] == split) & (hotel["ped_id"] == ped)].sort_values("step")[["x", "y"]].to_numpy()
    expected = [
        points[int(t)] if t == int(t) else (points[int(t)] + points[int(t) + 1]) / 2 for t in np.arange(20) * 1.5
    ]
    np.testing.assert_allclose(resampled.xy[0], np.array(expected))  # the last at 28.5: between steps 28 and 29


def test_select_in_scene_chooses_on_the_val_part_without_the_place_and_scores_the_place(
    levers: ModuleType, built_store: ArtifactStore
) -> None:
    windows = built_store.list("windows")[0]
    levers._hold_out("hotel", select_in_scene=True)
    parts = {part: batches.load_agent_windows(windows, "eth", part) for part in ("train", "val")}
    for part, data in parts.items():  # what the goal stage trains and chooses its best epoch on
        chosen = goal_stage.load_agent_windows(windows, "eth", part)
        assert sorted(chosen.row) == sorted(data.row[data.source != "biwi_hotel"]) and len(chosen) > 0
    scored = levers.load_agent_windows(windows, "eth", "val")  # what the script scores: the place alone
    assert set(scored.source) == {"biwi_hotel"}
    for load in (goal_stage.load_agent_windows, levers.load_agent_windows):
        with pytest.raises(SystemExit, match="no test part"):
            load(windows, "eth", "test")


class _Shifted(torch.nn.Module):
    """A stand-in goal U-Net whose logits are 2 − its input."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return 2.0 - x


def test_an_ensemble_samples_the_mean_of_its_members_probabilities(levers: ModuleType) -> None:
    x = torch.linspace(-30, 30, 13).reshape(1, 1, 13, 1)
    assert torch.allclose(levers.ProbabilityMean([torch.nn.Identity()])(x), x, atol=1e-5)  # one member: itself
    both = levers.ProbabilityMean([torch.nn.Identity(), _Shifted()])(x)
    assert torch.allclose(torch.sigmoid(both), (torch.sigmoid(x) + torch.sigmoid(2.0 - x)) / 2, atol=1e-6)
    assert torch.isfinite(both).all()  # ±30 logits: no probability clipped to 0 or 1


@pytest.mark.parametrize("beta", [0.0, 0.5, 1.0])
def test_a_place_s_share_of_the_draws_is_its_windows_to_the_one_minus_beta(levers: ModuleType, beta: float) -> None:
    places = np.array(["univ"] * 400 + ["zara"] * 100 + ["eth"] * 4)
    weights = levers.place_weights(places, beta)
    shares = np.array([weights[places == p].sum() for p in ("univ", "zara", "eth")]) / weights.sum()
    expected = np.array([400.0, 100.0, 4.0]) ** (1 - beta)
    np.testing.assert_allclose(shares, expected / expected.sum())


def test_the_scripts_scoring_reads_the_other_walkers_as_the_goal_stage_does(
    levers: ModuleType, built_store: ArtifactStore
) -> None:
    """With `goal.neighbour_channels` the script's own scoring gives each window's crops its other walkers: its
    mode (goal 1, no random draw) is the goal stage's, on the held-out place whose two parts are joined."""
    windows = built_store.list("windows")[0]
    levers._hold_out("hotel")
    val = levers.load_agent_windows(windows, "eth", "val")
    cfg = GoalConfig(crop_cells=16, widths=(4, 8), neighbour_channels=True, cv_channel=True)
    sampling = GoalsConfig(k=3, samples=50, kmeans_iterations=2)
    torch.manual_seed(0)
    model = goal_model.build_model(cfg, goal_model.input_channels(cfg, 8, 2)).eval()
    maps = SceneMaps(torch.zeros(1, 2, 1, 1), torch.zeros(1, 2), 1.0, ())
    _, mode = levers._val_fde(model, val, maps, cfg, sampling, 8, 12, torch.device("cpu"))[0]
    scene = goal_scene_index(maps, val, cfg, cross_fit=False)
    _, stage_mode = goal_model.evaluate(model, val, scene, maps, cfg, sampling, torch.device("cpu"), 0, 8, 12)
    assert mode == pytest.approx(stage_mode, abs=1e-5)
