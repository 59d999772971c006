"""AgentFormer's second stage, the DLow trajectory sampler (Yuan & Kitani 2020; AgentFormer model/dlow.py).

A small Q-net maps each agent's context (from the frozen CVAE's past encoder) to K latent codes
z_k = A_k ⊙ ε + b_k, which the frozen decoder turns into K futures. With `train_w_mean` (AgentFormer's
ETH/UCY setting) z_k = b_k in training and at test, so the K futures are deterministic given the past and
A enters only through the KL term. Its loss: best-of-K reconstruction, a diversity kernel over the K
futures, and a KL to the CVAE's prior clamped below (free bits).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import torch
from torch import Tensor, nn

from fftool.models.forceformer import Gaussian, kl_divergence


class Codes(NamedTuple):
    """The Q-net's K latent distributions per agent: N(b, A²), each (B, A, K, Z)."""

    A: Tensor
    b: Tensor

    def z(self, mean: bool, generator: torch.Generator | None = None, share_eps: bool = True) -> Tensor:
        """(B, A, K, Z) codes: b (`mean`), else A ⊙ ε + b, with one ε shared by every agent and sample
        (`share_eps`) or one per agent."""
        if mean:
            return self.b
        B, A, K, Z = self.b.shape
        shape = (1, 1, 1, Z) if share_eps else (B, A, 1, Z)
        eps = torch.randn(shape, generator=generator, device=self.b.device, dtype=self.b.dtype)
        return self.A * eps + self.b

    def posterior(self) -> Gaussian:
        """N(b, A²) as AgentFormer's q_z_dist_dlow (log A² + 1e-8)."""
        return Gaussian(self.b, (self.A**2 + 1e-8).log())


class QNet(nn.Module):
    """MLP (tanh) on the agent context, then two linear heads to K codes' A and b (AgentFormer: q_mlp [512, 256])."""

    def __init__(self, d_model: int, z_dim: int, k: int, hidden: Sequence[int] = (512, 256)) -> None:
        super().__init__()
        self.k, self.z_dim = k, z_dim
        layers: list[nn.Module] = []
        width = d_model
        for size in hidden:
            layers += [nn.Linear(width, size), nn.Tanh()]
            width = size
        self.mlp = nn.Sequential(*layers)
        self.q_A = nn.Linear(width, k * z_dim)
        self.q_b = nn.Linear(width, k * z_dim)

    def forward(self, agent_context: Tensor) -> Codes:
        B, A, _ = agent_context.shape
        h = self.mlp(agent_context.float())
        return Codes(self.q_A(h).view(B, A, self.k, self.z_dim), self.q_b(h).view(B, A, self.k, self.z_dim))


class DLowLossParts(NamedTuple):
    total: Tensor
    recon: Tensor
    diverse: Tensor
    kl: Tensor
    kl_unclamped: Tensor


def _per_window(values: Tensor, agent_mask: Tensor) -> Tensor:
    """(B, A) per-agent values -> (B,) their sum over real agents / the window's agent count (`normalize`)."""
    return (values * agent_mask).sum(1) / agent_mask.sum(1).clamp_min(1)


def dlow_loss(
    samples: Tensor,
    future: Tensor,
    codes: Codes,
    prior: Gaussian,
    agent_mask: Tensor,
    *,
    recon_weight: float,
    diverse_weight: float,
    d_scale: float,
    kl_weight: float,
    kl_min: float,
) -> DLowLossParts:
    """AgentFormer's DLow loss (model/dlow.py), each term per window as its one-window step computes it, then
    averaged over the batch's windows.

    samples: (B, K, A, T, 2) the K decoded futures; future: (B, A, T, 2) the truth (same frame and units);
    prior: the CVAE's p(z | X) per agent (B, A, Z). recon: per agent the min over K of the squared error summed
    over steps and xy, mean over agents. diverse: per agent the mean over pairs of samples of exp(-d²/d_scale),
    d² the squared distance of their flattened futures, summed over agents / their count. kl: KL(N(b, A²) ‖ p)
    summed over the K codes, dims and agents / their count, clamped below at kl_min.
    """
    mask = agent_mask.float()
    error = ((samples - future[:, None]) ** 2).sum((-1, -2))  # (B, K, A)
    recon = _per_window(error.min(1).values, mask)
    B, K, A = error.shape
    flat = samples.permute(0, 2, 1, 3, 4).reshape(B * A, K, -1)  # (B·A, K, T·2)
    d2 = torch.cdist(flat, flat).pow(2)
    pairs = torch.triu(torch.ones(K, K, dtype=torch.bool, device=samples.device), diagonal=1)
    kernel = (-d2[:, pairs] / d_scale).exp().mean(-1).view(B, A)  # F.pdist's pairs, i < j
    diverse = _per_window(kernel, mask)
    p = Gaussian(prior.mu[:, :, None].expand_as(codes.b), prior.logvar[:, :, None].expand_as(codes.b))
    kl_raw = _per_window(kl_divergence(codes.posterior(), p).sum(-1), mask)  # (B, A, K) summed over K
    kl = kl_raw.clamp_min(kl_min)
    real = agent_mask.any(1)
    mean = lambda x: (x * real).sum() / real.sum().clamp_min(1)  # noqa: E731
    total = recon_weight * recon + diverse_weight * diverse + kl_weight * kl
    return DLowLossParts(mean(total), mean(recon), mean(diverse), mean(kl), mean(kl_raw))
