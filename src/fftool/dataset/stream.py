"""Detections arriving frame by frame, kept as the recent tracks a prediction needs and no more.

A tracker reports positions at its own rate, with jittered times, agents appearing, vanishing and
skipping frames. A prediction at time t reads each agent's positions at the model's grid points
t - (obs_len - 1)·step … t, interpolated from the detections around them, and interpolation bridges at
most `max_gap_s` (as `fftool predict --max-gap`). So a detection older than t - horizon_s, with
horizon_s = (obs_len - 1)·step + max_gap_s, can never be read again, nor can one before a gap longer than
max_gap_s: both are dropped on each `add`, and an agent with no detection left is forgotten. Memory
stays bounded by the agents in view times the detections one horizon holds, however long the stream runs.
Everything is vectorised over the buffered rows; nothing loops over agents.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

_GAP_TOLERANCE_S = 1e-9  # as dataset.steps: a gap of exactly max_gap_s is bridged


@dataclass
class DetectionBuffer:
    """The detections a prediction at the newest time may still read, sorted by agent, then time."""

    horizon_s: float
    max_gap_s: float
    time: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (N,) seconds
    agent: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=object))  # (N,) ids as given
    xy: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (N, 2) metres
    last_time_s: float | None = None

    def add(self, time_s: float, agents: np.ndarray, xy: np.ndarray) -> None:
        """Detections of `agents` (M,) at `xy` (M, 2), all at `time_s`, later than any before (the caller checks)."""
        time = np.concatenate([self.time, np.full(len(agents), time_s)])
        agent = np.concatenate([self.agent, agents])
        points = np.concatenate([self.xy, xy])
        _, code = np.unique(agent, return_inverse=True)
        order = np.lexsort((time, code))
        time, agent, points, code = time[order], agent[order], points[order], code[order]
        new_agent = np.r_[True, code[1:] != code[:-1]]
        cut = new_agent | np.r_[False, np.diff(time) > self.max_gap_s + _GAP_TOLERANCE_S]
        segment = np.cumsum(cut)  # runs of one agent without a gap too long to bridge
        last_segment = np.maximum.reduceat(segment, np.flatnonzero(new_agent)) if len(segment) else segment
        keep = (segment == last_segment[np.cumsum(new_agent) - 1]) & (time >= time_s - self.horizon_s)
        self.time, self.agent, self.xy = time[keep], agent[keep], points[keep]
        self.last_time_s = time_s

    @property
    def agents(self) -> np.ndarray:
        """The ids with a detection still buffered, sorted."""
        return np.unique(self.agent)

    def tracks(self) -> pd.DataFrame:
        """The buffered detections as a track table (time_s, agent, x, y), as `fftool predict` reads a file."""
        return pd.DataFrame({"time_s": self.time, "agent": self.agent, "x": self.xy[:, 0], "y": self.xy[:, 1]})
