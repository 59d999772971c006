"""Cutting one recording's rows into windows of consecutive steps in which every agent is present.

Shared by the `windows` stage (8 + 12 step windows of every benchmark part) and `predict` (the 8 observed
steps before each prediction time). Vectorised over rows: no Python loop over pedestrians or steps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SequenceWindows:
    """The windows of one raw file (one source and split)."""

    first_step: np.ndarray  # (W,) first step of each window with >= 1 valid agent
    t0_step: np.ndarray  # (W,) last observed step
    t0_frame_id: np.ndarray  # (W,) raw frame id of the last observed step
    n_agents: np.ndarray  # (W,) valid agents per window
    n_present: np.ndarray  # (W,) pedestrians present at any step of the window
    agent_window: np.ndarray  # (M,) index into the W windows of each valid agent-window
    agent_ped: np.ndarray  # (M,) ped_id
    agent_xy: np.ndarray  # (M, L, 2) positions at the L window steps
    candidates: int  # window start steps considered (with or without valid agents)
    pedestrians: int
    frames: int


def slice_sequence(
    step: np.ndarray,
    ped_id: np.ndarray,
    frame_id: np.ndarray,
    xy: np.ndarray,
    window_len: int,
    obs_len: int,
    window_stride: int = 1,
) -> SequenceWindows:
    """Every valid agent-window of one raw file.

    Rows are runs of consecutive steps per pedestrian; a run of length n holds n - window_len + 1
    windows. Window starts are on the grid min_step + k * window_stride.
    """
    order = np.lexsort((step, ped_id))  # (N,) by pedestrian, then step
    s, p = step[order], ped_id[order]
    new_run = np.r_[True, (p[1:] != p[:-1]) | (s[1:] != s[:-1] + 1)]
    run_first_row = np.flatnonzero(new_run)  # (R,)
    run_len = np.diff(np.r_[run_first_row, len(s)])  # (R,)
    starts_per_run = np.maximum(run_len - window_len + 1, 0)
    run_of = np.repeat(np.arange(run_first_row.size), starts_per_run)  # (M0,)
    offset = np.arange(run_of.size) - np.repeat(np.cumsum(starts_per_run) - starts_per_run, starts_per_run)
    row0 = run_first_row[run_of] + offset  # (M0,) sorted-row index of each agent-window's first step
    min_step, max_step = int(step.min()), int(step.max())
    row0 = row0[(s[row0] - min_step) % window_stride == 0]

    first = s[row0]
    by_window = np.lexsort((p[row0], first))  # agent-windows ordered by window, then ped_id
    row0, first = row0[by_window], first[by_window]
    window_first, agent_window, n_agents = np.unique(first, return_inverse=True, return_counts=True)
    rows = order[row0[:, None] + np.arange(window_len)]  # (M, L) original row of each step

    n_steps = max_step - min_step + 1
    candidates = max(0, (n_steps - window_len) // window_stride + 1)
    return SequenceWindows(
        first_step=window_first,
        t0_step=window_first + obs_len - 1,
        t0_frame_id=frame_id[rows[np.searchsorted(first, window_first), obs_len - 1]]
        if rows.size
        else np.zeros(0, np.int64),
        n_agents=n_agents.astype(np.int32),
        n_present=_present_counts(step, ped_id, window_first, window_len),
        agent_window=agent_window.astype(np.int64),
        agent_ped=p[row0],
        agent_xy=xy[rows],
        candidates=candidates,
        pedestrians=int(np.unique(ped_id).size),
        frames=int(np.unique(step).size),
    )


def _present_counts(step: np.ndarray, ped_id: np.ndarray, window_first: np.ndarray, window_len: int) -> np.ndarray:
    """Pedestrians present at any step of each window, via a peds × distinct-steps presence prefix sum.

    Columns are the distinct steps seen, not every step of the span: a valid but far-off frame id
    (any int64 passes ingest) must not size the array by the gap.
    """
    steps, step_index = np.unique(step, return_inverse=True)
    _, ped_index = np.unique(ped_id, return_inverse=True)
    presence = np.zeros((ped_index.max() + 1, steps.size + 1), dtype=np.int32)  # (P, S+1)
    presence[ped_index, step_index + 1] = 1
    cumulative = presence.cumsum(axis=1)
    # Window w covers the distinct steps with index lo[w] <= i < hi[w].
    lo, hi = np.searchsorted(steps, window_first), np.searchsorted(steps, window_first + window_len)
    inside = cumulative[:, hi] - cumulative[:, lo]  # (P, W)
    return (inside > 0).sum(axis=0).astype(np.int32)
