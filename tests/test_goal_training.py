"""Goal variants trained with the goal module's own errors and chosen under the fair protocol
(`goal_training.source = "module"`); the paper's choice, true goals, keeps its models and fingerprints."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from fftool import pipeline
from fftool.artifacts.store import ArtifactStore
from fftool.config import load_config, predictor_config
from fftool.learning import goal_errors

from .test_maps import make_scene
from .test_reproduce import TINY_PIPELINE


def _straight(heading_deg: float, speed: float, n: int) -> np.ndarray:
    """n identical 20-step paths from the origin at `speed` metres per step toward `heading_deg`."""
    angle = math.radians(heading_deg)
    steps = np.arange(20)[:, None] * speed * np.array([math.cos(angle), math.sin(angle)])
    return np.repeat(steps[None], n, 0).astype(np.float32)


def test_an_error_measured_ahead_of_one_walker_lands_ahead_of_another() -> None:
    """The nearest goal's error is kept in the walker's heading frame: 0.3 m ahead and 0.1 m to the left of an
    eastbound walker is 0.3 m ahead and 0.1 m to the left of a northbound one."""
    val = _straight(0.0, 0.4, 10)
    goals = np.repeat(val[:, -1:], 3, 1) + np.array([[2.0, 2.0], [0.3, 0.1], [-1.5, 0.0]], np.float32)
    errors = goal_errors.fit(val, goals, obs_len=8, bins=1, true_share=0.0)
    train = torch.as_tensor(_straight(90.0, 0.4, 4))[None]  # (1, 4, 20, 2)
    drawn = errors.draw(train, 8, torch.Generator().manual_seed(0))
    torch.testing.assert_close(drawn - train[:, :, -1], torch.tensor([-0.1, 0.3]).expand(1, 4, 2))


def test_errors_come_from_walkers_of_the_same_speed_and_a_true_share_keeps_the_truth() -> None:
    slow, fast = _straight(0.0, 0.05, 20), _straight(0.0, 1.0, 20)
    goals = np.concatenate([slow[:, -1:] + [0.1, 0.0], fast[:, -1:] + [1.0, 0.0]])  # K = 1
    errors = goal_errors.fit(np.concatenate([slow, fast]), goals, 8, bins=2, true_share=0.0)
    train = torch.as_tensor(np.stack([_straight(0.0, 0.05, 3), _straight(0.0, 1.0, 3)]))  # (2, 3, 20, 2)
    moved = errors.draw(train, 8, torch.Generator().manual_seed(1)) - train[:, :, -1]
    torch.testing.assert_close(moved[0], torch.tensor([0.1, 0.0]).expand(3, 2))
    torch.testing.assert_close(moved[1], torch.tensor([1.0, 0.0]).expand(3, 2))
    kept = goal_errors.fit(np.concatenate([slow, fast]), goals, 8, bins=2, true_share=1.0)
    assert torch.equal(kept.draw(train, 8, torch.Generator().manual_seed(1)), train[:, :, -1])


@pytest.mark.slow
def test_a_dr_cvae_trains_on_module_goals_and_keeps_its_fair_best_epoch(raw_tree: Path, tmp_path: Path) -> None:
    make_scene(tmp_path / "scenes" / "zara1")
    profile = tmp_path / "tiny.toml"
    profile.write_text(TINY_PIPELINE.format(raw=str(raw_tree), scenes=str(tmp_path / "scenes")))
    paper = predictor_config(load_config(profile, ["cvae.epochs=2"]), "dr")
    module = predictor_config(load_config(profile, ["cvae.epochs=2", 'goal_training.source="module"']), "dr")
    fingerprint = lambda cfg: pipeline.resolve(cfg, ["cvae"], "zara1")[-1].fingerprint  # noqa: E731
    unread = load_config(profile, ["cvae.epochs=2", "goal_training.true_share=0.5"])
    assert fingerprint(paper) == fingerprint(predictor_config(unread, "dr"))  # the paper's models keep theirs
    assert fingerprint(module) != fingerprint(paper)
    built = pipeline.run(module, ArtifactStore(tmp_path / "artifacts"), ["cvae"], benchmark="zara1")
    assert {"goal", "goals", "cvae"} <= set(built.new)
    stats = built["cvae"].manifest.stats
    log = stats["log"]
    assert all(np.isfinite(row["val_fair_min_ade@20_m"]) for row in log)
    best = min(log, key=lambda row: row["val_fair_min_ade@20_m"])
    assert stats["best_epoch"] == best["epoch"] and stats["best_val_fair_min_ade@20_m"] == best["val_fair_min_ade@20_m"]


def test_a_dlow_sampler_over_a_module_trained_cvae_keeps_its_fair_best_epoch(raw_tree: Path, tmp_path: Path) -> None:
    """DLow over a goal variant trained for the module's goals: the goals artifact read and declared, training
    goals moved the same way, the best epoch the fair one; over the paper's CVAE nothing of that is read."""
    make_scene(tmp_path / "scenes" / "zara1")
    profile = tmp_path / "tiny.toml"
    profile.write_text(TINY_PIPELINE.format(raw=str(raw_tree), scenes=str(tmp_path / "scenes")))
    sets = ["cvae.epochs=1", "dlow.epochs=2"]
    module = predictor_config(load_config(profile, [*sets, 'goal_training.source="module"']), "dr")
    paper = predictor_config(load_config(profile, sets), "dr")
    reads = lambda cfg: pipeline.resolve(cfg, ["dlow"], "zara1")[-1].reads  # noqa: E731
    assert "goals" in reads(module).artifacts and "goal_training.*" in reads(module).params
    assert "goals" not in reads(paper).artifacts and "goal_training.*" not in reads(paper).params
    built = pipeline.run(module, ArtifactStore(tmp_path / "artifacts"), ["dlow"], benchmark="zara1")
    stats = built["dlow"].manifest.stats
    best = min(stats["log"], key=lambda row: row["val_fair_min_ade@20_m"])
    assert stats["best_epoch"] == best["epoch"] and stats["best_val_fair_min_ade@20_m"] == best["val_fair_min_ade@20_m"]
    assert built["dlow"].manifest.sources["goals"] == built["goals"].fingerprint


