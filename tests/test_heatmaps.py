"""Goal rasters and the U-Net: geometry round trips, peaks, softargmax, sampling, shapes."""

from __future__ import annotations

import math

import pytest
import torch

from fftool.models import GoalUNet
from fftool.science.heatmaps import (
    cells_to_world,
    refine_mode,
    render,
    rotation,
    sample_goals,
    sample_scene,
    softargmax,
    world_to_cells,
)


def test_crop_transform_round_trips_and_centres() -> None:
    g = torch.Generator().manual_seed(0)
    center = torch.rand(5, 2, generator=g) * 10
    R = rotation(torch.rand(5, generator=g) * 2 * math.pi, torch.tensor([0, 1, 0, 1, 1]))
    points = torch.rand(5, 7, 2, generator=g) * 20 - 5
    cells = world_to_cells(points, center, R, 0.5, 48)
    torch.testing.assert_close(cells_to_world(cells, center, R, 0.5, 48), points)
    middle = world_to_cells(center[:, None], center, R, 0.5, 48)
    torch.testing.assert_close(middle, torch.full_like(middle, 24.0))  # a cell centre, not a corner (23.5)
    torch.testing.assert_close(R @ R.transpose(1, 2), torch.eye(2).expand(5, 2, 2))


@pytest.mark.parametrize("size", [48, 47])
def test_a_standing_pedestrians_ideal_map_gives_its_goal_exactly(size: int) -> None:
    """The crop centre is a cell centre: the ideal map of a pedestrian who stays put peaks on one cell, so
    every refinement of the mode returns the last observed position (on a cell corner it was 0.12 m off)."""
    center, R = torch.tensor([[3.3, -1.7]]), rotation(torch.tensor([0.4]), torch.tensor([0]))
    cells = world_to_cells(center[:, None], center, R, 0.5, size)
    logits = torch.logit(render(cells, size, 1.0)[:, 0].clamp(1e-6, 1 - 1e-6))
    for radius in (0, 1, 2):
        mode = sample_goals(logits, 1, mode_radius=radius)
        torch.testing.assert_close(cells_to_world(mode, center, R, 0.5, size), center[:, None], atol=1e-5, rtol=0)


def test_heatmap_peak_is_at_the_right_cell() -> None:
    cells = torch.tensor([[[7.0, 12.0], [0.0, 31.0]]])
    maps = render(cells, 32, 1.0)
    for p in range(2):
        flat = maps[0, p].argmax()
        assert (int(flat % 32), int(flat // 32)) == tuple(int(v) for v in cells[0, p])
        assert maps[0, p].max() == pytest.approx(1.0)


@pytest.mark.parametrize("goal", [(10.3, 20.7), (3.0, 40.2), (44.5, 5.5)])
def test_softargmax_recovers_a_planted_peak(goal: tuple[float, float]) -> None:
    logits = torch.log(render(torch.tensor([[goal]]), 48, 1.0)[:, 0])  # a Gaussian peak at a sub-cell position
    torch.testing.assert_close(softargmax(logits), torch.tensor([goal]), atol=0.05, rtol=0)


@pytest.mark.parametrize("goal", [(10.3, 20.7), (2.2, 40.4), (24.5, 24.5)])
def test_the_local_softargmax_mode_finds_a_sub_cell_peak_that_the_argmax_misses(goal: tuple[float, float]) -> None:
    truth = torch.tensor([goal])
    logits = torch.logit(render(truth[:, None], 48, 1.0)[:, 0].clamp(1e-6, 1 - 1e-6))
    logits[0, 5, 40] += 2.0  # a second, smaller bump far away must not pull the mode toward it
    argmax_error = torch.linalg.vector_norm(refine_mode(logits, 0) - truth)
    local_error = torch.linalg.vector_norm(refine_mode(logits, 2) - truth)
    assert local_error < 0.12 and local_error < argmax_error + 1e-6


def test_scene_sampling_follows_the_world_grid() -> None:
    # A 20 × 30 cell map (0.5 m cells, origin (-2, 1)) with one hot cell at row 4, col 9.
    scene = torch.zeros(1, 1, 20, 30)
    scene[0, 0, 4, 9] = 1.0
    origin = torch.tensor([[-2.0, 1.0]])
    hot_world = origin[0] + (torch.tensor([9.0, 4.0]) + 0.5) * 0.5  # the hot cell's centre in metres
    center = hot_world[None] + torch.tensor([[1.0, -0.5]])
    R = rotation(torch.tensor([0.7]), torch.tensor([1]))
    crop = sample_scene(scene, origin, 0.5, torch.tensor([0]), center, R, 0.5, 16)
    expected = world_to_cells(hot_world[None, None], center, R, 0.5, 16)[0, 0]
    flat = crop[0, 0].argmax()
    found = torch.tensor([float(flat % 16), float(flat // 16)])
    assert torch.linalg.vector_norm(found - expected) < 1.0


def test_sampling_gives_k_distinct_goals_with_the_mode_first() -> None:
    g = torch.Generator().manual_seed(1)
    logits = 8 * render(torch.tensor([[[10.0, 10.0], [30.0, 25.0]]]), 40, 2.0).amax(1) - 4
    logits[0, 25, 30] += 1.0  # the second bump is the mode
    goals = sample_goals(logits, 20, generator=g)
    assert goals.shape == (1, 20, 2)
    assert goals[0, 0].tolist() == [30.0, 25.0]
    assert len({tuple(v) for v in goals[0].round(decimals=4).tolist()}) == 20
    near = lambda c: (torch.linalg.vector_norm(goals[0] - torch.tensor(c), dim=-1) < 6).sum()  # noqa: E731
    assert near([10.0, 10.0]) >= 2 and near([30.0, 25.0]) >= 2  # both modes are covered
    plain = sample_goals(logits, 5, method="multinomial", generator=g)
    assert plain.shape == (1, 5, 2) and plain[0, 0].tolist() == [30.0, 25.0]


@pytest.mark.parametrize("size", [(33, 47), (48, 48), (17, 9)])
def test_unet_output_matches_any_input_size(size: tuple[int, int]) -> None:
    net = GoalUNet(in_channels=5, widths=(4, 8, 8, 16))
    out = net(torch.rand(2, 5, *size))
    assert out.shape == (2, 1, *size)
    assert GoalUNet(in_channels=5, widths=(4, 8), out_channels=3)(torch.rand(2, 5, *size)).shape == (2, 3, *size)
    out.sum().backward()
    assert all(p.grad is not None for p in net.parameters())
