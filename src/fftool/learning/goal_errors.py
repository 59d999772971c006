"""Training goals as wrong as the goal module's (`goal_training.source = "module"` or `"fair"`).

A CVAE trained with each window's true end point learns to trust its goal completely, then meets sampled
goals at test. Here a training goal is the true end point moved by errors the goal module made on a window
it never trained on, expressed in that window's heading frame and drawn for a training agent of the same
speed quantile, then turned to the agent's own heading: for "module", the error of the nearest of its K
goals (the goal the best of the K fair samples decodes); for "fair", the errors of all K goals (a whole goal
set, so that sample k of the best-of-K loss decodes goal k, as the fair protocol does at test).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch
from torch import Tensor

from fftool.artifacts.store import Artifact
from fftool.config import ForcesConfig, GoalTrainingConfig
from fftool.learning.batches import SceneBatch, SceneSet
from fftool.learning.protocols import with_forces
from fftool.learning.sampling import load_sampled_goals
from fftool.variants import SPECS

_STANDING_M = 1e-3  # a last observed step shorter than this has no heading: the frame is the world's


def heading(xy: Tensor, obs_len: int) -> tuple[Tensor, Tensor]:
    """Unit heading (..., 2) and length (...) of the last observed step of paths (..., T, 2)."""
    step = xy[..., obs_len - 1, :] - xy[..., obs_len - 2, :]
    speed = torch.linalg.vector_norm(step, dim=-1)
    east = torch.zeros_like(step)
    east[..., 0] = 1.0
    unit = torch.where((speed > _STANDING_M)[..., None], step / speed.clamp_min(_STANDING_M)[..., None], east)
    return unit, speed


def _to_frame(vector: Tensor, unit: Tensor) -> Tensor:
    """World vectors (..., 2) in the frame whose x axis is `unit` (..., 2)."""
    along = (vector * unit).sum(-1)
    across = vector[..., 1] * unit[..., 0] - vector[..., 0] * unit[..., 1]
    return torch.stack([along, across], -1)


def _from_frame(local: Tensor, unit: Tensor) -> Tensor:
    """The inverse of `_to_frame`."""
    x, y = local[..., 0, None], local[..., 1, None]
    normal = torch.stack([-unit[..., 1], unit[..., 0]], -1)
    return x * unit + y * normal


@dataclass(frozen=True)
class GoalErrors:
    """The goal module's nearest-goal errors on validation windows, grouped by the windows' speed quantile."""

    local: Tensor  # (M, 2) nearest-goal errors in each window's heading frame, rows sorted by speed bin
    sets: Tensor  # (M, K, 2) every goal's error in the same frame, the same rows
    edges: Tensor  # (bins - 1,) speed quantiles, metres per step
    start: Tensor  # (bins,) first row of each bin
    count: Tensor  # (bins,) rows of each bin (an empty bin draws from all rows)
    true_share: float  # the share of agents that keep their true goal

    def to(self, device: torch.device) -> GoalErrors:
        moved = (self.local, self.sets, self.edges, self.start, self.count)
        return GoalErrors(*(t.to(device) for t in moved), self.true_share)

    def _rows(self, speed: Tensor, gen: torch.Generator) -> Tensor:
        """(B, A) a validation row of each agent's speed bin, drawn uniformly."""
        group = torch.bucketize(speed, self.edges)  # (B, A)
        u = torch.rand(speed.shape, generator=gen, device=speed.device)
        return self.start[group] + (u * self.count[group]).long().clamp_max(self.count[group] - 1)

    def draw(self, xy: Tensor, obs_len: int, gen: torch.Generator) -> Tensor:
        """(B, A, 2) training goals for windows xy (B, A, T, 2): the true end point plus a drawn error."""
        unit, speed = heading(xy, obs_len)
        moved = xy[..., -1, :] + _from_frame(self.local[self._rows(speed, gen)], unit)
        keep = torch.rand(speed.shape, generator=gen, device=xy.device) < self.true_share
        return torch.where(keep[..., None], xy[..., -1, :], moved)

    def draw_sets(self, xy: Tensor, obs_len: int, gen: torch.Generator, k: int) -> Tensor:
        """(B, A, k, 2) goal sets for windows xy (B, A, T, 2): k of the K goals the module drew for one
        validation window of the agent's speed bin (a random k, in random order), moved onto the agent's true
        end point and turned to its heading."""
        unit, speed = heading(xy, obs_len)
        local = self.sets[self._rows(speed, gen)]  # (B, A, K, 2)
        if k > local.shape[2]:
            raise ValueError(f"a goal set holds {local.shape[2]} goals, {k} were asked for")
        pick = torch.rand(local.shape[:3], generator=gen, device=xy.device).argsort(-1)[..., :k]
        local = local.gather(2, pick[..., None].expand(-1, -1, -1, 2))
        return xy[..., -1, None, :] + _from_frame(local, unit[..., None, :])


