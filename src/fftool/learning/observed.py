"""Observed paths -> the model's padded batches: what `predict` and the API hand to the shared sampler.

The model reads, besides positions, each agent's desired speed and (re) its group, which the `forces`
stage computes per window. Here they come from the observed steps alone, with the same function
(`window_forces`) in the same frame (centred on the window's first agent), so an agent-window the
`forces` stage saw gets the same numbers. Groups are found among the agents handed in: DBSCAN per
step over them, not over every pedestrian of the recording.
"""

from __future__ import annotations

import numpy as np
import torch

from fftool.config import ForcesConfig
from fftool.learning.batches import AgentWindows, SceneBatch, SceneSet
from fftool.science.groups import cluster_frames
from fftool.science.social_forces import group_ids, window_forces


def desired_speed_and_groups(
    past: np.ndarray, mask: np.ndarray, cfg: ForcesConfig | None, dt_s: float | None, groups: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """(B, A) desired speed v0 and (B, A) window-local group ids (-1 alone) from past (B, A, T, 2) metres.

    mask (B, A): real agents. Without force constants (a variant that reads no force) both are unused:
    zeros and -1. groups: False for a variant that reads no group (every id -1, without the DBSCAN runs).
    """
    B, A, T, _ = past.shape
    if cfg is None or dt_s is None or B == 0:
        return np.zeros((B, A), np.float32), np.full((B, A), -1, np.int64)
    present = np.repeat(mask[:, :, None], T, axis=2)
    frame_key = np.broadcast_to(np.arange(B)[:, None, None] * T + np.arange(T), (B, A, T))
    labels = np.full((B, A, T), -1, dtype=np.int64)
    if groups:
        labels[present] = cluster_frames(frame_key[present], past[present], cfg.dbscan_eps_m, cfg.dbscan_min_samples)
    origin = past[:, :1, T - 1 : T]  # as the forces stage: float32 stays precise near the window
    position = torch.as_tensor(past - origin, dtype=torch.float32)
    valid = torch.as_tensor(mask)
    result = window_forces(
        position, torch.as_tensor(present), position[:, :, -1], torch.as_tensor(labels), cfg, dt_s=dt_s, obs_len=T
    )
    together = result.groups & valid[:, :, None] & valid[:, None, :]
    return result.speed0[..., 0].numpy(), group_ids(together).numpy()


def padded_batch(
    past: np.ndarray, mask: np.ndarray, pred_len: int, cfg: ForcesConfig | None, dt_s: float | None
) -> SceneBatch:
    """A SceneBatch of observed paths (B, A, T, 2) metres: the future is zeros, as the sampler never reads it."""
    B, A, T, _ = past.shape
    speed0, group = desired_speed_and_groups(past, mask, cfg, dt_s)
    xy = np.concatenate([past, np.zeros((B, A, pred_len, 2))], 2)
    zeros = torch.zeros(B, A, T + pred_len, 2)
    row = np.where(mask, np.arange(B * A).reshape(B, A), -1)
    return SceneBatch(
        xy=torch.as_tensor(xy, dtype=torch.float32),
        agent_mask=torch.as_tensor(mask),
        f_dr=zeros,
        f_re=zeros.clone(),
        speed0=torch.as_tensor(speed0),
        group=torch.as_tensor(np.where(mask, group, -1)),
        row=torch.as_tensor(row),
    )


def scene_set(
    xy: np.ndarray,
    window: np.ndarray,
    agent: np.ndarray,
    pred_len: int,
    cfg: ForcesConfig | None,
    dt_s: float | None,
    groups: bool = True,
) -> SceneSet:
    """Agent-windows (M, T, 2) of windows 0..W-1 (sorted) as a SceneSet the planner cuts into batches; groups:
    whether the variant reads them (`desired_speed_and_groups`)."""
    M, T, _ = xy.shape
    window_start = np.r_[0, np.flatnonzero(np.diff(window)) + 1, M]
    counts = np.diff(window_start)
    slot = np.arange(M) - np.repeat(window_start[:-1], counts)
    mask = np.zeros((len(counts), int(counts.max()) if M else 0), dtype=bool)
    mask[window, slot] = True
    past = np.zeros((*mask.shape, T, 2))
    past[window, slot] = xy
    speed0, group = desired_speed_and_groups(past, mask, cfg, dt_s, groups)
    L = T + pred_len
    data = AgentWindows(
        xy=np.concatenate([xy, np.zeros((M, pred_len, 2))], 1),
        source=np.full(M, "", dtype=object),
        first_step=np.zeros(M, np.int64),
        window_id=window.astype(np.int64),
        ped_id=agent.astype(np.int64),
        row=np.arange(M, dtype=np.int64),
    )
    zeros = np.broadcast_to(np.float32(0), (M, L, 2))
    arrays = {
        "f_dr": zeros,
        "f_re": zeros,
        "speed0": np.broadcast_to(speed0[window, slot][:, None], (M, L)),
        "group_id": group[window, slot].astype(np.int32),
    }
    return SceneSet(data, arrays, window_start)
