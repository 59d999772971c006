"""Prediction metrics: minADE_K, minFDE_K, the collision count NC (ForceFormer §IV-C), and the field's
two other collision metrics: COL (EigenTrajectory / SingularTrajectory) and Col-II (Trajnet++).

Every function works on padded windows: predictions (B, K, A, T, 2), ground truth (B, A, T, 2) and the
agent mask (B, A), all in metres. Distances are unsquared Euclidean (the paper prints ‖·‖², a typo
relative to every implementation). Definitions and pitfalls: docs/metrics.md.

Worked example: one agent, K = 2 samples that miss the truth by 1 m and 3 m at every step gives minADE =
minFDE = 1 m; two agents whose samples miss by (1 m, 3 m) and (3 m, 1 m) have minADE 1 m each but JADE 2 m
(one sample index for the whole window: the joint metrics of Weng et al. 2023); two agents whose best-ADE
samples are 0.05 m apart at 3 steps give NC = 6 ordered pairs-steps (3 unordered), since the paper's sum
runs over m ≠ n. COL and Col-II use their sources' own thresholds and interpolation, not γ, so that the
numbers compare with published ones.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
import torch
from torch import Tensor


@dataclass(frozen=True)
class AgentMetrics:
    """Per agent-window results of one batch, (B, A) each; padded slots hold zeros."""

    min_ade: Tensor  # min over K of the mean over steps of ‖ŷ - y‖
    min_fde: Tensor  # min over K of ‖ŷ_T - y_T‖ (independent of the ADE minimum)
    best_k: Tensor  # the sample with the smallest ADE (long)
    collisions: Tensor  # (other agent, step) pairs closer than γ, best-ADE samples of both (paper)
    joint_collisions: Tensor  # the same with one sample per window: the one with the smallest summed ADE
    joint_ade: Tensor  # ADE of that sample, the window's joint best: their mean over agent-windows is JADE
    joint_fde: Tensor  # FDE of the window's sample with the smallest summed FDE: their mean is JFDE
    col: Tensor  # COL: % of the K samples within COL_THRESHOLD_M of another agent's same-index sample
    col_gt: Tensor  # Col-II: 1 if the best-ADE sample comes within COL_GT_THRESHOLD_M of a neighbour's truth


# COL as in EigenTrajectory's and SingularTrajectory's utils/metrics.py (compute_batch_col): 4 points per
# step (num_interp), 0.2 m, and only the first 3 * 4 + 2 = 14 points of the dense path (their slice), i.e.
# the first 3.25 steps after the first predicted position.
COL_THRESHOLD_M: Final = 0.2
COL_PARTS: Final = 4
COL_POINTS: Final = 3 * COL_PARTS + 2
# Col-II as in Trajnet++ (trajnetplusplustools metrics.collision): person_radius 0.1 m, so centres within
# 2 × 0.1 m collide (<=), on segments split in inter_parts = 2 (the midpoint added).
COL_GT_THRESHOLD_M: Final = 0.2
COL_GT_PARTS: Final = 2


def displacement(pred: Tensor, truth: Tensor) -> Tensor:
    """‖ŷ - y‖ per sample, agent and step: (B, K, A, T)."""
    return torch.linalg.vector_norm(pred - truth[:, None], dim=-1)


def ade_fde(pred: Tensor, truth: Tensor) -> tuple[Tensor, Tensor]:
    """ADE and FDE of every sample and agent, (B, K, A) each; minADE_K / minFDE_K are their minima over K."""
    error = displacement(pred, truth)  # (B, K, A, T)
    return error.mean(-1), error[..., -1]


def goal_fde(goals: Tensor, truth: Tensor) -> tuple[Tensor, Tensor]:
    """Per agent (B,): FDE@K of K goals (B, K, 2), the min over K of ‖ĝ_k − g‖, and FDE@1, the first goal's.

    A goal is a one-step prediction of the end point, so this is minFDE_K (and its first sample's error).
    """
    errors = displacement(goals[:, :, None, None], truth[:, None, None])[:, :, 0, 0]  # (B, K)
    return errors.min(-1).values, errors[:, 0]


def _pairs(agent_mask: Tensor) -> Tensor:
    """(B, A, A) True for two different real agents of the same window."""
    A = agent_mask.shape[1]
    eye = torch.eye(A, dtype=torch.bool, device=agent_mask.device)
    return agent_mask[:, :, None] & agent_mask[:, None, :] & ~eye


def pair_contacts(paths: Tensor, agent_mask: Tensor, threshold_m: float) -> Tensor:
    """For each agent, the number of (other real agent, step) pairs closer than threshold: (B, A).

    paths (B, A, T, 2). Summing the result over agents counts ordered pairs (each contact twice).
    """
    gaps = torch.cdist(paths.transpose(1, 2), paths.transpose(1, 2))  # (B, T, A, A)
    close = (gaps < threshold_m) & _pairs(agent_mask)[:, None]
    return close.sum((1, 3)) * agent_mask


def interpolate(paths: Tensor, parts: int) -> Tensor:
    """(..., T, 2) -> (..., parts·(T−1)+1, 2): each step split into `parts` equal pieces, both ends kept.

    Collisions between two samples can happen between time steps; both COL and Col-II look there.
    """
    fraction = torch.arange(parts, dtype=paths.dtype, device=paths.device) / parts  # (parts,)
    start, step = paths[..., :-1, None, :], (paths[..., 1:, :] - paths[..., :-1, :])[..., None, :]
    dense = (start + fraction[:, None] * step).flatten(-3, -2)  # (..., (T-1)·parts, 2)
    return torch.cat([dense, paths[..., -1:, :]], dim=-2)


def _exact_cdist(a: Tensor, b: Tensor) -> Tensor:
    """cdist without the matrix-product shortcut, so a threshold test matches the reference to the float."""
    return torch.cdist(a, b, compute_mode="donot_use_mm_for_euclid_dist")


def col_rate(pred: Tensor, agent_mask: Tensor) -> Tensor:
    """COL per agent (B, A), in %: the share of its K samples that come within COL_THRESHOLD_M (strictly)
    of another real agent's sample with the same index, anywhere on the first COL_POINTS points of the
    paths interpolated at COL_PARTS points per step. pred (B, K, A, T, 2)."""
    dense = interpolate(pred, COL_PARTS)[..., :COL_POINTS, :].transpose(2, 3)  # (B, K, D, A, 2)
    closest = _exact_cdist(dense, dense).amin(2)  # (B, K, A, A) over the dense points
    hit = ((closest < COL_THRESHOLD_M) & _pairs(agent_mask)[:, None]).any(-1)  # (B, K, A)
    return hit.to(pred.dtype).mean(1) * 100 * agent_mask


def gt_collisions(paths: Tensor, truth: Tensor, agent_mask: Tensor) -> Tensor:
    """Col-II per agent (B, A), 0 or 1: whether its path (B, A, T, 2) comes within COL_GT_THRESHOLD_M
    (inclusive) of another real agent's ground truth (B, A, T, 2), both split at COL_GT_PARTS per step."""
    mine = interpolate(paths, COL_GT_PARTS).transpose(1, 2)  # (B, D, A, 2)
    theirs = interpolate(truth, COL_GT_PARTS).transpose(1, 2)
    closest = _exact_cdist(mine, theirs).amin(1)  # (B, A, A): my path against their truth
    return ((closest <= COL_GT_THRESHOLD_M) & _pairs(agent_mask)).any(-1).long()


def agent_metrics(pred: Tensor, truth: Tensor, agent_mask: Tensor, threshold_m: float) -> AgentMetrics:
    """minADE_K, minFDE_K, both NC counts (at γ = threshold_m), COL and Col-II for each real agent."""
    ade, fde = ade_fde(pred, truth)  # (B, K, A)
    min_ade, best_k = ade.min(1)
    B, K, A, T, _ = pred.shape
    index = best_k[:, None, :, None, None].expand(B, 1, A, T, 2)
    best = pred.gather(1, index)[:, 0]  # (B, A, T, 2) each agent's best-ADE sample
    windows = torch.arange(B, device=pred.device)
    joint_k = (ade * agent_mask[:, None]).sum(-1).argmin(1)  # (B,) the window's best joint sample
    joint_final_k = (fde * agent_mask[:, None]).sum(-1).argmin(1)  # (B,) the same by FDE
    joint = pred[windows, joint_k]
    mask = agent_mask.to(pred.dtype)
    return AgentMetrics(
        min_ade=min_ade * mask,
        min_fde=fde.min(1).values * mask,
        best_k=best_k * agent_mask,
        collisions=pair_contacts(best, agent_mask, threshold_m),
        joint_collisions=pair_contacts(joint, agent_mask, threshold_m),
        joint_ade=ade[windows, joint_k] * mask,
        joint_fde=fde[windows, joint_final_k] * mask,
        col=col_rate(pred, agent_mask),
        col_gt=gt_collisions(best, truth, agent_mask),
    )


def collision_count(per_agent: Tensor | np.ndarray, pairs: str = "ordered") -> int:
    """NC from per-agent contact counts (a tensor or an array): the paper's ordered sum, or unordered (half)."""
    total = int(per_agent.sum())
    if pairs == "ordered":
        return total
    if pairs == "unordered":
        return total // 2
    raise ValueError(f"pairs must be 'ordered' or 'unordered', not {pairs!r}")
