"""Goal U-Net training on a tiny synthetic benchmark: learning, resuming, sampling, the CLI."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import torch
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
from typer.testing import CliRunner

from fftool import pipeline
from fftool.artifacts.store import ArtifactStore
from fftool.cli import app
from fftool.config import GoalConfig, GoalsConfig, load_config
from fftool.errors import IntegrityError
from fftool.learning import goal_model, training
from fftool.learning.batches import SceneMaps, load_agent_windows
from fftool.learning.training import save_checkpoint
from fftool.science.heatmaps import softargmax
from fftool.stages import goal
from fftool.stages.contract import StageContext

from .test_maps import make_scene

TINY = GoalConfig(
    resolution_m=0.5, crop_cells=16, widths=(4, 8, 8), epochs=4, batch_size=16, lr=3e-3, train_stride=1, val_max=0
)
SAMPLING = GoalsConfig(k=5, samples=200, kmeans_iterations=5)


def _inputs(raw_tree: Path, store: ArtifactStore, tmp_path: Path, scenes: tuple[str, ...] = ("zara1",)) -> dict:
    """The tiny benchmark's windows, and maps of `scenes` (zara1, its test scene, by default)."""
    for scene in scenes:
        make_scene(tmp_path / "scenes" / scene)
    cfg = load_config(None, [f"data.raw_dir={str(raw_tree)!r}", f"data.scenes_dir={str(tmp_path / 'scenes')!r}"])
    built = pipeline.run(cfg, store, ["windows", "maps"])
    return {"windows": built["windows"], "maps": built["maps"]}


@pytest.fixture
def inputs(raw_tree: Path, built_store: ArtifactStore, tmp_path: Path) -> dict:
    return _inputs(raw_tree, built_store, tmp_path)


def _train(inputs: dict, tmp_path: Path, name: str, cfg: GoalConfig = TINY, on_progress=None) -> dict:
    out = tmp_path / name
    out.mkdir(exist_ok=True)
    ctx = StageContext(
        out,
        tmp_path / "scratch",
        benchmark="zara1",
        device_name="cpu",
        **({"on_progress": on_progress} if on_progress else {}),
    )
    return goal.train(cfg, SAMPLING, inputs["windows"], inputs["maps"], ctx)


def test_loss_decreases_and_the_best_model_reloads(inputs: dict, tmp_path: Path) -> None:
    stats = _train(inputs, tmp_path, "run")
    losses = [row["train_loss"] for row in stats["log"]]
    assert losses[-1] < losses[0]
    assert stats["train_agent_windows"] > 100 and stats["val_agent_windows"] > 10
    assert 1 <= stats["best_epoch"] <= 4
    saved = torch.load(tmp_path / "run" / "model.pt", weights_only=True)
    assert saved["config"]["crop_cells"] == 16 and saved["in_channels"] == 8 + 6
    assert (tmp_path / "run" / "log.csv").read_text().startswith("epoch,seconds,train_loss")


def test_an_interrupted_run_resumes_and_ends_like_an_uninterrupted_one(inputs: dict, tmp_path: Path) -> None:
    reference = _train(inputs, tmp_path, "reference", TINY.model_copy(update={"epochs": 3}))
    (tmp_path / "scratch" / "last.pt").unlink()  # a fresh start for the interrupted run

    def interrupt(phase: str, done: int, total: int) -> None:
        if phase.startswith("epoch 3/") and done == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        _train(inputs, tmp_path, "interrupted", TINY.model_copy(update={"epochs": 3}), on_progress=interrupt)
    assert torch.load(tmp_path / "scratch" / "last.pt", weights_only=True)["epoch"] == 1  # epochs 1-2 saved
    resumed = _train(inputs, tmp_path, "resumed", TINY.model_copy(update={"epochs": 3}))
    assert resumed["resumed_from_epoch"] == 2
    for a, b in zip(reference["log"], resumed["log"]):
        assert a["train_loss"] == pytest.approx(b["train_loss"], rel=1e-6)
    ref = torch.load(tmp_path / "reference" / "model.pt", weights_only=True)["state_dict"]
    res = torch.load(tmp_path / "resumed" / "model.pt", weights_only=True)["state_dict"]
    for key in ref:
        torch.testing.assert_close(ref[key], res[key])


