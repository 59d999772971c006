"""What a predictor may see at test time: goals per protocol, past forces, and the constant-velocity reference.

Goal protocols (docs/metrics.md):
    paper  - the sampled goal closest to the ground-truth end point, then K CVAE samples with it
             (reads the ground truth, as the paper does);
    fair   - sample k uses sampled goal k (never reads the ground-truth future);
    oracle - the true end point (an upper bound, "planning" mode).

Test-time inputs never use stored forces: the past F_dr and F_re are recomputed from the observed
positions and the goal the protocol hands out, with the same functions as the `forces` stage, so no
ground-truth goal leaks through them.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Final

import torch
from torch import Tensor

from fftool.config import ForcesConfig
from fftool.errors import FftoolError
from fftool.learning.batches import SceneBatch
from fftool.science.social_forces import (
    desired_direction,
    desired_speed,
    driving_force,
    finite_difference_velocity,
    group_pairs,
    repulsive_force,
)

PROTOCOLS: Final = ("paper", "fair", "oracle")


def protocol_goals(protocol: str, sampled: Tensor | None, truth_end: Tensor, k: int) -> Tensor:
    """Goals (B, k, A, 2) for each of k samples: sampled (B, A, G, 2) world goals, truth_end (B, A, 2).

    paper and oracle give every sample the same goal; fair gives sample i goal i (needs G = k).
    """
    if protocol == "oracle":
        return truth_end[:, None].expand(-1, k, -1, -1)
    if sampled is None:
        raise ValueError(f"protocol {protocol!r} needs sampled goals")
    if protocol == "paper":
        closest = torch.linalg.vector_norm(sampled - truth_end[:, :, None], dim=-1).argmin(-1)  # (B, A)
        chosen = sampled.gather(2, closest[..., None, None].expand(-1, -1, 1, 2))[:, :, 0]
        return chosen[:, None].expand(-1, k, -1, -1)
    if protocol == "fair":
        if sampled.shape[2] != k:
            raise FftoolError(
                f"the fair protocol pairs goal k with sample k: the goals artifact holds {sampled.shape[2]} goals "
                f"per agent-window, evaluate.k is {k}; set goals.k = evaluate.k"
            )
        return sampled.transpose(1, 2)
    raise ValueError(f"unknown goal protocol {protocol!r}; one of {', '.join(PROTOCOLS)}")


def with_past_forces(
    batch: SceneBatch, goal: Tensor, cfg: ForcesConfig, dt_s: float, obs_len: int, arrays: tuple[str, ...]
) -> SceneBatch:
    """The batch with the forces arrays named (f_dr, f_re: what the variant's encoder reads) of the observed
    steps recomputed toward `goal` (B, A, 2) from the observed positions alone; their future steps and the
    arrays not named are zeros (the sampler never reads them; the decoder recomputes its own)."""
    observed = replace(batch, xy=batch.xy[:, :, :obs_len])
    recomputed = with_forces(observed, goal, cfg, dt_s, obs_len, arrays)
    zeros = torch.zeros_like(batch.f_dr)
    forces = {
        name: torch.cat([getattr(recomputed, name), zeros[:, :, obs_len:]], 2) if name in arrays else zeros
        for name in ("f_dr", "f_re")
    }
    return replace(batch, **forces)


def with_forces(
    batch: SceneBatch, goal: Tensor, cfg: ForcesConfig, dt_s: float, obs_len: int, arrays: tuple[str, ...]
) -> SceneBatch:
    """The batch with the forces arrays named (f_dr, f_re) recomputed toward `goal` (B, A, 2) at every step,
    observed and future: what a CVAE trained with goals other than the true end point reads (its posterior
    reads the future's). Each force reads only its own constants, so a model is keyed on no other."""
    present = batch.agent_mask[:, :, None].expand(-1, -1, batch.xy.shape[2])
    velocity = finite_difference_velocity(batch.xy, present, dt_s, obs_len)
    changed = {}
    if "f_dr" in arrays:
        speed0 = desired_speed(velocity, present, obs_len, cfg)
        direction, defined = desired_direction(batch.xy, goal[:, :, None, :], cfg.goal_min_distance_m)
        changed["f_dr"] = driving_force(velocity, direction, defined & present, speed0, cfg.tau_s)
    if "f_re" in arrays:
        changed["f_re"] = repulsive_force(batch.xy, present, goal, velocity, group_pairs(batch.group), cfg)
    return replace(batch, **changed)


def repeat_windows(batch: SceneBatch, k: int) -> SceneBatch:
    """Each window k times in a row (repeat_interleave order), e.g. one copy per goal of the fair protocol."""
    return batch.map(lambda t: t.repeat_interleave(k, 0))


def constant_velocity(
    past: Tensor, pred_len: int, k: int, angle_std_deg: float, speed_std: float, gen: torch.Generator
) -> Tensor:
    """K futures (B, K, A, T, 2) of the last observed velocity, sample 0 exact, the others with a random
    heading turn and speed factor (Schöller et al. 2020's multi-sample constant-velocity model).

    past (B, A, Tp, 2) world positions.
    """
    B, A = past.shape[:2]
    velocity = past[:, :, -1] - past[:, :, -2]  # metres per step, (B, A, 2)
    angle = torch.randn(B, k, A, generator=gen, device=past.device) * math.radians(angle_std_deg)
    speed = (1 + torch.randn(B, k, A, generator=gen, device=past.device) * speed_std).clamp_min(0)
    angle[:, 0], speed[:, 0] = 0.0, 1.0
    cos, sin = torch.cos(angle), torch.sin(angle)
    vx, vy = velocity[:, None, :, 0], velocity[:, None, :, 1]
    turned = torch.stack([cos * vx - sin * vy, sin * vx + cos * vy], -1) * speed[..., None]  # (B, K, A, 2)
    steps = torch.arange(1, pred_len + 1, device=past.device, dtype=past.dtype)
    return past[:, None, :, -1, None, :] + steps[None, None, None, :, None] * turned[:, :, :, None, :]
