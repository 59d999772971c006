"""Metrics on hand-made predictions: minADE/minFDE with independent minima, NC and its variants."""

from __future__ import annotations

import pytest
import torch

from fftool.science.metrics import agent_metrics, collision_count


def _line(x0: float, y: float, dx: float = 0.0, steps: int = 4) -> torch.Tensor:
    """A path along x from x0 with step dx at height y: (T, 2)."""
    xs = x0 + dx * torch.arange(1, steps + 1, dtype=torch.float32)
    return torch.stack([xs, torch.full_like(xs, y)], -1)


def test_min_ade_and_min_fde_are_taken_independently() -> None:
    truth = _line(0, 0, 1)[None, None]  # (B=1, A=1, T=4, 2)
    # Sample 0: off by 1 m at every step (ADE 1, FDE 1). Sample 1: exact until the end, off 3 m at the
    # last step (ADE 0.75, FDE 3). Best ADE is sample 1, best FDE is sample 0.
    s0 = truth[0, 0] + torch.tensor([0.0, 1.0])
    s1 = truth[0, 0].clone()
    s1[-1, 1] += 3.0
    pred = torch.stack([s0, s1])[None, :, None]  # (1, K=2, 1, T, 2)
    m = agent_metrics(pred, truth, torch.ones(1, 1, dtype=torch.bool), 0.1)
    assert m.min_ade.item() == pytest.approx(0.75)
    assert m.min_fde.item() == pytest.approx(1.0)
    assert m.best_k.item() == 1


def test_padded_agents_do_not_count() -> None:
    truth = torch.zeros(1, 2, 4, 2)
    pred = torch.ones(1, 3, 2, 4, 2)  # padded agent 1 sits on agent 0's predictions too
    mask = torch.tensor([[True, False]])
    m = agent_metrics(pred, truth, mask, 0.1)
    assert m.min_ade[0, 1] == 0 and m.collisions.sum() == 0
    assert m.min_ade[0, 0].item() == pytest.approx(2**0.5)


def test_a_planted_collision_is_counted_per_the_paper_and_its_variants() -> None:
    """Two agents 0.06 m apart at steps 0-1 and 1 m apart at steps 2-3; the best-ADE samples follow
    the truth within 1 mm, a second sample per agent stays far away."""
    truth = torch.zeros(1, 2, 4, 2)
    truth[0, :, :, 0] = torch.arange(4.0)
    truth[0, 1, :, 1] = torch.tensor([0.06, 0.06, 1.0, 1.0])
    near = truth + 0.001
    far = truth + torch.tensor([0.0, 5.0]) * torch.tensor([1.0, -1.0])[:, None, None]  # agents apart
    pred = torch.stack([far[0], near[0]])[None]  # (1, K=2, A=2, T=4, 2): the best sample is k=1
    m = agent_metrics(pred, truth, torch.ones(1, 2, dtype=torch.bool), threshold_m=0.1)
    assert m.best_k.tolist() == [[1, 1]]
    assert m.collisions.tolist() == [[2, 2]]
    assert collision_count(m.collisions, "ordered") == 4  # the paper's sum over m != n
    assert collision_count(m.collisions, "unordered") == 2
    assert agent_metrics(pred, truth, torch.ones(1, 2, dtype=torch.bool), threshold_m=0.05).collisions.sum() == 0


def test_collisions_at_the_same_step_only_and_strictly_below_gamma() -> None:
    truth = torch.zeros(1, 3, 3, 2)
    paths = torch.zeros(1, 1, 3, 3, 2)  # K=1, A=3, T=3
    paths[0, 0, 1, :, 0] = torch.tensor([0.05, 0.5, 0.1])  # agent 1: 0.05 m, 0.5 m, exactly γ from agent 0
    paths[0, 0, 2, :, 0] = torch.tensor([5.0, 5.0, 5.0])  # agent 2 far away
    m = agent_metrics(paths, truth, torch.ones(1, 3, dtype=torch.bool), threshold_m=0.1)
    assert m.collisions.tolist() == [[1, 1, 0]]  # only step 0 (0.1 m is not < 0.1 m)
    assert collision_count(m.collisions) == 2


def test_joint_variant_uses_one_sample_per_window() -> None:
    truth = torch.zeros(1, 2, 2, 2)
    truth[0, 1, :, 0] = 1.0  # agent 1 stands 1 m from agent 0
    pred = truth[:, None].repeat(1, 2, 1, 1, 1)
    # Sample 1 moves agent 1 onto agent 0 (a collision) but is agent 0's best by far; sample 0 is the
    # better joint sample. Per-agent best-ADE: agent 0 -> sample 1 (exact), agent 1 -> sample 0 (exact).
    pred[0, 0, 0] += 0.5
    pred[0, 1, 1, :, 0] = 0.0
    m = agent_metrics(pred, truth, torch.ones(1, 2, dtype=torch.bool), 0.1)
    assert m.best_k.tolist() == [[1, 0]]
    assert m.collisions.sum() == 0  # per-agent best samples keep 1 m apart
    assert m.joint_collisions.sum() == 0  # joint best is sample 0: agent 0 shifted 0.5 m, agent 1 at 1 m
    pred[0, 0, 0] = truth[0, 0] + torch.tensor([0.95, 0.0])  # now sample 0 puts agent 0 on agent 1
    m = agent_metrics(pred, truth, torch.ones(1, 2, dtype=torch.bool), 0.1)
    assert collision_count(m.joint_collisions) == 4 and m.collisions.sum() == 0
