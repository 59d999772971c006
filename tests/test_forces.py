"""The forces stage: causality, alignment with the windows, agreement with a direct computation, CLI."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import torch
from typer.testing import CliRunner

from fftool import pipeline
from fftool.artifacts.schema import AGENT_WINDOWS_FILE, FORCES_ARRAYS, FORCES_INDEX_FILE, WINDOWS_FILE
from fftool.artifacts.store import ArtifactStore
from fftool.cli import app
from fftool.config import ForcesConfig, load_config
from fftool.dataset.scene_images import apply_homography, read_homography
from fftool.science.social_forces import finite_difference_velocity, group_ids, social_forces, window_forces

OBS, L = 8, 20


def _random_batch(seed: int, b: int = 6, n: int = 7):
    """Random walkers, some absent at the start or the end, with random DBSCAN-like labels."""
    g = torch.Generator().manual_seed(seed)
    start = torch.rand(b, n, 1, 2, generator=g) * 6
    steps = torch.randn(b, n, L, 2, generator=g).mul(0.15).add(torch.tensor([0.4, 0.1])).cumsum(dim=2)
    position = (start + steps).double()
    present = torch.ones(b, n, L, dtype=torch.bool)
    present[0, 1, :3] = False  # appears during the observation
    present[1, 2, OBS - 1 :] = False  # leaves at the last observed step
    present[2, 3, OBS + 2 :] = False  # leaves in the future
    present[3, 4, :OBS] = False  # appears in the future
    present[4, 2, : OBS - 1] = False  # appears at the last observed step: no backward difference there
    present[:, -1] = False  # a padded slot
    labels = torch.randint(-1, 3, (b, n, OBS), generator=g)
    labels = torch.where(present[..., :OBS], labels, torch.full_like(labels, -1))
    return position, present, labels


@pytest.mark.parametrize("neighbours", ["valid", "present"])
@pytest.mark.parametrize("speed_rule", ["mean_observed", "current", "constant"])
def test_observed_step_features_do_not_see_the_future(neighbours: str, speed_rule: str) -> None:
    cfg = ForcesConfig(neighbours=neighbours, desired_speed=speed_rule)
    position, present, labels = _random_batch(0)
    goal = position[:, :, -1]
    heading = ~present.all(dim=-1) if neighbours == "present" else None
    before = window_forces(position, present, goal, labels, cfg, dt_s=0.4, obs_len=OBS, heading=heading)
    perturbed = position.clone()
    perturbed[:, :, OBS:-1] += torch.randn_like(perturbed[:, :, OBS:-1]) * 3.0  # every future step but the goal
    after = window_forces(perturbed, present, goal, labels, cfg, dt_s=0.4, obs_len=OBS, heading=heading)
    for name in ("f_dr", "f_re", "velocity", "speed0"):
        assert torch.equal(getattr(before, name)[:, :, :OBS], getattr(after, name)[:, :, :OBS]), name
    assert torch.equal(group_ids(before.groups), group_ids(after.groups))
    assert not torch.equal(before.f_re[:, :, OBS:-1], after.f_re[:, :, OBS:-1])  # the test can fail


def test_goal_is_the_only_future_input() -> None:
    position, present, labels = _random_batch(1)
    before = window_forces(position, present, position[:, :, -1], labels, ForcesConfig(), dt_s=0.4, obs_len=OBS)
    moved_goal = position[:, :, -1] + 1.0
    after = window_forces(position, present, moved_goal, labels, ForcesConfig(), dt_s=0.4, obs_len=OBS)
    assert not torch.equal(before.f_dr[:, :, :OBS], after.f_dr[:, :, :OBS])


@pytest.fixture
def built(raw_tree: Path, built_store: ArtifactStore) -> dict:
    cfg = load_config(None, [f"data.raw_dir={str(raw_tree)!r}"])
    return pipeline.run(cfg, built_store, ["forces"])


def test_arrays_align_with_agent_windows(built: dict) -> None:
    forces, windows = built["forces"], built["windows"]
    index = pq.read_table(forces.file(FORCES_INDEX_FILE)).to_pandas()
    agents = pq.read_table(windows.file(AGENT_WINDOWS_FILE)).to_pandas()
    assert index[["window_id", "ped_id"]].equals(agents[["window_id", "ped_id"]])
    assert (index["benchmark"].astype(str) == agents["benchmark"].astype(str)).all()
    xy = np.stack(agents["xy"].to_numpy()).reshape(len(agents), L, 2)
    arrays = {name: np.load(forces.file(file), mmap_mode="r") for name, file in FORCES_ARRAYS.items()}
    assert isinstance(arrays["f_dr"], np.memmap)
    assert arrays["f_dr"].shape == arrays["f_re"].shape == arrays["velocity"].shape == (len(agents), L, 2)
    np.testing.assert_allclose(arrays["goal"], xy[:, -1], rtol=1e-6)
    np.testing.assert_allclose(arrays["velocity"][:, 5], (xy[:, 5] - xy[:, 4]) / 0.4, rtol=0, atol=1e-5)
    assert arrays["group_id"].dtype == np.int32


def test_stage_equals_a_direct_computation_per_window(built: dict) -> None:
    windows = built["windows"]
    agents = pq.read_table(windows.file(AGENT_WINDOWS_FILE)).to_pandas()
    table = pq.read_table(windows.file(WINDOWS_FILE)).to_pandas()
    arrays = {name: np.load(built["forces"].file(file)) for name, file in FORCES_ARRAYS.items()}
    crowded = table.sort_values("n_agents").iloc[-1]
    rows = np.flatnonzero(
        (agents["benchmark"] == crowded["benchmark"]).to_numpy()
        & (agents["part"] == crowded["part"]).to_numpy()
        & (agents["window_id"] == crowded["window_id"]).to_numpy()
    )
    position = torch.tensor(np.stack(agents["xy"].to_numpy()[rows]).reshape(1, len(rows), L, 2))
    present = torch.ones(1, len(rows), L, dtype=torch.bool)
    velocity = finite_difference_velocity(position, present, 0.4, OBS)
    speed0 = torch.linalg.vector_norm(velocity[..., :OBS, :], dim=-1).mean(-1, keepdim=True).expand(1, len(rows), L)
    gid = torch.tensor(arrays["group_id"][rows])
    groups = ((gid[:, None] == gid[None, :]) & (gid[:, None] >= 0) & ~torch.eye(len(rows), dtype=torch.bool))[None]
    f_dr, f_re = social_forces(position, present, position[:, :, -1], velocity, speed0, groups, ForcesConfig())
    assert len(rows) >= 2
    np.testing.assert_allclose(arrays["f_dr"][rows], f_dr[0].numpy(), rtol=1e-5, atol=1e-5)  # float32 features
    np.testing.assert_allclose(arrays["f_re"][rows], f_re[0].numpy(), rtol=1e-5, atol=1e-5)


def test_summary_and_cache(built: dict, raw_tree: Path, store: ArtifactStore) -> None:
    summary = built["forces"].manifest.stats["summary"]
    assert len(summary) == 15
    assert all(row["mean_abs_f_dr"] > 0 for row in summary)
    cfg = load_config(None, [f"data.raw_dir={str(raw_tree)!r}", "forces.fov_reading='position'"])
    again = pipeline.run(cfg, store, ["forces"])
    assert again["forces"].fingerprint != built["forces"].fingerprint
    assert again["windows"].fingerprint == built["windows"].fingerprint


def test_cli_forces_and_explain_without_scene_image(tmp_path: Path, raw_tree: Path) -> None:
    root = tmp_path / "artifacts"
    runner = CliRunner()
    args = ["forces", "--root", str(root), "--set", f"data.raw_dir={str(raw_tree)!r}"]
    args += ["--set", f"data.scenes_dir={str(tmp_path / 'none')!r}"]
    first = runner.invoke(app, args)
    assert first.exit_code == 1
    assert "Error: no 'tracks' artifact for these parameters" in first.output
    assert "run `fftool ingest` first, with the same -c/--set" in first.output
    assert runner.invoke(app, ["ingest", "--root", str(root), "--raw", str(raw_tree)]).exit_code == 0
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "mean |F_dr|" in result.output
    windows = pq.read_table(next((root / "windows").iterdir()) / WINDOWS_FILE).to_pandas()
    frame = int(windows[(windows["benchmark"] == "zara1") & (windows["part"] == "test")]["t0_frame_id"].iloc[0])
    png = tmp_path / "x.png"
    result = runner.invoke(app, [*args, "--explain", "zara1", str(frame), "--out", str(png)])
    assert result.exit_code == 0, result.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    missing = runner.invoke(app, [*args, "--explain", "zara1", "5"])
    assert missing.exit_code == 1 and "Error: no zara1 test window whose last observed frame is 5" in missing.output
    unknown = runner.invoke(app, [*args, "--explain", "atlantis", "5"])
    assert unknown.exit_code == 1 and "Error: unknown scene 'atlantis'" in unknown.output
    assert runner.invoke(app, [*args, "--device", "tpu"]).exit_code == 2


@pytest.mark.data
def test_homography_round_trip_on_the_real_scenes(real_raw: Path) -> None:
    scenes = real_raw.parent / "scenes"
    for scene in ("eth", "hotel", "univ", "zara1", "zara2"):
        matrix = read_homography(scenes / scene / "world_to_pixel.txt")
        world = np.random.default_rng(0).uniform(0, 10, (50, 2))
        pixels = apply_homography(matrix, world)
        back = apply_homography(np.linalg.inv(matrix), pixels)
        np.testing.assert_allclose(back, world, atol=1e-9)
    ucy = read_homography(scenes / "zara1" / "world_to_pixel.txt")
    np.testing.assert_allclose(apply_homography(ucy, np.array([[0.0, 0.0]])), [[0.0, 576.0]])  # bottom-left
