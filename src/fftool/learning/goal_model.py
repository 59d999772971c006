"""The goal estimator as functions: network inputs, loss, goal sampling, and loading a trained model.

Shared by the `goal` (training) and `goals` (sampling) stages, which never import each other.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Final

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from fftool.artifacts.schema import GOAL_MODEL_FILE
from fftool.artifacts.store import Artifact
from fftool.config import GoalConfig, GoalsConfig
from fftool.learning.batches import AgentWindows, SceneMaps
from fftool.learning.training import generator, model_file
from fftool.models import GoalUNet
from fftool.science.heatmaps import (
    cells_to_world,
    constant_velocity_cells,
    render,
    render_sum,
    rotation,
    sample_goals,
    sample_scene,
    softargmax,
    world_to_cells,
)
from fftool.science.metrics import goal_fde

# Where a padding slot of `others` stands: so far from any crop that its Gaussian is exactly zero.
FAR_M: Final = 1e6


def input_channels(cfg: GoalConfig, obs_len: int, map_channels: int) -> int:
    return obs_len + int(cfg.cv_channel) + 2 * int(cfg.neighbour_channels) + map_channels


@dataclass(frozen=True)
class Neighbours:
    """The other walkers of each agent-window's scene: `rows` (M, N) index `paths` (P, L, 2), -1 pads.

    Built once for a whole part (`of`) so that a subset or a batch still sees every other walker of its window."""

    paths: Tensor
    rows: Tensor

    @classmethod
    def of(cls, xy: np.ndarray, window: np.ndarray) -> Neighbours:
        """The paths xy (M, L, 2) grouped by their window (M,): each row's others are its window's other rows."""
        order = np.argsort(window, kind="stable")
        _, start, count = np.unique(window[order], return_index=True, return_counts=True)
        group = np.empty(len(window), np.int64)
        group[order] = np.repeat(np.arange(len(start)), count)
        position = np.empty(len(window), np.int64)
        position[order] = np.arange(len(window))
        most = max(int(count.max()) - 1 if len(count) else 0, 1)
        j = np.arange(most)[None]
        first, own = start[group][:, None], (position - start[group])[:, None]
        at = np.minimum(first + j + (j >= own), max(len(window) - 1, 0))  # skip the row itself
        rows = np.where(j < count[group][:, None] - 1, order[at], -1) if len(window) else np.zeros((0, 1), np.int64)
        return cls(torch.as_tensor(xy, dtype=torch.float32), torch.as_tensor(rows, dtype=torch.long))

    def subset(self, index: np.ndarray) -> Neighbours:
        return Neighbours(self.paths, self.rows[torch.as_tensor(index, dtype=torch.long)])

    def observed(self, index: slice | Tensor, obs_len: int, reverse: Tensor | None = None) -> Tensor:
        """(b, N, obs_len, 2) the others' observed positions for rows `index`, played backwards where `reverse`
        (b,) is set (as the training crop's own path), FAR_M where a slot pads."""
        rows = self.rows[index]
        rows = rows[:, : max(int((rows >= 0).sum(1).max()) if len(rows) else 0, 1)]  # the batch's most others
        paths = self.paths[rows.clamp(min=0)]  # (b, N, L, 2)
        if reverse is not None:
            paths = torch.where(reverse[:, None, None, None], paths.flip(2), paths)
        return torch.where((rows >= 0)[:, :, None, None], paths[:, :, :obs_len], FAR_M)


def scene_others(obs: Tensor) -> Tensor:
    """(A, A, 2, 2): for each of the A walkers of one scene (A, T, 2), everyone's last two observed positions, its
    own at FAR_M (the `others` of `goal_inputs` where the whole batch is one scene, as in the exported graph)."""
    own = torch.arange(obs.shape[0], device=obs.device)
    self_slot = (own[:, None] == own[None])[:, :, None, None]
    return torch.where(self_slot, FAR_M, obs[None, :, -2:].expand(obs.shape[0], -1, -1, -1))


def goal_inputs(
    obs: Tensor,
    scene: Tensor,
    maps: SceneMaps,
    cfg: GoalConfig,
    angle: Tensor,
    mirror: Tensor,
    pred_len: int,
    others: Tensor | None = None,
) -> tuple[Tensor, Tensor, Tensor]:
    """(B, 8 [+ 1 CV] [+ 2 others] + C, S, S) network input, crop centres (B, 2) and crop rotations (B, 2, 2).

    others (B, N, T ≥ 2, 2): the other walkers' observed positions (FAR_M pads), read with `neighbour_channels`:
    a channel of where they are at the last observed step and one of their constant-velocity goals (each a sum
    of Gaussians, at most 1)."""
    S, res = cfg.crop_cells, cfg.resolution_m
    if cfg.align_heading:
        velocity = obs[:, -1] - obs[:, -2]
        angle = angle + torch.atan2(velocity[:, 1], velocity[:, 0])
    center, R = obs[:, -1], rotation(angle, mirror)
    cells = world_to_cells(obs, center, R, res, S)
    if cfg.cv_channel:
        cells = torch.cat([cells, constant_velocity_cells(cells, pred_len)[:, None]], 1)
    channels = [render(cells, S, cfg.heatmap_sigma_cells)]  # (B, 8 [+ 1], S, S)
    if cfg.neighbour_channels:
        if others is None:
            raise ValueError("goal.neighbour_channels: the goal U-Net reads the other walkers; none were given")
        last, previous = others[:, :, -1], others[:, :, -2]
        for points in (last, last + pred_len * (last - previous)):  # where they are, where they head
            spots = render_sum(world_to_cells(points, center, R, res, S), S, cfg.heatmap_sigma_cells)
            channels.append(spots[:, None].clamp(max=1))
    crop = sample_scene(maps.stack, maps.origins, maps.resolution_m, scene, center, R, res, S)  # (B, C, S, S)
    return torch.cat([*channels, crop.to(obs.dtype)], dim=1), center, R


def speed_scaled(xy: Tensor, scale: Tensor, obs_len: int) -> Tensor:
    """(B, T, 2) windows with each one's positions scaled about its last observed position by scale (B,): the same
    path walked `scale` times as fast, which `goal.speed_scale` trains with."""
    last = xy[:, obs_len - 1 : obs_len]
    return last + scale[:, None, None].to(xy.dtype) * (xy - last)


def supervised_steps(cfg: GoalConfig, pred_len: int) -> list[int]:
    """The future steps (1 … pred_len) the U-Net's output maps stand for, evenly spaced, the goal's last."""
    n = cfg.supervised_steps
    return [round(pred_len * (i + 1) / n) for i in range(n)]


def goal_loss(logits: Tensor, future_cells: Tensor, cfg: GoalConfig) -> tuple[Tensor, Tensor, Tensor]:
    """total, BCE (mean over cells and output maps) and MSE (cells², softargmax of the goal map vs the true goal)
    with λ on one of them. logits (B, n, S, S), future_cells (B, n, 2): the supervised steps' true cells."""
    target = render(future_cells, cfg.crop_cells, cfg.target_sigma_cells)
    bce = F.binary_cross_entropy_with_logits(logits, target)
    reachable = future_cells[:, -1].clamp(0, cfg.crop_cells - 1)  # a goal outside the crop pulls to its border
    mse = ((softargmax(logits[:, -1]) - reachable) ** 2).sum(-1).mean()
    total = cfg.loss_lambda * bce + mse if cfg.lambda_scales == "bce" else bce + cfg.loss_lambda * mse
    return total, bce, mse


def build_model(cfg: GoalConfig, in_channels: int) -> GoalUNet:
    multiple = 2 ** (len(cfg.widths) - 1)
    assert cfg.crop_cells % multiple == 0, f"crop_cells {cfg.crop_cells} must be divisible by {multiple}"
    target_share = 2 * math.pi * cfg.target_sigma_cells**2 / cfg.crop_cells**2  # mass of the target map
    return GoalUNet(
        in_channels=in_channels,
        widths=tuple(cfg.widths),
        prior_logit=math.log(target_share / (1 - target_share)),
        out_channels=cfg.supervised_steps,
    )


@torch.no_grad()
def predict_goals(
    model: GoalUNet,
    obs: Tensor,
    scene: Tensor,
    maps: SceneMaps,
    cfg: GoalConfig,
    goals_cfg: GoalsConfig,
    gen: torch.Generator,
    pred_len: int,
    others: Tensor | None = None,
) -> Tensor:
    """(B, K, 2) world goals, the map's mode first, for observed paths (B, 8, 2) (others: see `goal_inputs`)."""
    return goals_from_map(*goal_map(model, obs, scene, maps, cfg, pred_len, others), cfg, goals_cfg, gen)


def goal_map(
    model: GoalUNet,
    obs: Tensor,
    scene: Tensor,
    maps: SceneMaps,
    cfg: GoalConfig,
    pred_len: int,
    others: Tensor | None = None,
) -> tuple[Tensor, Tensor, Tensor]:
    """The network's part of `predict_goals` (what `fftool export` puts in a graph): the goal map's logits
    (B, S, S) in each path's crop, the crops' centres (B, 2) and rotations (B, 2, 2)."""
    zeros = torch.zeros(obs.shape[0], device=obs.device, dtype=obs.dtype)
    x, center, R = goal_inputs(obs, scene, maps, cfg, zeros, zeros.bool(), pred_len, others)
    return model(x)[:, -1], center, R


def goals_from_map(
    logits: Tensor, center: Tensor, R: Tensor, cfg: GoalConfig, goals_cfg: GoalsConfig, gen: torch.Generator
) -> Tensor:
    """The sampling part of `predict_goals`: (B, K, 2) world goals drawn from the goal maps' logits (B, S, S)."""
    cells = sample_goals(
        logits,
        goals_cfg.k,
        method=goals_cfg.method,
        temperature=goals_cfg.temperature,
        threshold=goals_cfg.threshold,
        samples=goals_cfg.samples,
        iterations=goals_cfg.kmeans_iterations,
        mode_radius=goals_cfg.mode_radius_cells,
        generator=gen,
    )
    return cells_to_world(cells, center, R, cfg.resolution_m, cfg.crop_cells)


def goal_batches(
    model: GoalUNet,
    data: AgentWindows,
    scene: Tensor,
    maps: SceneMaps,
    cfg: GoalConfig,
    goals_cfg: GoalsConfig,
    gen: torch.Generator,
    obs_len: int,
    pred_len: int,
    device: torch.device,
    batch: int,
    neighbours: Neighbours | None = None,
) -> Iterator[tuple[int, Tensor, Tensor]]:
    """(end row, positions (b, T, 2), goals (b, K, 2)) for consecutive batches of `data`, drawn from `gen` in
    row order (what the caller draws from `gen` between batches stays in that order too). neighbours: the other
    walkers of `data`'s rows (default: the other rows of their window)."""
    if cfg.neighbour_channels and neighbours is None:
        neighbours = Neighbours.of(data.xy, data.window_id)
    for start in range(0, len(data), batch):
        index = slice(start, start + batch)
        xy = torch.as_tensor(data.xy[index], dtype=torch.float32, device=device)
        others = None if neighbours is None else neighbours.observed(index, obs_len).to(device)
        obs, where = xy[:, :obs_len], scene[index].to(device)
        goals = predict_goals(model, obs, where, maps, cfg, goals_cfg, gen, pred_len, others)
        yield min(start + batch, len(data)), xy, goals


def evaluate(
    model: GoalUNet,
    data: AgentWindows,
    scene: Tensor,
    maps: SceneMaps,
    cfg: GoalConfig,
    goals_cfg: GoalsConfig,
    device: torch.device,
    seed: int,
    obs_len: int,
    pred_len: int,
    neighbours: Neighbours | None = None,
) -> tuple[float, float]:
    """Mean goal-FDE@K and FDE@1 over `data` (no augmentation, fixed sampling seed)."""
    model.eval()
    gen = generator(seed, device)
    fde_k, fde_1 = [], []
    batch = cfg.batch_size * 4
    batches = goal_batches(model, data, scene, maps, cfg, goals_cfg, gen, obs_len, pred_len, device, batch, neighbours)
    for _, xy, goals in batches:
        k, one = goal_fde(goals, xy[:, -1])
        fde_k.append(k)
        fde_1.append(one)
    return float(torch.cat(fde_k).mean()), float(torch.cat(fde_1).mean())


def load_model(goal: Artifact, device: torch.device) -> tuple[GoalUNet, GoalConfig, GoalsConfig]:
    """Rebuild the trained U-Net from its artifact alone (a damaged model file is an IntegrityError), with the
    goal sampling its best epoch was chosen under."""
    with model_file(goal.file(GOAL_MODEL_FILE), device, "fftool train-goal --force") as saved:
        cfg = GoalConfig.model_validate(saved["config"])
        # channels last, as in training (stages/goal.py): its convolutions run about twice as fast on a CPU
        model = build_model(cfg, saved["in_channels"]).to(device, memory_format=torch.channels_last)
        model.load_state_dict(saved["state_dict"])
        return model.eval(), cfg, GoalsConfig.model_validate(saved["sampling"])
