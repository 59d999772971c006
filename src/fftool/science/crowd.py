"""A simulated crowd: pedestrians crossing a corridor toward goals, moved by fftool's own social forces.

`simulate_crowd` is seeded and deterministic (CPU torch, float64). Everyone's forces come from
`social_forces` (driving force + elliptical repulsion, field of view), the same functions the `forces`
stage and the model use; a step updates every agent at once (no Python loop over agents). Used by
`fftool simulate-crowd` to make a dataset of the project's own (docs/tutorial.md, "Your own dataset").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from fftool.config import ForcesConfig
from fftool.science.social_forces import social_forces


@dataclass(frozen=True)
class Crowd:
    """Positions sampled every `sample_s` seconds: one row per (time, agent) present."""

    time_s: np.ndarray  # (N,) float64
    agent: np.ndarray  # (N,) int64
    xy: np.ndarray  # (N, 2) float64 metres


def simulate_crowd(
    agents: int,
    seconds: float,
    seed: int,
    *,
    length_m: float = 20.0,
    width_m: float = 8.0,
    sim_step_s: float = 0.1,
    sample_s: float = 0.4,
    forces: ForcesConfig | None = None,
) -> Crowd:
    """`agents` pedestrians enter a `length_m` × `width_m` corridor at uniform random times in [0, seconds) at
    either end, each walking to a goal at the other end at a desired speed N(1.3, 0.2²) m/s, and leave on
    arrival. Euler steps of `sim_step_s`: v += (F_dr + F_re) Δt, speed capped at 1.3 v0, walls clamp y."""
    cfg = forces or ForcesConfig()
    gen = np.random.default_rng(seed)
    enter_s = np.sort(gen.uniform(0.0, seconds, agents))
    from_left = gen.random(agents) < 0.5
    start = np.stack([np.where(from_left, 0.0, length_m), gen.uniform(0.5, width_m - 0.5, agents)], axis=1)
    goal = np.stack([np.where(from_left, length_m, 0.0), gen.uniform(0.5, width_m - 0.5, agents)], axis=1)
    speed0 = np.clip(gen.normal(1.3, 0.2, agents), 0.6, 2.0)

    pos = torch.as_tensor(start)  # (N, 2)
    goal_t = torch.as_tensor(goal)
    v0 = torch.as_tensor(speed0)
    direction = (goal_t - pos) / torch.linalg.vector_norm(goal_t - pos, dim=-1, keepdim=True)
    vel = direction * v0[:, None]
    entered = torch.zeros(agents, dtype=torch.bool)
    left = torch.zeros(agents, dtype=torch.bool)
    no_groups = torch.zeros(1, agents, agents, dtype=torch.bool)
    every = max(1, round(sample_s / sim_step_s))
    times, ids, xys = [], [], []
    for step in range(round(seconds / sim_step_s)):  # time steps, every agent at once
        now = step * sim_step_s
        entered = torch.as_tensor(enter_s <= now + 1e-9)
        present = entered & ~left
        if step % every == 0 and bool(present.any()):
            index = torch.nonzero(present).flatten()
            times.append(np.full(index.numel(), round(now, 6)))
            ids.append(index.numpy())
            xys.append(pos[index].numpy().copy())
        f_dr, f_re = social_forces(
            pos[None, :, None],
            present[None, :, None],
            goal_t[None],
            vel[None, :, None],
            v0[None, :, None],
            no_groups,
            cfg,
        )  # (1, N, 1, 2) each
        acc = (f_dr + f_re)[0, :, 0]
        new_vel = vel + acc * sim_step_s
        speed = torch.linalg.vector_norm(new_vel, dim=-1, keepdim=True)
        new_vel = new_vel * torch.clamp(1.3 * v0[:, None] / speed.clamp_min(1e-9), max=1.0)
        moved = pos + new_vel * sim_step_s
        moved[:, 1] = moved[:, 1].clamp(0.0, width_m)
        pos = torch.where(present[:, None], moved, pos)
        vel = torch.where(present[:, None], new_vel, vel)
        arrived = torch.linalg.vector_norm(goal_t - pos, dim=-1) < 0.5
        left = left | (present & arrived)
    if not times:
        return Crowd(np.zeros(0), np.zeros(0, np.int64), np.zeros((0, 2)))
    return Crowd(np.concatenate(times), np.concatenate(ids).astype(np.int64), np.concatenate(xys))