def fit(val_xy: np.ndarray, val_goals: np.ndarray, obs_len: int, bins: int, true_share: float) -> GoalErrors:
    """The errors of validation windows (M, T, 2) whose goal module drew goals (M, K, 2) for them."""
    xy = torch.as_tensor(np.asarray(val_xy), dtype=torch.float32)
    goals = torch.as_tensor(np.asarray(val_goals), dtype=torch.float32)
    if len(xy) == 0:
        raise ValueError("the goal module's errors need validation windows with sampled goals; there are none")
    error = goals - xy[:, None, -1]  # (M, K, 2)
    nearest = error[torch.arange(len(xy)), torch.linalg.vector_norm(error, dim=-1).argmin(1)]
    unit, speed = heading(xy, obs_len)
    edges = torch.quantile(speed, torch.linspace(0, 1, bins + 1)[1:-1])
    group = torch.bucketize(speed, edges)
    order = torch.argsort(group, stable=True)
    count = torch.bincount(group, minlength=bins)
    start = torch.cumsum(count, 0) - count
    empty = count == 0
    start, count = torch.where(empty, 0, start), torch.where(empty, len(xy), count)
    sets = _to_frame(error, unit[:, None])
    return GoalErrors(_to_frame(nearest, unit)[order], sets[order], edges, start, count, float(true_share))


@dataclass(frozen=True)
class ModuleGoals:
    """What a goal variant trained for the goal module's goals uses beside its data: the module's errors, to
    move each training goal by, and its K goals of the validation windows, for the fair validation."""

    errors: GoalErrors
    val_goals: np.ndarray  # (M, K, 2), aligned with the validation scenes' agent-windows
    # goal_training.source: moved training goals, goal sets for the samples, or true goals (the fair best epoch)
    source: Literal["true", "module", "fair"]

    def move(
        self,
        batch: SceneBatch,
        obs_len: int,
        gen: torch.Generator,
        forces_cfg: ForcesConfig | None,
        dt_s: float | None,
        variant: str,
    ) -> tuple[SceneBatch, Tensor]:
        """The training goals (B, A, 2) of a batch on the errors' device, and the batch with the forces the
        variant reads recomputed toward them (observed and future)."""
        goal = self.errors.draw(batch.xy, obs_len, gen)
        if forces_cfg is not None and dt_s is not None:
            batch = with_forces(batch, goal, forces_cfg, dt_s, obs_len, SPECS[variant].training_reads)
        return batch, goal


def module_goals(
    goals: Artifact, val: SceneSet, benchmark: str, obs_len: int, cfg: GoalTrainingConfig, device: torch.device
) -> ModuleGoals:
    """The goals artifact's validation goals and the errors fitted on them."""
    val_goals = np.asarray(load_sampled_goals(goals, val, benchmark, "val"))
    fitted = fit(val.data.xy, val_goals, obs_len, cfg.speed_bins, cfg.true_share)
    return ModuleGoals(fitted.to(device), val_goals, cfg.source)
