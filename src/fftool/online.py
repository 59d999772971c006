"""A trained model in a control loop: detections in as they come, K futures per agent in view out.

    from fftool.online import OnlinePredictor
    online = OnlinePredictor("cpu/zara1/dr", k=20)
    result = online.update(time_s, {agent: (x, y)})   # result.futures: (M, K, 12, 2) for result.agents

Each update draws through `fftool.api.draw_futures`, the path `predict_tracks` takes, so a stream gives the
numbers `fftool predict --at` gives for the same detections and seed (to float rounding: an update decodes its
most-likely future in the same rollout); an `fftool export` folder runs its ONNX
graph with onnxruntime instead (within 1e-4 m of the torch path).
"""

from __future__ import annotations

import copy
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from fftool import zoo
from fftool.api import (
    MAX_ABS_COORDINATE_M,
    Drawn,
    DrawsGoals,
    Model,
    check_k,
    check_seed,
    draw_futures,
    futures_table,
    goals_per_sample,
    load,
    load_goal_sampler,
    off_limits,
)
from fftool.dataset.steps import grid_steps, observed_windows
from fftool.dataset.stream import DetectionBuffer
from fftool.errors import InputError, UsageError
from fftool.export import is_export
from fftool.exported import ExportedModel
from fftool.variants import reads_goal


@dataclass(frozen=True)
class OnlineFutures:
    """What one `OnlinePredictor.update` returns: K futures of every agent with a full observed history."""

    time_s: float
    agents: np.ndarray  # (M,) ids as the detections gave them, sorted
    futures: np.ndarray  # (M, K, pred_len, 2) metres
    goals: np.ndarray  # (M, K, 2) the goal each future steered toward (the last position for goal-free variants)
    # (M, pred_len, 2) one future per agent for a planner that wants one (`Model.most_likely`)
    most_likely: np.ndarray

    def table(self) -> pd.DataFrame:
        """The long format of `predict_tracks`: one row per (agent, sample, step)."""
        return futures_table(np.full(len(self.agents), self.time_s), self.agents, self.goals, self.futures)


Detections = Mapping[object, tuple[float, float]]  # agent id -> (x, y) metres


