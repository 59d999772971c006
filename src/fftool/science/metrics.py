"""Prediction metrics: minADE_K, minFDE_K and the collision count NC (ForceFormer §IV-C).

Every function works on padded windows: predictions (B, K, A, T, 2), ground truth (B, A, T, 2) and the
agent mask (B, A), all in metres. Distances are unsquared Euclidean (the paper prints ‖·‖², a typo
relative to every implementation). Definitions and pitfalls: docs/metrics.md.

Worked example: one agent, K = 2 samples that miss the truth by 1 m and 3 m at every step gives
minADE = minFDE = 1 m; two agents whose best-ADE samples are 0.05 m apart at 3 steps give NC = 6
ordered pairs-steps (3 unordered), since the paper's sum runs over m ≠ n.
"""

from __future__ import annotations

from dataclasses import dataclass

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


def pair_contacts(paths: Tensor, agent_mask: Tensor, threshold_m: float) -> Tensor:
    """For each agent, the number of (other real agent, step) pairs closer than threshold: (B, A).

    paths (B, A, T, 2). Summing the result over agents counts ordered pairs (each contact twice).
    """
    gaps = torch.cdist(paths.transpose(1, 2), paths.transpose(1, 2))  # (B, T, A, A)
    A = paths.shape[1]
    pairs = agent_mask[:, :, None] & agent_mask[:, None, :] & ~torch.eye(A, dtype=torch.bool, device=paths.device)
    close = (gaps < threshold_m) & pairs[:, None]
    return close.sum((1, 3)) * agent_mask


def agent_metrics(pred: Tensor, truth: Tensor, agent_mask: Tensor, threshold_m: float) -> AgentMetrics:
    """minADE_K, minFDE_K and both collision counts for each real agent of a batch of windows."""
    ade, fde = ade_fde(pred, truth)  # (B, K, A)
    min_ade, best_k = ade.min(1)
    B, K, A, T, _ = pred.shape
    index = best_k[:, None, :, None, None].expand(B, 1, A, T, 2)
    best = pred.gather(1, index)[:, 0]  # (B, A, T, 2) each agent's best-ADE sample
    joint_k = (ade * agent_mask[:, None]).sum(-1).argmin(1)  # (B,) the window's best joint sample
    joint = pred[torch.arange(B, device=pred.device), joint_k]
    mask = agent_mask.to(pred.dtype)
    return AgentMetrics(
        min_ade=min_ade * mask,
        min_fde=fde.min(1).values * mask,
        best_k=best_k * agent_mask,
        collisions=pair_contacts(best, agent_mask, threshold_m),
        joint_collisions=pair_contacts(joint, agent_mask, threshold_m),
    )


def collision_count(per_agent: Tensor | np.ndarray, pairs: str = "ordered") -> int:
    """NC from per-agent contact counts (a tensor or an array): the paper's ordered sum, or unordered (half)."""
    total = int(per_agent.sum())
    if pairs == "ordered":
        return total
    if pairs == "unordered":
        return total // 2
    raise ValueError(f"pairs must be 'ordered' or 'unordered', not {pairs!r}")