def test_the_cli_trains_samples_and_prints_the_tables(raw_tree: Path, tmp_path: Path) -> None:
    make_scene(tmp_path / "scenes" / "zara1")
    root = str(tmp_path / "artifacts")
    common = [
        "--root",
        root,
        "--set",
        f"data.raw_dir={str(raw_tree)!r}",
        "--set",
        f"data.scenes_dir={str(tmp_path / 'scenes')!r}",
    ]
    tiny = ["--set", "goal.crop_cells=16", "--set", "goal.widths=[4, 8, 8]", "--set", "goal.epochs=1"]
    tiny += ["--set", "goal.resolution_m=0.5", "--set", "goals.samples=100"]
    runner = CliRunner()
    missing = runner.invoke(app, ["train-goal", "--benchmarks", "zara1", *common, *tiny])
    assert missing.exit_code == 1 and "run `fftool ingest` first, with the same -c/--set" in missing.output
    assert runner.invoke(app, ["ingest", *common]).exit_code == 0
    assert runner.invoke(app, ["maps", *common]).exit_code == 0
    trained = runner.invoke(app, ["train-goal", "--benchmarks", "zara1", *common, *tiny, "--device", "cpu"])
    assert trained.exit_code == 0, trained.output
    assert "val_goal_fde@20_m" in trained.output
    sampled = runner.invoke(app, ["sample-goals", "--benchmarks", "zara1", *common, *tiny])
    assert sampled.exit_code == 0, sampled.output
    assert "goal module alone" in sampled.output and "Goal-SAR" in sampled.output
    goals = np.load(next((Path(root) / "goals").iterdir()) / "goals.npy")
    assert goals.shape[1:] == (20, 2) and np.isfinite(goals).all()
    assert runner.invoke(app, ["train-goal", "--benchmarks", "atlantis", *common]).exit_code == 2
    assert runner.invoke(app, ["train-goal", "-b", "zara1", *common]).exit_code == 2  # no hidden 0.x spelling


def test_the_cv_channel_and_adamw_cosine_train(inputs: dict, tmp_path: Path) -> None:
    cfg = TINY.model_copy(
        update={"epochs": 2, "cv_channel": True, "optimizer": "adamw", "weight_decay": 0.01, "schedule": "cosine"}
    )
    stats = _train(inputs, tmp_path, "cv", cfg)
    saved = torch.load(tmp_path / "cv" / "model.pt", weights_only=True)
    assert saved["in_channels"] == 8 + 1 + 6
    assert np.isfinite([row["train_loss"] for row in stats["log"]]).all()
    events = EventAccumulator(str(tmp_path / "cv" / "tensorboard"))
    events.Reload()  # the same curves as log.csv, as TensorBoard scalars
    assert [e.value for e in events.Scalars("train_loss")] == pytest.approx([row["train_loss"] for row in stats["log"]])


def test_aligned_crops_turn_any_heading_to_plus_col() -> None:
    steps = torch.arange(8.0)[:, None]
    paths = torch.stack([steps * torch.tensor([0.1, 0.0]), steps * torch.tensor([-0.06, 0.08])]) + 3.0  # 0.1 m/step
    maps = SceneMaps(torch.zeros(1, 2, 4, 4), torch.zeros(1, 2), 0.5, ())
    cfg = TINY.model_copy(update={"align_heading": True, "cv_channel": True})
    zeros = torch.zeros(2)
    x, _, _ = goal_model.goal_inputs(paths, torch.zeros(2, dtype=torch.long), maps, cfg, zeros, zeros.bool(), 12)
    assert x.shape == (2, 8 + 1 + 2, 16, 16)
    torch.testing.assert_close(x[0], x[1], atol=1e-5, rtol=0)  # the two headings give one picture
    cv_cell = softargmax(torch.log(x[:, 8].clamp_min(1e-30)))  # 12 · 0.1 m = 2.4 cells ahead of cell 8
    torch.testing.assert_close(cv_cell, torch.tensor([[10.4, 8.0], [10.4, 8.0]]), atol=1e-3, rtol=0)