class OnlinePredictor:
    """A trained model in a control loop: feed detections as they come, get K futures per agent in view.

        online = OnlinePredictor("cpu/zara1/dr", k=20)     # a Model, an artifact id, folder or shipped name,
                                                           # or the folder of `fftool export` (onnxruntime)
        for time_s, detections in tracker:                 # {agent id: (x, y) metres}, at the sensor's rate
            result = online.update(time_s, detections)     # result.futures: (M, K, 12, 2) for result.agents

    Each update predicts at its own time for every agent detected then with positions at all obs_len grid
    points of the model's step before it (interpolated from the detections, bridging gaps up to max_gap_s):
    the numbers `predict_tracks(..., at=[time_s])` gives for the detections so far, with the same seed (within
    1e-5 m: the most-likely future rides in the same rollout, a product one row larger).
    Memory is bounded (dataset/stream.py). An update is all or nothing: one refused (an InputError) or failing
    (a goal variant's goal missing) leaves the predictor as it was, so the corrected update is taken.
    Not for several threads at once: a second `update` while one runs is refused with a UsageError (give each
    thread its own predictor, or serialise the calls).
    """

    def __init__(
        self,
        model: Model | ExportedModel | str | Path,
        *,
        k: int = 20,
        seed: int = 0,
        goal_sampler: DrawsGoals | str | Path | None = None,
        max_gap_s: float = 1.0,
        root: Path | None = None,
        device: str | torch.device = "cpu",
    ) -> None:
        """goal_sampler: a goal U-Net (or its reference) drawing K goals per agent for goal variants; a shipped
        goal variant brings its own, and so does an export of one made with its goal U-Net. Without one, goal
        variants take `goals` in each update."""
        if isinstance(model, (str, Path)) and is_export(Path(model)):
            model = ExportedModel.load(model)
        if isinstance(model, ExportedModel):
            if k != model.k:
                raise UsageError(f"k = {k}: {model.folder} was exported with K = {model.k} (its graph's codes)")
            goal_sampler = goal_sampler or model.goal_sampler  # exported with its goal U-Net: that graph
        elif not isinstance(model, Model):
            shipped = zoo.is_name(model)
            name, model = model, load(model, root=root, device=device)
            if goal_sampler is None and shipped and reads_goal(model.variant):
                goal_sampler = name  # as `fftool predict --model cpu/zara1/dr`: its benchmark's goal U-Net
        if isinstance(goal_sampler, (str, Path)):
            goal_sampler = load_goal_sampler(goal_sampler, root=root, device=model.device)
        check_k(k, 1, model.pred_len)
        check_seed(seed)
        if not max_gap_s >= 0:
            raise UsageError(f"max_gap_s = {max_gap_s}: expected seconds, at least 0")
        self.model, self.k, self.seed, self.goal_sampler = model, k, seed, goal_sampler
        self.max_gap_s = float(max_gap_s)
        self.buffer = DetectionBuffer((model.obs_len - 1) * model.step_s + self.max_gap_s, self.max_gap_s)
        self.id_kind: type | None = None  # str or int, fixed by the first detection
        self._busy = threading.Lock()

    def update(
        self,
        time_s: float,
        detections: Mapping[object, tuple[float, float]],
        goals: Mapping[object, tuple[float, float]] | None = None,
    ) -> OnlineFutures:
        """Take the detections at `time_s` (seconds, later than the last update) and predict from them.

        goals: for goal variants, one (x, y) per agent detected now: used before any goal sampler's goals (an
        agent without one gets the sampler's K goals)."""
        if not self._busy.acquire(blocking=False):
            raise UsageError("OnlinePredictor.update: called again while an update runs (one predictor per thread)")
        before = copy.copy(self.buffer), self.id_kind  # add() replaces the buffer's arrays, never edits them
        try:
            return self._update(time_s, detections, goals)
        except BaseException:
            self.buffer, self.id_kind = before
            raise
        finally:
            self._busy.release()

    def _update(
        self,
        time_s: float,
        detections: Mapping[object, tuple[float, float]],
        goals: Mapping[object, tuple[float, float]] | None,
    ) -> OnlineFutures:
        agents, xy = self._checked(time_s, detections)
        if goals is not None:
            _positions(goals, [a for a in agents if a in goals], "goal of agent", time_s)
        self.buffer.add(float(time_s), agents, xy)
        self.id_kind = self.id_kind or (_id_kind(agents[0]) if len(agents) else None)
        k, pred_len = self.k, self.model.pred_len
        result = OnlineFutures(
            float(time_s), agents[:0], np.zeros((0, k, pred_len, 2)), np.zeros((0, k, 2)), np.zeros((0, pred_len, 2))
        )
        if len(agents):
            buffer = self.buffer
            steps = grid_steps(_STREAM, buffer.time, buffer.agent, buffer.xy, self.model.step_s, self.max_gap_s)
            found = observed_windows(_STREAM, steps, self.model.obs_len, np.zeros(1, np.int64), require=False)
            if len(found.xy):
                labels = steps.labels[found.agent]
                if isinstance(self.model, ExportedModel):
                    drawn = self._exported(found.xy, labels, goals)
                else:
                    drawn = draw_futures(
                        self.model, found, labels, k=k, seed=self.seed, goals=goals, goal_sampler=self.goal_sampler
                    )
                result = OnlineFutures(float(time_s), labels, drawn.futures, drawn.goals, drawn.most_likely)
        return result

    def _exported(self, past: np.ndarray, labels: np.ndarray, goals: Detections | None) -> Drawn:
        """An exported model's K futures and most-likely future of the agents observed at past (M, obs_len, 2): one
        scene, one call of its graph; the same goals as the torch path (passed first, else the goal sampler's K)."""
        model, k = self.model, self.k
        assert isinstance(model, ExportedModel)
        if not reads_goal(model.variant):
            futures, most_likely = model.draw(past, None, self.seed)
            return Drawn(np.repeat(past[:, None, -1], k, 1), futures, most_likely)
        chosen, all_passed = goals_per_sample(
            model.variant, labels, past, goals, self.goal_sampler, k=k, seed=self.seed, pred_len=model.pred_len,
            device=model.device,
        )  # fmt: skip
        # every agent's goal known: the graph for one goal per agent, as the torch path decodes known goals
        futures, most_likely = model.draw(past, chosen[:, 0] if all_passed else chosen, self.seed)
        return Drawn(chosen, futures, most_likely)

    def _checked(self, time_s: object, detections: object) -> tuple[np.ndarray, np.ndarray]:
        """(M,) agent ids and (M, 2) positions of an update, or an InputError before any state changes."""
        if isinstance(time_s, bool) or not isinstance(time_s, (int, float, np.integer, np.floating)):
            raise InputError(f"time {time_s!r}: expected a number of seconds")
        if not np.isfinite(time_s):
            raise InputError(f"time {time_s}: expected a finite number of seconds")
        last = self.buffer.last_time_s
        if last is not None and not time_s > last:
            raise InputError(f"time {time_s:.6g} s: not after the last update's {last:.6g} s; times must increase")
        if not isinstance(detections, Mapping):
            raise InputError(f"detections: expected a mapping of agent id to (x, y), got {type(detections).__name__}")
        agents = np.array(list(detections), dtype=object)
        kind = self.id_kind or (_id_kind(agents[0]) if len(agents) else None)
        odd = [a for a in agents if _id_kind(a) is not kind or kind is None]
        if odd:
            raise InputError(
                f"agent id {odd[0]!r}: expected ids of one kind for the whole stream, all whole numbers or all "
                f"strings{f' (this stream has {kind.__name__} ids)' if kind else ''}"
            )
        return agents, _positions(detections, agents, "agent", time_s)


_STREAM = Path("<stream>")


def _id_kind(agent: object) -> type | None:
    """int or str: the agent ids a stream may use (sortable, as the windows order agents by id)."""
    if isinstance(agent, str):
        return str
    return int if isinstance(agent, (int, np.integer)) and not isinstance(agent, bool) else None


def _positions(of: Mapping[object, object], agents: object, what: str, time_s: object) -> np.ndarray:
    """(M, 2) finite coordinates within bounds of `agents` in `of`, or an InputError naming the first bad one."""
    rows = []
    for agent in agents:
        point = np.asarray(of[agent], dtype=object)
        if point.shape != (2,) or not all(isinstance(v, (int, float, np.integer, np.floating)) for v in point):
            raise InputError(f"{what} {agent!r} at {time_s} s: {of[agent]!r} is not an (x, y) pair of numbers")
        rows.append(point.astype(np.float64))
    xy = np.array(rows, dtype=np.float64).reshape(-1, 2)
    off = np.flatnonzero(off_limits(xy))
    if off.size:
        agent = list(agents)[off[0]]
        raise InputError(
            f"{what} {agent!r} at {time_s} s: {xy[off[0]].tolist()} is not a finite coordinate within "
            f"±{MAX_ABS_COORDINATE_M:g} m"
        )
    return xy
