"""Social forces (Helbing & Molnár 1995) as pure, batched, differentiable torch functions.

Used by the `forces` stage and, at test time, by the model's autoregressive decoder, so both compute
the same features. Shapes use B batch (windows), N agents, T steps; pairwise tensors are (..., N, N)
with [a, b] = "effect of b on a". Padded agents are masked out: absent pedestrians exert and feel
nothing. No Python loop runs over agents or steps. The equations are written out in docs/forces.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import torch
from torch import Tensor

from fftool.config import ForcesConfig

# The radicand of 2b is clamped here, as in the socialforce package: where the ellipse degenerates
# (alpha exactly on beta's next-step segment) b is not differentiable and the force is zero.
RADICAND_MIN = 1e-8


def _norm(vector: Tensor) -> Tensor:
    return torch.linalg.vector_norm(vector, dim=-1)


def _unit(vector: Tensor) -> Tensor:
    """vector / |vector|, and 0 for the zero vector (0 / tiny; no NaN, no NaN gradient)."""
    return vector / _norm(vector).clamp_min(torch.finfo(vector.dtype).tiny)[..., None]


def desired_direction(position: Tensor, goal: Tensor, min_distance_m: float) -> tuple[Tensor, Tensor]:
    """Unit vector e = (g - r) / |g - r| (..., 2) and where it is defined (..., ), i.e. |g - r| >= min."""
    offset = goal - position
    defined = _norm(offset) >= min_distance_m
    return torch.where(defined[..., None], _unit(offset), torch.zeros_like(offset)), defined


def driving_force(velocity: Tensor, direction: Tensor, defined: Tensor, desired_speed: Tensor, tau_s: float) -> Tensor:
    """F_dr = (v0 e - v) / tau (..., 2); zero where the direction is undefined."""
    force = (desired_speed[..., None] * direction - velocity) / tau_s
    return torch.where(defined[..., None], force, torch.zeros_like(force))


class Ellipse(NamedTuple):
    """The elliptical b of every pair, with the pieces its gradient is made of."""

    b: Tensor  # (..., N, N) semi-minor axis
    ahead: Tensor  # (..., N, N, 2) r_ab - v_b Δt e_b
    n_sum: Tensor  # (..., N, N) |r_ab| + |r_ab - v_b Δt e_b|
    live: Tensor  # (..., N, N) bool: the radicand is above its clamp (b is differentiable there)


def ellipse_b(r_ab: Tensor, speed_b: Tensor, direction_b: Tensor, step_s: float) -> Ellipse:
    """Semi-minor axis b (..., N, N): 2b = sqrt((|r| + |r - v_b Δt e_b|)^2 - (v_b Δt)^2), with the terms
    `pair_repulsion` differentiates, so the forces use exactly this b.

    r_ab (..., N, N, 2) = r_a - r_b; speed_b (..., N) and direction_b (..., N, 2) belong to b.
    """
    step = (speed_b * step_s)[..., None, :]  # (..., 1, N) how far b moves in Δt
    ahead = r_ab - step[..., None] * direction_b[..., None, :, :]  # (..., N, N, 2)
    n_sum = _norm(r_ab) + _norm(ahead)
    radicand = n_sum**2 - step**2
    return Ellipse(0.5 * torch.sqrt(radicand.clamp_min(RADICAND_MIN)), ahead, n_sum, radicand > RADICAND_MIN)


def potential(b: Tensor, v0_m2_s2: float, sigma_m: float) -> Tensor:
    """V(b) = V0 exp(-b / sigma)."""
    return v0_m2_s2 * torch.exp(-b / sigma_m)


def pair_repulsion(
    r_ab: Tensor, speed_b: Tensor, direction_b: Tensor, *, v0_m2_s2: float, sigma_m: float, step_s: float
) -> Tensor:
    """f_ab = -grad_{r_ab} V(b) (..., N, N, 2), by the analytic gradient.

    With n1 = |r|, n2 = |r - v_b Δt e_b|: grad b = (n1 + n2) (r/n1 + (r - v_b Δt e_b)/n2) / (4 b), and
    dV/db = -V / sigma, so f = V / sigma * grad b. Zero where the radicand is clamped.
    """
    b, ahead, n_sum, live = ellipse_b(r_ab, speed_b, direction_b, step_s)
    scale = potential(b, v0_m2_s2, sigma_m) / sigma_m * n_sum / (4 * b) * live  # |f| / |grad-direction|
    return scale[..., None] * (_unit(r_ab) + _unit(ahead))


def fov_weight(direction_a: Tensor, toward_b: Tensor, fov_deg: float, out_of_view: float) -> Tensor:
    """w (..., N, N): 1 if e_a · f >= |f| cos(ε) (β in α's view cone of opening 2ε), else c.

    direction_a (..., N, 2) is e_α; toward_b (..., N, N, 2) is the vector f the cone is tested on.
    """
    cos_half = math.cos(math.radians(fov_deg / 2))
    alignment = torch.einsum("...aj,...abj->...ab", direction_a, toward_b)
    in_view = alignment >= _norm(toward_b) * cos_half
    return torch.where(in_view, torch.ones_like(alignment), torch.full_like(alignment, out_of_view))


def same_group(labels: Tensor, min_steps: int) -> Tensor:
    """(..., N, N) bool: pairs sharing a cluster (label >= 0) at more than min_steps of the steps.

    labels (..., N, S) holds per-step cluster labels, -1 for noise or absent.
    """
    together = (labels[..., :, None, :] == labels[..., None, :, :]) & (labels[..., :, None, :] >= 0)
    return together.sum(dim=-1) > min_steps


def group_pairs(ids: Tensor) -> Tensor:
    """(..., N, N) bool from window-local group ids (..., N) (-1 alone): pairs that do not repel, self excluded.

    The inverse of `group_ids`, for reading stored ids back.
    """
    pairs = (ids[..., :, None] == ids[..., None, :]) & (ids[..., :, None] >= 0)
    return pairs & ~torch.eye(ids.shape[-1], dtype=torch.bool, device=ids.device)


def group_ids(groups: Tensor) -> Tensor:
    """(..., N) long: the smallest agent index of each agent's group component, -1 when alone.

    Components of the (symmetric) group relation by transitive closure: log2(N) boolean products.
    """
    n = groups.shape[-1]
    reach = groups | torch.eye(n, dtype=torch.bool, device=groups.device)
    for _ in range(max(1, math.ceil(math.log2(max(n, 2))))):
        reach = (reach.float() @ reach.float()) > 0
    index = torch.arange(n, device=groups.device).expand_as(reach)
    first = torch.where(reach, index, torch.full_like(index, n)).min(dim=-1).values
    return torch.where(groups.any(dim=-1), first, torch.full_like(first, -1))


def finite_difference_velocity(position: Tensor, present: Tensor, dt_s: float, obs_len: int) -> Tensor:
    """Velocity (B, N, T, 2) from positions (B, N, T, 2) and presence (B, N, T), causally.

    v_t = (r_t - r_{t-1}) / dt where both are present. A step without a backward difference (the
    first step, or a first appearance) takes the forward difference (r_{t+1} - r_t) / dt, except when
    that would read a future position at an observed step; then it is zero. So observed-step
    velocities depend on observed positions only (AgentFormer duplicates v_1 into v_0 the same way).
    """
    T = position.shape[-2]
    diff = (position[..., 1:, :] - position[..., :-1, :]) / dt_s  # (B, N, T-1, 2): step t-1 -> t
    pair = present[..., 1:] & present[..., :-1]  # (B, N, T-1)
    backward = torch.cat([torch.zeros_like(diff[..., :1, :]), diff], dim=-2)
    has_backward = torch.cat([torch.zeros_like(pair[..., :1]), pair], dim=-1)
    forward = torch.cat([diff, torch.zeros_like(diff[..., :1, :])], dim=-2)
    step = torch.arange(T, device=position.device)
    causal = (step + 1 < obs_len) | (step >= obs_len)  # forward difference allowed at this step
    has_forward = torch.cat([pair, torch.zeros_like(pair[..., :1])], dim=-1) & causal
    velocity = torch.where(has_backward[..., None], backward, torch.zeros_like(backward))
    use_forward = ~has_backward & has_forward & present
    return torch.where(use_forward[..., None], forward, velocity)


def desired_speed(velocity: Tensor, present: Tensor, obs_len: int, cfg: ForcesConfig) -> Tensor:
    """v0 (B, N, T) per the config's rule; the mean rule averages observed speeds where present."""
    speed = _norm(velocity)
    if cfg.desired_speed == "current":
        return speed
    if cfg.desired_speed == "constant":
        return torch.full_like(speed, cfg.desired_speed_mps)
    observed = present[..., :obs_len]
    count = observed.sum(dim=-1).clamp_min(1)
    mean = (speed[..., :obs_len] * observed).sum(dim=-1) / count  # (B, N)
    return mean[..., None].expand_as(speed)


def social_forces(
    position: Tensor,
    present: Tensor,
    goal: Tensor,
    velocity: Tensor,
    speed0: Tensor,
    groups: Tensor,
    cfg: ForcesConfig,
    heading: Tensor | None = None,
) -> tuple[Tensor, Tensor]:
    """F_dr and F_re (B, N, T, 2) for every agent and step of a padded batch.

    Args:
        position: (B, N, T, 2) metres; anything at absent slots.
        present: (B, N, T) bool; padded agents are False everywhere.
        goal: (B, N, 2) each agent's goal.
        velocity: (B, N, T, 2) m/s (see `finite_difference_velocity`).
        speed0: (B, N, T) desired speed v0.
        groups: (B, N, N) bool pairs that do not repel (see `same_group`).
        cfg: the force constants.
        heading: (B, N) bool; agents whose goal is unknown (neighbours that are not valid) use their
            velocity direction as e for the ellipse and feel no force. Default: every goal is known.
    """
    direction, defined = _directions(position, goal, velocity, cfg, heading)
    f_dr = driving_force(velocity, direction, defined & present, speed0, cfg.tau_s)
    return f_dr, _repulsion(position, present, velocity, direction, defined, groups, cfg)


def repulsive_force(
    position: Tensor,
    present: Tensor,
    goal: Tensor,
    velocity: Tensor,
    groups: Tensor,
    cfg: ForcesConfig,
    heading: Tensor | None = None,
) -> Tensor:
    """F_re (B, N, T, 2) alone, as `social_forces` computes it: what the re decoder recomputes at every step
    (it reads none of the driving force's constants, so its model is not keyed on them)."""
    direction, defined = _directions(position, goal, velocity, cfg, heading)
    return _repulsion(position, present, velocity, direction, defined, groups, cfg)


def _directions(
    position: Tensor, goal: Tensor, velocity: Tensor, cfg: ForcesConfig, heading: Tensor | None
) -> tuple[Tensor, Tensor]:
    """Each agent's desired direction e toward its goal and where it is defined (see `social_forces`)."""
    direction, defined = desired_direction(position, goal[:, :, None, :], cfg.goal_min_distance_m)
    if heading is not None:
        direction = torch.where(heading[:, :, None, None], _unit(velocity), direction)
        defined = defined & ~heading[:, :, None]
    return direction, defined


def _repulsion(
    position: Tensor,
    present: Tensor,
    velocity: Tensor,
    direction: Tensor,
    defined: Tensor,
    groups: Tensor,
    cfg: ForcesConfig,
) -> Tensor:
    """The field-of-view weighted elliptical repulsion of every other present agent outside one's group."""
    N = position.shape[1]  # position: (B, N, T, 2)
    pos_t, e_t = position.transpose(1, 2), direction.transpose(1, 2)  # (B, T, N, 2)
    r_ab = pos_t[:, :, :, None, :] - pos_t[:, :, None, :, :]  # (B, T, N, N, 2)
    f_ab = pair_repulsion(
        r_ab,
        _norm(velocity).transpose(1, 2),
        e_t,
        v0_m2_s2=cfg.v0_m2_s2,
        sigma_m=cfg.sigma_m,
        step_s=cfg.ellipse_step_s,
    )
    toward = -f_ab if cfg.fov_reading == "force" else -r_ab
    weight = fov_weight(e_t, toward, cfg.fov_deg, cfg.fov_out_of_view)  # (B, T, N, N)
    present_t = present.transpose(1, 2)  # (B, T, N)
    not_self = ~torch.eye(N, dtype=torch.bool, device=position.device)
    interacts = present_t[..., :, None] & present_t[..., None, :] & not_self & ~groups[:, None]
    f_re = ((weight * interacts)[..., None] * f_ab).sum(dim=-2)  # (B, T, N, 2)
    return f_re.transpose(1, 2) * (defined & present)[..., None]


@dataclass(frozen=True)
class WindowForces:
    """Everything the force features of a batch of windows are made of."""

    f_dr: Tensor  # (B, N, T, 2) driving force
    f_re: Tensor  # (B, N, T, 2) repulsive force
    velocity: Tensor  # (B, N, T, 2) finite-difference velocity
    speed0: Tensor  # (B, N, T) desired speed
    groups: Tensor  # (B, N, N) bool: pairs that do not repel


def window_forces(
    position: Tensor,
    present: Tensor,
    goal: Tensor,
    labels: Tensor,
    cfg: ForcesConfig,
    *,
    dt_s: float,
    obs_len: int,
    heading: Tensor | None = None,
) -> WindowForces:
    """The forces stage's whole computation for a padded batch of windows.

    Args:
        position: (B, N, T, 2) metres. present: (B, N, T) bool. goal: (B, N, 2).
        labels: (B, N, obs_len) DBSCAN cluster labels at the observed steps, -1 for noise or absent.
        cfg: the force constants. dt_s: seconds per step. obs_len: observed steps.
        heading: (B, N) bool, agents without a known goal (see `social_forces`).
    """
    velocity = finite_difference_velocity(position, present, dt_s, obs_len)
    speed0 = desired_speed(velocity, present, obs_len, cfg)
    groups = same_group(labels, cfg.group_min_steps)
    groups = groups & ~torch.eye(groups.shape[-1], dtype=torch.bool, device=groups.device)
    f_dr, f_re = social_forces(position, present, goal, velocity, speed0, groups, cfg, heading=heading)
    return WindowForces(f_dr, f_re, velocity, speed0, groups)
