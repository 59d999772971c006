"""Model inputs per ForceFormer variant, in each window's normalised frame.

Positions are taken relative to the window origin (the mean of the agents' last observed positions)
and, in training, turned by one random angle per window (AgentFormer's scene rotation); forces and
goals turn with them. Inside the decoder the goal and force features are recomputed from the model's
own predicted positions with the same force functions as the `forces` stage.

Each variant's features per step: fftool.variants.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from fftool.config import ForcesConfig
from fftool.learning.batches import SceneBatch
from fftool.models.forceformer import StepFeatures
from fftool.science.social_forces import desired_direction, driving_force, group_pairs, repulsive_force
from fftool.variants import SPECS


def training_inputs(variant: str) -> dict[str, tuple[str, ...] | None]:
    """What training a variant's model reads (Reads.artifacts): the windows, and the forces arrays it trains on."""
    arrays = SPECS[variant].training_reads
    return {"windows": None, **({"forces": arrays} if arrays else {})}


@dataclass(frozen=True)
class Prepared:
    """One batch in the normalised frame, with everything the model and the loss need."""

    past: Tensor  # (B, A, Tp, F) encoder features
    future: Tensor  # (B, A, Tf, F) posterior features (ground truth)
    past_pos: Tensor  # (B, A, Tp, 2)
    future_pos: Tensor  # (B, A, Tf, 2) the target
    goal: Tensor  # (B, A, 2) the goal given to the model
    speed0: Tensor  # (B, A)
    groups: Tensor  # (B, A, A) bool
    agent_mask: Tensor  # (B, A)
    origin: Tensor  # (B, 2) world
    rotation: Tensor  # (B, 2, 2) normalised = R (world - origin)

    @property
    def last_step(self) -> Tensor:
        """(B, A, 2) the last observed displacement: what constant velocity extrapolates."""
        return self.past_pos[:, :, -1] - self.past_pos[:, :, -2]

    def to_world(self, positions: Tensor) -> Tensor:
        """(B, ..., A, T, 2) normalised positions back to world metres (leading sample dims allowed)."""
        R = self.rotation.view(self.rotation.shape[0], *([1] * (positions.dim() - 3)), 2, 2)
        origin = self.origin.view(self.origin.shape[0], *([1] * (positions.dim() - 2)), 2)
        return torch.einsum("...ji,...tj->...ti", R, positions) + origin


def _turn(vectors: Tensor, R: Tensor) -> Tensor:
    """Apply (B, 2, 2) rotations to (B, A, T, 2) or (B, A, 2) vectors."""
    return torch.einsum("bij,b...j->b...i", R, vectors)


def _step_features(variant: str, pos: Tensor, goal: Tensor, forces: Tensor | None) -> list[Tensor]:
    parts = [pos]
    if variant in ("goal", "re"):
        goal_t = goal[:, :, None, :].expand_as(pos) if pos.dim() == 4 else goal
        parts += [goal_t, pos - goal_t]
    if forces is not None:
        parts.append(forces)
    return parts


def prepare(
    batch: SceneBatch,
    variant: str,
    obs_len: int,
    *,
    goal: Tensor | None = None,
    rotate: bool = False,
    generator: torch.Generator | None = None,
) -> Prepared:
    """Normalise a batch and build the encoder/posterior features of `variant`.

    goal: (B, A, 2) world goals; default the ground truth (training). rotate: random scene rotation.
    """
    mask = batch.agent_mask
    last = batch.xy[:, :, obs_len - 1]  # (B, A, 2)
    origin = (last * mask[..., None]).sum(1) / mask.sum(1, keepdim=True).clamp_min(1)
    B = len(origin)
    angle = torch.rand(B, generator=generator, device=origin.device) * 2 * math.pi if rotate else origin.new_zeros(B)
    cos, sin = torch.cos(angle), torch.sin(angle)
    R = torch.stack([torch.stack([cos, -sin], -1), torch.stack([sin, cos], -1)], -2)
    pos = _turn(batch.xy - origin[:, None, None, :], R)  # (B, A, L, 2)
    velocity = torch.diff(pos, dim=2, prepend=pos[:, :, :1])
    velocity[:, :, 0] = velocity[:, :, 1]  # AgentFormer duplicates the first velocity
    goal_n = _turn((batch.xy[:, :, -1] if goal is None else goal) - origin[:, None, :], R)
    forces = {"dr": _turn(batch.f_dr, R), "re": _turn(batch.f_re, R)}.get(variant)
    position, *extras = _step_features(variant, pos, goal_n, forces)
    features = torch.cat([position, velocity, *extras], -1) * mask[:, :, None, None]
    return Prepared(
        past=features[:, :, :obs_len],
        future=features[:, :, obs_len:],
        past_pos=pos[:, :, :obs_len],
        future_pos=pos[:, :, obs_len:],
        goal=goal_n,
        speed0=batch.speed0,
        groups=group_pairs(batch.group),
        agent_mask=mask,
        origin=origin,
        rotation=R,
    )


def decoder_features(
    variant: str, prepared: Prepared, forces_cfg: ForcesConfig | None, dt_s: float | None, repeat: int = 1
) -> StepFeatures:
    """The decoder's per-step input from positions decoded so far; forces recomputed from predictions.

    forces_cfg, dt_s: the force constants and time step (None for variants without forces).
    repeat: how many samples each window is repeated for (batch dim B·repeat, repeat_interleave order).
    """
    if SPECS[variant].uses_forces and (forces_cfg is None or dt_s is None):
        raise ValueError(f"the {variant} variant decodes with social forces: it needs their constants and time step")
    rep = (lambda x: x.repeat_interleave(repeat, 0)) if repeat > 1 else (lambda x: x)
    goal, speed0, groups, mask = (
        rep(prepared.goal),
        rep(prepared.speed0),
        rep(prepared.groups),
        rep(prepared.agent_mask),
    )

    def features(positions: Tensor, step: int) -> Tensor:
        pos = positions[:, :, -1]  # (B, A, 2)
        if variant in ("baseline", "goal"):
            return torch.cat(_step_features(variant, pos, goal, None), -1)
        velocity = (positions[:, :, -1] - positions[:, :, -2]) / dt_s if positions.shape[2] > 1 else None
        if velocity is None:  # the first decoder input: the last observed step, whose velocity is known
            velocity = rep(prepared.past_pos[:, :, -1] - prepared.past_pos[:, :, -2]) / dt_s
        if variant == "dr":
            direction, defined = desired_direction(pos, goal, forces_cfg.goal_min_distance_m)
            force = driving_force(velocity, direction, defined & mask, speed0, forces_cfg.tau_s)
        else:
            force = repulsive_force(pos[:, :, None], mask[:, :, None], goal, velocity[:, :, None], groups, forces_cfg)
            force = force[:, :, 0]
        return torch.cat(_step_features(variant, pos, goal, force), -1)

    return features