@pytest.mark.parametrize("damage", ["garbage", "truncated"])
def test_a_damaged_resume_checkpoint_is_set_aside_and_the_build_starts_over(
    inputs: dict, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, damage: str
) -> None:
    warned: list[str] = []
    monkeypatch.setattr(training, "warn", warned.append)
    cfg = TINY.model_copy(update={"epochs": 2})
    reference = _train(inputs, tmp_path, "reference", cfg)
    last = tmp_path / "scratch" / "last.pt"
    last.write_bytes(os.urandom(4096) if damage == "garbage" else last.read_bytes()[:-100])
    damaged = last.read_bytes()
    rerun = _train(inputs, tmp_path, "rerun", cfg)
    assert rerun["resumed_from_epoch"] == 0 and [row["epoch"] for row in rerun["log"]] == [1, 2]
    assert [row["train_loss"] for row in rerun["log"]] == pytest.approx([r["train_loss"] for r in reference["log"]])
    (aside,) = (tmp_path / "scratch").glob("last.pt.damaged-*")
    assert aside.read_bytes() == damaged and len(warned) == 1 and "does not load" in warned[0]
    assert torch.load(last, weights_only=True)["epoch"] == 1  # a new checkpoint of the finished run


@pytest.mark.parametrize("tamper", ["garbage", "pickled function", "cvae model"])
def test_a_tampered_model_file_is_one_integrity_error(tmp_path: Path, tamper: str) -> None:
    path = tmp_path / "model.pt"
    saved = {
        "state_dict": goal_model.build_model(TINY, 14).state_dict(),
        "in_channels": 14,
        "config": TINY.model_dump(),
        "sampling": GoalsConfig(mode_radius_cells=1).model_dump(),
    }
    save_checkpoint(path, saved)
    artifact = type("A", (), {"file": lambda self, name: tmp_path / name})()
    assert goal_model.load_model(artifact, torch.device("cpu"))[1:] == (TINY, GoalsConfig(mode_radius_cells=1))
    if tamper == "garbage":
        path.write_bytes(b"garbage!" + path.read_bytes()[8:])
    elif tamper == "pickled function":
        torch.save({**saved, "hook": print}, path)
    else:
        torch.save({"state_dict": saved["state_dict"], "config": {"d_model": 16, "n_heads": 2}}, path)
    with pytest.raises(IntegrityError) as caught:
        goal_model.load_model(artifact, torch.device("cpu"))
    message = str(caught.value)
    assert message.startswith(f"{path}: not a valid fftool checkpoint, ")
    assert message.endswith("; rebuild it with `fftool train-goal --force`")
    assert "weights_only" not in message and "\n" not in message


def test_supervised_steps_are_evenly_spaced_and_end_at_the_goal() -> None:
    assert goal_model.supervised_steps(TINY, 12) == [12]
    assert goal_model.supervised_steps(TINY.model_copy(update={"supervised_steps": 3}), 12) == [4, 8, 12]
    assert goal_model.supervised_steps(TINY.model_copy(update={"supervised_steps": 12}), 12) == list(range(1, 13))


