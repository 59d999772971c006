"""Metrics on hand-made predictions: minADE/minFDE with independent minima, NC and its variants."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from fftool.science.metrics import agent_metrics, col_rate, collision_count, gt_collisions


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


def _col_reference(pred: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """COL written out with loops from EigenTrajectory's definition (utils/metrics.py compute_batch_col):
    4 points per step, the first 14 dense points, strictly below 0.2 m, same sample index, in %."""
    B, K, A, T, _ = pred.shape
    out = np.zeros((B, A))
    for b in range(B):
        for n in range(A):
            if not mask[b, n]:
                continue
            hits = 0
            for k in range(K):
                hit = False
                for m in range(A):
                    if m == n or not mask[b, m]:
                        continue
                    for j in range(min(14, 4 * (T - 1) + 1)):
                        t, f = divmod(j, 4)
                        here = pred[b, k, n, t] + (f / 4) * (pred[b, k, n, min(t + 1, T - 1)] - pred[b, k, n, t])
                        there = pred[b, k, m, t] + (f / 4) * (pred[b, k, m, min(t + 1, T - 1)] - pred[b, k, m, t])
                        hit |= bool(np.linalg.norm(here - there) < 0.2)
                hits += hit
            out[b, n] = 100 * hits / K
    return out


def test_col_matches_a_loop_reference_on_random_crowds() -> None:
    gen = torch.Generator().manual_seed(0)
    pred = torch.rand(3, 5, 4, 12, 2, generator=gen) * 1.5  # crowded: many contacts, many misses
    mask = torch.tensor([[True, True, True, False], [True, True, False, False], [True, False, False, False]])
    col = col_rate(pred, mask)
    np.testing.assert_allclose(col.numpy(), _col_reference(pred.numpy(), mask.numpy()), atol=1e-4)
    assert 0 < col[mask].mean() < 100 and (col[~mask] == 0).all()


def test_col_counts_samples_with_a_contact_at_the_same_index_only() -> None:
    """Agent 1 walks 3 m from agent 0. Sample 0: it comes 0.1 m close at step 1 (a collision). Sample 2 of
    agent 0 walks exactly on sample 1 of agent 1, a different index (no collision)."""
    pred = torch.zeros(1, 3, 2, 12, 2)
    pred[0, :, 1, :, 1] = 3.0
    pred[0, 0, 1, 1, 1] = 0.1
    pred[0, 2, 0, :, 1] = 6.0
    pred[0, 1, 1, :, 1] = 6.0
    col = col_rate(pred, torch.ones(1, 2, dtype=torch.bool))
    assert col.tolist() == [[pytest.approx(100 / 3), pytest.approx(100 / 3)]]


def test_col_sees_a_crossing_between_two_steps_and_only_in_the_first_14_dense_points() -> None:
    """The two agents swap places in one step: 2 m apart at both steps, 0 m at the half step."""
    pred = torch.zeros(1, 1, 2, 12, 2)
    pred[0, 0, 0, 1:, 0] = 2.0  # agent 0: (0, 0) then (2, 0)
    pred[0, 0, 1, 0, 0] = 2.0  # agent 1: (2, 0), (0, 0), then far away
    pred[0, 0, 1, 2:] = 5.0
    mask = torch.ones(1, 2, dtype=torch.bool)
    assert col_rate(pred, mask).tolist() == [[100.0, 100.0]]
    assert agent_metrics(pred, pred[:, 0], mask, 0.1).collisions.sum() == 0  # NC sees no contact at any step
    # Agent 1 approaches agent 0 (at the origin) at 0.8 m per step from step 3: 0.05 m away at 3.25 steps
    # (dense point 13, the last one COL reads) when it starts 0.25 m away, and only at 3.5 steps (dense
    # point 14, not read) when it starts 0.45 m away.
    for start, expected in ((0.25, 100.0), (0.45, 0.0)):
        late = torch.zeros(1, 1, 2, 12, 2)
        late[0, 0, 1, :, 1] = 5.0
        late[0, 0, 1, 3:, 1] = start - 0.8 * torch.arange(9.0)
        assert col_rate(late, mask).tolist() == [[expected, expected]], start


def test_col_gt_compares_the_best_sample_with_the_neighbours_truth_between_steps() -> None:
    """Agent 0's best sample crosses agent 1's true path at a half step; its own truth never counts."""
    truth = torch.zeros(1, 2, 3, 2)
    truth[0, 0, :, 0] = torch.tensor([0.0, 2.0, 4.0])  # agent 0 walks +x
    truth[0, 1, :, 0] = torch.tensor([2.0, 0.0, -2.0])  # agent 1 walks -x: they swap at t = 0.5
    truth[0, 1, :, 1] = 1.0  # ... 1 m to the side, so the truths never collide
    pred = truth[:, None].clone()  # K = 1, every sample exact: Col-II of the truth itself
    mask = torch.ones(1, 2, dtype=torch.bool)
    assert agent_metrics(pred, truth, mask, 0.1).col_gt.tolist() == [[0, 0]]
    pred[0, 0, 1, :, 1] = 0.0  # agent 1's prediction moves onto agent 0's line: crosses agent 0's truth at t=0.5
    m = agent_metrics(pred, truth, mask, 0.1)
    assert m.col_gt.tolist() == [[0, 1]]  # agent 1's path hits agent 0's truth; agent 0's path is its truth
    assert gt_collisions(truth, truth, torch.tensor([[True, False]])).sum() == 0  # padded neighbours do not count


def test_joint_metrics_take_one_sample_index_for_the_whole_window() -> None:
    """The worked example of science/metrics.py: errors (1 m, 3 m) and (3 m, 1 m) give minADE 1 m but JADE 2 m."""
    truth = torch.zeros(1, 2, 12, 2)
    truth[0, 1, :, 1] = 10.0  # far apart: no contacts
    miss = torch.tensor([[1.0, 3.0], [3.0, 1.0]])  # (agent, sample) → metres off in x at every step
    pred = truth[:, None].repeat(1, 2, 1, 1, 1)  # (1, K = 2, A = 2, T, 2)
    pred[0, :, :, :, 0] += miss.T[:, :, None]
    mask = torch.ones(1, 2, dtype=torch.bool)
    m = agent_metrics(pred, truth, mask, 0.1)
    assert m.min_ade.tolist() == [[1.0, 1.0]] and m.min_fde.tolist() == [[1.0, 1.0]]
    assert m.joint_ade.mean().item() == pytest.approx(2.0) and m.joint_fde.mean().item() == pytest.approx(2.0)
    # Agent 0's sample 1 ends exactly on the truth: sample 1 now wins by FDE (0 + 1 < 1 + 3) but not by ADE
    # (its ADE sum 3 - 3/12 + 1 = 3.75 < 4: it wins there too), so both joint minima move to sample 1.
    pred[0, 1, 0, -1, 0] = 0.0
    m = agent_metrics(pred, truth, mask, 0.1)
    assert m.joint_fde.tolist() == [[0.0, 1.0]]
    assert m.joint_ade[0].tolist() == pytest.approx([3.0 * 11 / 12, 1.0])
    assert (m.joint_ade >= m.min_ade).all()  # agent-weighted JADE is never below minADE