def test_a_goal_set_keeps_every_goal_where_the_module_put_it_relative_to_the_truth() -> None:
    """goal_training.source = "fair": k of the K goals of one validation window, each at the same distance
    ahead of and beside a training walker's true end point as it was from the validation walker's, in any
    order; an agent of another speed draws another window's set."""
    val = _straight(0.0, 0.4, 1)
    offsets = np.array([[2.0, 2.0], [0.3, 0.1], [-1.5, 0.0], [0.0, -0.7]], np.float32)
    slow = _straight(0.0, 0.05, 1)
    errors = goal_errors.fit(
        np.concatenate([val, slow]), np.stack([val[0, -1] + offsets, slow[0, -1] + offsets * 0]), 8, 2, 0.0
    )
    train = torch.as_tensor(_straight(90.0, 0.4, 5))[None]  # (1, 5, 20, 2), northbound
    drawn = errors.draw_sets(train, 8, torch.Generator().manual_seed(0), 3) - train[:, :, -1, None]
    turned = {(round(-y, 4), round(x, 4)) for x, y in offsets.tolist()}  # east's (ahead, left) seen going north
    assert drawn.shape == (1, 5, 3, 2)
    for agent in drawn[0]:
        got = {(round(x, 4), round(y, 4)) for x, y in agent.tolist()}
        assert len(got) == 3 and got <= turned
    slow_train = torch.as_tensor(_straight(0.0, 0.05, 2))[None]
    assert torch.equal(
        errors.draw_sets(slow_train, 8, torch.Generator(), 2), slow_train[:, :, -1, None].expand(1, 2, 2, 2)
    )
    with pytest.raises(ValueError, match="4 goals, 5 were asked for"):
        errors.draw_sets(train, 8, torch.Generator(), 5)


@pytest.mark.slow
@pytest.mark.parametrize("choice", ['goal_training.source="fair"', "goal_training.fair_best_epoch=true"])
def test_a_goal_cvae_trained_for_the_fair_protocol_keeps_its_fair_best_epoch(
    choice: str, raw_tree: Path, tmp_path: Path
) -> None:
    """goal_training.source = "fair": the best-of-K term decodes the module's goal sets (it is trained: not
    zero after the warm-up epoch); fair_best_epoch: true goals. Either way the best epoch is the fair one and
    the model has its own fingerprint, other than the paper's and the module-goal model's."""
    make_scene(tmp_path / "scenes" / "zara1")
    profile = tmp_path / "tiny.toml"
    profile.write_text(TINY_PIPELINE.format(raw=str(raw_tree), scenes=str(tmp_path / "scenes")))
    sets = ["cvae.epochs=2", "cvae.best_of_k_warmup_epochs=1"]
    fair = predictor_config(load_config(profile, [*sets, choice]), "goal")
    module = predictor_config(load_config(profile, [*sets, 'goal_training.source="module"']), "goal")
    paper = predictor_config(load_config(profile, sets), "goal")
    fingerprint = lambda cfg: pipeline.resolve(cfg, ["cvae"], "zara1")[-1].fingerprint  # noqa: E731
    assert len({fingerprint(fair), fingerprint(module), fingerprint(paper)}) == 3
    built = pipeline.run(fair, ArtifactStore(tmp_path / "artifacts"), ["cvae"], benchmark="zara1")
    stats = built["cvae"].manifest.stats
    log = stats["log"]
    assert [row["train_best_of_k"] == 0 for row in log] == [True, False]
    best = min(log, key=lambda row: row["val_fair_min_ade@20_m"])
    assert stats["best_epoch"] == best["epoch"]
