"""User tracks on the model's time grid, and the observed windows ending at each prediction time.

The grid is anchored at the file's last time (step 0) and spaced by the model's step. A file already on
that grid keeps its positions exactly; any other file is resampled by linear interpolation per agent,
which `warnings` says. A gap in an agent's track longer than `max_gap_s` is never bridged: it is an
error naming the agent and the time. Everything is vectorised over rows (searchsorted over agent-major
keys), with no Python loop over agents or steps.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from fftool.dataset.windowing import slice_sequence
from fftool.errors import RawDataError, UsageError

_ON_GRID = 1e-6  # a time within this many steps of a grid point is on it
_MAX_STEPS = 2**31  # the longest grid a file may span (steps are int64 from float64 times)
# How tracks are put on the grid; a custom dataset's tracks fingerprint hashes it (dataset/custom.py), so a
# change here rebuilds them. 2: each time snapped onto the grid on its own (1 dropped near-grid end points).
RESAMPLING_VERSION = 2


@dataclass(frozen=True)
class StepTracks:
    """Positions at integer steps (step 0 = the file's last time), agents as codes into `labels`."""

    agent: np.ndarray  # (N,) int64 code
    step: np.ndarray  # (N,) int64, <= 0
    xy: np.ndarray  # (N, 2) float64 metres
    labels: np.ndarray  # (P,) the agent ids of the file, sorted
    last_time_s: float  # the time of step 0
    step_s: float
    warnings: list[str] = field(default_factory=list)

    def time_of(self, step: np.ndarray) -> np.ndarray:
        return self.last_time_s + step * self.step_s


def to_steps(path: Path, tracks: pd.DataFrame, step_s: float, max_gap_s: float) -> StepTracks:
    """Tracks (time_s, agent, x, y; sorted by agent, time) on the grid of `step_s` seconds ending at the last time."""
    xy = tracks[["x", "y"]].to_numpy()
    return grid_steps(path, tracks["time_s"].to_numpy(), tracks["agent"].to_numpy(), xy, step_s, max_gap_s)


def grid_steps(
    path: Path, time: np.ndarray, agent_ids: np.ndarray, xy: np.ndarray, step_s: float, max_gap_s: float
) -> StepTracks:
    """`to_steps` of rows given as arrays: times (N,) s, agent ids (N,), positions (N, 2) m, sorted by agent, time."""
    labels, agent = np.unique(agent_ids, return_inverse=True)
    last = float(time.max())
    same = agent[1:] == agent[:-1]
    gaps = np.flatnonzero(same & (np.diff(time) > max_gap_s + 1e-9))
    if gaps.size:
        i = gaps[0]
        raise RawDataError(
            path,
            f"agent {labels[agent[i]]} has no position from time {time[i]:.6g} s to {time[i + 1]:.6g} s, a gap "
            f"longer than {max_gap_s:g} s that interpolation would invent; split the track or raise the gap limit",
        )
    with np.errstate(over="ignore"):
        rel = (time - last) / step_s
    if not np.isfinite(rel).all() or rel.min() < -_MAX_STEPS:  # a grid this long has no int64 steps
        raise RawDataError(
            path,
            f"times span {last - float(time.min()):.6g} s, more than {_MAX_STEPS:,} steps of {step_s:g} s; expected "
            "times in seconds (or frame numbers with their frame step)",
        )
    # A time on the grid up to floating-point rounding (a frame number times a frame step, a unit converted)
    # is snapped onto it, each on its own: ceil/floor of an unsnapped -2.9999999997 would drop that observation.
    near = np.abs(rel - np.round(rel)) < _ON_GRID
    on_grid = bool(near.all())
    rel = np.where(near, np.round(rel), rel)
    first, end = np.ceil(rel[np.r_[True, ~same]]), np.floor(rel[np.r_[~same, True]])
    counts = np.maximum(end - first + 1, 0).astype(np.int64)  # (P,) grid points per agent
    grid_agent = np.repeat(np.arange(len(counts)), counts)
    grid_step = np.repeat(first, counts) + np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    # Agent-major keys: each agent's times lie in its own interval, so one searchsorted finds every segment.
    span = float(rel.max() - rel.min()) + 2.0
    key, grid_key = agent * span + (rel - rel.min()), grid_agent * span + (grid_step - rel.min())
    right = np.clip(np.searchsorted(key, grid_key, side="left"), 0, len(key) - 1)
    exact = key[right] == grid_key
    left = np.where(exact, right, right - 1)
    width = np.where(exact, 1.0, rel[right] - rel[left])
    weight = np.where(exact, 0.0, (grid_step - rel[left]) / width)[:, None]
    grid_xy = np.where(exact[:, None], xy[right], xy[left] + weight * (xy[right] - xy[left]))
    warnings = []
    native = float(np.median(np.diff(time)[same])) if same.any() else step_s
    if not exact.all():
        how = "resampled" if not on_grid else "filled"
        warnings.append(
            f"{path}: {how} {int((~exact).sum())} of {exact.size} positions by linear interpolation onto the "
            f"model's {step_s:g} s step (the file's step is {native:.4g} s)"
        )
    elif not on_grid:
        warnings.append(
            f"{path}: read the {exact.size} positions on the model's {step_s:g} s grid; the other "
            f"{int((~near).sum())} lie between its points and were not used (the file's step is {native:.4g} s)"
        )
    return StepTracks(grid_agent.astype(np.int64), grid_step.astype(np.int64), grid_xy, labels, last, step_s, warnings)


@dataclass(frozen=True)
class ObservedWindows:
    """The agents with every observed step at each prediction time, window-major then by agent."""

    xy: np.ndarray  # (M, obs_len, 2) float64 metres
    agent: np.ndarray  # (M,) int64 code into StepTracks.labels
    window: np.ndarray  # (M,) int64 window index 0..W-1
    t0_step: np.ndarray  # (W,) the prediction step (last observed) of each window


def prediction_steps(tracks: StepTracks, at: str | list[float]) -> np.ndarray | None:
    """The steps to predict from: the last time ("last"), every step ("all": None) or the given times (seconds)."""
    if at == "last":
        return np.zeros(1, dtype=np.int64)
    if at == "all":
        return None
    rel = (np.asarray(at, dtype=np.float64) - tracks.last_time_s) / tracks.step_s
    outside = np.flatnonzero((rel > _ON_GRID) | (rel < tracks.step.min() - _ON_GRID))
    if outside.size:
        raise UsageError(
            f"--at {at[outside[0]]:g}: outside the file's times ({tracks.time_of(tracks.step.min()):.6g} to "
            f"{tracks.last_time_s:.6g} s)"
        )
    off = np.flatnonzero(np.abs(rel - np.round(rel)) > _ON_GRID)
    if off.size:
        raise UsageError(
            f"--at {at[off[0]]:g}: not on the model's {tracks.step_s:g} s grid, which ends at the file's last "
            f"time {tracks.last_time_s:.6g} s"
        )
    return np.round(rel).astype(np.int64)


def observed_windows(
    path: Path, tracks: StepTracks, obs_len: int, steps: np.ndarray | None, require: bool = True
) -> ObservedWindows:
    """Every agent present at all `obs_len` steps up to each prediction step (None: every step that has one).

    None found is an error naming the times, unless `require` is False (a stream: nobody in view yet)."""
    found = slice_sequence(tracks.step, tracks.agent, tracks.step, tracks.xy, obs_len, obs_len)
    keep_window = np.ones(found.t0_step.size, bool) if steps is None else np.isin(found.t0_step, steps)
    if require and not keep_window.any():
        times = ", ".join(f"{t:.6g} s" for t in tracks.time_of(steps)[:5]) if steps is not None else "any time"
        raise RawDataError(
            path,
            f"no agent has {obs_len} observed steps of {tracks.step_s:g} s up to {times}: expected at least one "
            f"agent present at every one of the {obs_len} steps before a prediction time",
        )
    if require and steps is not None:  # every time asked for, not just one of them
        missing = np.setdiff1d(steps, found.t0_step)
        if missing.size:
            when = tracks.time_of(missing[:1])[0]
            raise RawDataError(
                path,
                f"no agent has {obs_len} observed steps of {tracks.step_s:g} s up to {when:.6g} s (asked for): "
                f"expected at least one agent present at every one of the {obs_len} steps before it",
            )
    keep = keep_window[found.agent_window]
    renumber = np.cumsum(keep_window) - 1
    return ObservedWindows(
        xy=found.agent_xy[keep],
        agent=found.agent_ped[keep],
        window=renumber[found.agent_window[keep]],
        t0_step=found.t0_step[keep_window],
    )