def test_several_output_maps_a_sharp_target_and_time_reversal_train_and_sample(inputs: dict, tmp_path: Path) -> None:
    cfg = TINY.model_copy(update={"epochs": 2, "supervised_steps": 3, "target_sigma_cells": 0.5, "time_reversal": 0.5})
    stats = _train(inputs, tmp_path, "multi", cfg)
    assert np.isfinite([row["train_loss"] for row in stats["log"]]).all()
    artifact = type("A", (), {"file": lambda self, name: tmp_path / "multi" / name})()
    model, loaded, sampling = goal_model.load_model(artifact, torch.device("cpu"))
    assert loaded == cfg and sampling.k == SAMPLING.k and model.head.out_channels == 3


@pytest.mark.parametrize("reversal", [0.0, 1.0])
def test_time_reversal_makes_the_first_observed_position_the_goal(
    inputs: dict, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, reversal: float
) -> None:
    """Played backwards, a window's goal is where it started: every supervised goal is a first position."""
    targets: list[torch.Tensor] = []
    original = goal.world_to_cells

    def spy(points: torch.Tensor, *args: object) -> torch.Tensor:
        targets.append(points[:, -1].clone())
        return original(points, *args)

    monkeypatch.setattr(goal, "world_to_cells", spy)
    _train(inputs, tmp_path, f"reversal{reversal}", TINY.model_copy(update={"epochs": 1, "time_reversal": reversal}))
    windows = torch.as_tensor(load_agent_windows(inputs["windows"], "zara1", "train").xy, dtype=torch.float32)
    seen = torch.cat(targets)
    end = 0 if reversal else -1
    distance = torch.cdist(seen, windows[:, end], compute_mode="donot_use_mm_for_euclid_dist").min(1).values
    assert seen.shape[0] > 0 and distance.max() < 1e-4


def test_speed_scaling_keeps_the_last_observed_position_and_scales_every_displacement() -> None:
    xy = torch.tensor([[[0.0, 0.0], [1.0, 0.0], [2.0, 1.0], [4.0, 1.0]]])  # observed 3, then one future step
    scaled = goal_model.speed_scaled(xy, torch.tensor([0.5]), obs_len=3)
    expected = torch.tensor([[[1.0, 0.5], [1.5, 0.5], [2.0, 1.0], [3.0, 1.0]]])  # about (2, 1), halved
    assert torch.equal(scaled, expected)


@pytest.mark.parametrize("speed_scale", [1.0, 2.0])
def test_speed_scale_trains_with_factors_drawn_in_its_range(
    inputs: dict, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, speed_scale: float
) -> None:
    """Every training window is scaled by a factor in [1 / speed_scale, speed_scale], spread over that range;
    off (1), no window is touched."""
    factors: list[torch.Tensor] = []
    original = goal.speed_scaled

    def spy(xy: torch.Tensor, scale: torch.Tensor, obs_len: int) -> torch.Tensor:
        factors.append(scale.clone())
        return original(xy, scale, obs_len)

    monkeypatch.setattr(goal, "speed_scaled", spy)
    _train(inputs, tmp_path, f"speed{speed_scale}", TINY.model_copy(update={"epochs": 1, "speed_scale": speed_scale}))
    if speed_scale == 1:
        assert factors == []
        return
    seen = torch.cat(factors)
    assert seen.numel() > 20 and seen.min() >= 1 / speed_scale - 1e-6 and seen.max() <= speed_scale + 1e-6
    assert 0.25 < (seen < 1).float().mean() < 0.75 and seen.min() < 0.6 and seen.max() > 1.6  # log-uniform


def test_map_dropout_gives_a_share_of_training_crops_the_zero_scene(
    raw_tree: Path, built_store: ArtifactStore, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The map-less crops predict and the API give the module, seen in training: about `map_dropout` of the
    crops that have a map lose it; without dropout, only the windows of a source without a map read none."""
    inputs = _inputs(raw_tree, built_store, tmp_path, ("zara1", "zara2"))  # zara2: one of zara1's training scenes
    scenes: list[torch.Tensor] = []
    original = goal.goal_inputs

    def spy(obs: torch.Tensor, scene: torch.Tensor, maps: SceneMaps, *args: object):  # type: ignore[no-untyped-def]
        scenes.append(scene.clone())
        return original(obs, scene, maps, *args)

    monkeypatch.setattr(goal, "goal_inputs", spy)
    trainer = goal._trainer(TINY, SAMPLING, "zara1", inputs["windows"], inputs["maps"], torch.device("cpu"))
    zero = len(trainer.maps.names)
    share: dict[float, float] = {}
    for dropout in (0.0, 0.5):
        scenes.clear()
        (tmp_path / "scratch" / "last.pt").unlink(missing_ok=True)  # a fresh start, not the last run's end
        _train(inputs, tmp_path, f"dropout{dropout}", TINY.model_copy(update={"epochs": 2, "map_dropout": dropout}))
        share[dropout] = (torch.cat(scenes) == zero).float().mean().item()
    without_map = (trainer.train_scene == zero).float().mean().item()
    assert share[0.0] == pytest.approx(without_map, abs=0.1) and share[0.0] < 0.8
    assert share[0.5] == pytest.approx(share[0.0] + (1 - share[0.0]) * 0.5, abs=0.08)


def test_channels_last_weights_compute_what_the_default_layout_computes() -> None:
    """Training runs the U-Net channels-last for speed; the function, and a reload into the default layout,
    stay the same."""
    torch.manual_seed(0)
    model = goal_model.build_model(TINY, 11)
    fast = goal_model.build_model(TINY, 11).to(memory_format=torch.channels_last)
    fast.load_state_dict(model.state_dict())
    assert fast.encoder[0][0].weight.is_contiguous(memory_format=torch.channels_last)
    x = torch.randn(5, 11, TINY.crop_cells, TINY.crop_cells)
    torch.testing.assert_close(fast(x), model(x), atol=1e-5, rtol=1e-5)
    reloaded = goal_model.build_model(TINY, 11)
    reloaded.load_state_dict(fast.state_dict())
    torch.testing.assert_close(reloaded(x), model(x), atol=1e-5, rtol=1e-5)


def test_the_trainer_holds_its_weights_channels_last(inputs: dict) -> None:
    trainer = goal._trainer(TINY, SAMPLING, "zara1", inputs["windows"], inputs["maps"], torch.device("cpu"))
    first = trainer.model.encoder[0][0].weight
    assert first.is_contiguous(memory_format=torch.channels_last) and not first.is_contiguous()


def test_neighbours_are_the_other_rows_of_each_window_and_a_subset_keeps_them() -> None:
    xy = np.arange(6 * 20 * 2, dtype=np.float64).reshape(6, 20, 2)
    found = goal_model.Neighbours.of(xy, np.array([3, 1, 3, 2, 3, 1]))
    assert found.rows.tolist() == [[2, 4], [5, -1], [0, 4], [-1, -1], [0, 2], [1, -1]]
    kept = found.subset(np.array([4, 3]))  # row 4's others, 0 and 2, are not in the subset but stay in view
    observed = kept.observed(slice(None), 8)
    assert observed.shape == (2, 2, 8, 2)
    torch.testing.assert_close(observed[0], torch.as_tensor(xy[[0, 2], :8], dtype=torch.float32))
    assert (observed[1] == goal_model.FAR_M).all()  # a walker alone in its window: padding only
    backwards = kept.observed(slice(None), 8, reverse=torch.tensor([True, False]))
    torch.testing.assert_close(backwards[0], torch.as_tensor(xy[[0, 2], ::-1][:, :8].copy(), dtype=torch.float32))
    assert kept.subset(np.array([1])).observed(slice(None), 8).shape == (1, 1, 8, 2)  # as wide as its crowd


def test_the_neighbour_channels_mark_where_the_others_are_and_where_they_head() -> None:
    """A walker standing at the origin (0.5 m cells, crop 16: cell (8, 8)); another 2 m along x and 1 m along y,
    walking 0.05 m per step along y: it stands at cell (col 12, row 10), its constant-velocity goal 12 · 0.05 m
    further at (12, 11.2). A padding slot draws nothing; two walkers on one cell make at most 1."""
    steps = torch.arange(8.0)[:, None]
    other = torch.tensor([2.0, 1.0]) - (7 - steps) * torch.tensor([0.0, 0.05])
    padding = torch.full((8, 2), goal_model.FAR_M)
    cfg = TINY.model_copy(update={"neighbour_channels": True})
    maps = SceneMaps(torch.zeros(1, 2, 4, 4), torch.zeros(1, 2), 0.5, ())
    zeros, scene = torch.zeros(2), torch.zeros(2, dtype=torch.long)
    others = torch.stack([torch.stack([other, padding]), torch.stack([other, other])])  # (2 crops, 2 slots, 8, 2)
    x, _, _ = goal_model.goal_inputs(torch.zeros(2, 8, 2), scene, maps, cfg, zeros, zeros.bool(), 12, others)
    assert x.shape == (2, 8 + 2 + 2, 16, 16)
    here, heading = x[0, 8], x[0, 9]
    assert here[10, 12] == pytest.approx(1.0) and here.sum() == pytest.approx(2 * torch.pi, rel=1e-3)
    found = softargmax(torch.log(torch.stack([here, heading]).clamp_min(1e-30)))
    torch.testing.assert_close(found, torch.tensor([[12.0, 10.0], [12.0, 11.2]]), atol=1e-3, rtol=0)
    assert x[1, 8].max() == 1.0 and x[1, 8].sum() < x[0, 8].sum() * 2  # summed, then at most 1
    with pytest.raises(ValueError, match="neighbour_channels"):
        goal_model.goal_inputs(torch.zeros(2, 8, 2), scene, maps, cfg, zeros, zeros.bool(), 12)


@pytest.mark.parametrize("reversal", [0.0, 1.0])
def test_training_crops_read_their_windows_other_walkers_played_as_their_own_path(
    inputs: dict, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, reversal: float
) -> None:
    """Every other walker a training crop reads stands where a window of the train part stands at the crop's last
    observed step: step 8 of 20, or step 13 when the window is played backwards; never at the crop's own spot."""
    seen: list[tuple[torch.Tensor, torch.Tensor]] = []
    original = goal.goal_inputs

    def spy(obs: torch.Tensor, *args: object):  # type: ignore[no-untyped-def]
        others = args[-1]
        assert isinstance(others, torch.Tensor)
        seen.append((obs[:, -1].clone(), others[:, :, -1].clone()))
        return original(obs, *args)

    monkeypatch.setattr(goal, "goal_inputs", spy)
    cfg = TINY.model_copy(update={"epochs": 1, "time_reversal": reversal, "neighbour_channels": True})
    _train(inputs, tmp_path, f"others{reversal}", cfg)
    saved = torch.load(tmp_path / f"others{reversal}" / "model.pt", weights_only=True)
    assert saved["in_channels"] == 8 + 2 + 6
    windows = torch.as_tensor(load_agent_windows(inputs["windows"], "zara1", "train").xy, dtype=torch.float32)
    step = 12 if reversal else 7
    real = [others[:, :, 0] < goal_model.FAR_M for _, others in seen]
    points = torch.cat([others[keep] for (_, others), keep in zip(seen, real)])
    assert len(points) > sum(len(own) for own, _ in seen)  # the tiny data's windows hold several walkers
    distance = torch.cdist(points, windows[:, step], compute_mode="donot_use_mm_for_euclid_dist").min(1).values
    assert distance.max() < 1e-4
    apart = [(others - own[:, None]).norm(dim=-1)[keep] for (own, others), keep in zip(seen, real)]
    assert torch.cat(apart).min() > 0  # a crop's others never include itself
