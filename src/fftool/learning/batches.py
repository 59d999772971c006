"""Artifact -> array loaders shared by the learning stages (goal, goals, cvae, evaluate) and the plots, and
the pair-budget batching they share with the forces stage.

Stages read each other's outputs only through these loaders and `schema.py`, never by import.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, fields

import numpy as np
import pyarrow.parquet as pq
import torch

from fftool.artifacts.schema import AGENT_WINDOWS_FILE, MAPS_TRANSFORMS_FILE, WINDOWS_FILE, map_file
from fftool.artifacts.store import Artifact
from fftool.dataset.scenes import scene_of


@dataclass(frozen=True)
class AgentWindows:
    """The valid agent-windows of one benchmark part, in agent_windows.parquet order."""

    xy: np.ndarray  # (M, L, 2) float64 metres
    source: np.ndarray  # (M,) str
    first_step: np.ndarray  # (M,) int64
    window_id: np.ndarray  # (M,) int64
    ped_id: np.ndarray  # (M,) int64
    row: np.ndarray  # (M,) int64 row of agent_windows.parquet

    def __len__(self) -> int:
        return len(self.row)

    def subset(self, index: np.ndarray) -> AgentWindows:
        return AgentWindows(
            self.xy[index],
            self.source[index],
            self.first_step[index],
            self.window_id[index],
            self.ped_id[index],
            self.row[index],
        )


def load_agent_windows(windows: Artifact, benchmark: str, part: str, stride: int = 1) -> AgentWindows:
    """Valid agent-windows of (benchmark, part); with stride > 1 only windows starting every stride steps."""
    agents = pq.read_table(windows.file(AGENT_WINDOWS_FILE))  # one read: keys and positions
    keys = agents.select(["benchmark", "part", "window_id", "ped_id"]).to_pandas()
    rows = np.flatnonzero((keys["benchmark"] == benchmark).to_numpy() & (keys["part"] == part).to_numpy())
    table = pq.read_table(
        windows.file(WINDOWS_FILE), filters=[("benchmark", "=", benchmark), ("part", "=", part)]
    ).to_pandas()
    table = table.set_index("window_id")
    window_id = keys["window_id"].to_numpy()[rows]
    first_step = table.loc[window_id, "first_step"].to_numpy()
    source = table.loc[window_id, "source"].astype(str).to_numpy()
    keep = first_step % stride == 0
    rows = rows[keep]
    window_len = int(windows.manifest.stats["window_len"])
    xy = agents.column("xy").take(rows).combine_chunks().flatten().to_numpy()
    xy = xy.reshape(len(rows), window_len, 2).copy()  # writable
    return AgentWindows(
        xy=xy,
        source=source[keep],
        first_step=first_step[keep],
        window_id=window_id[keep],
        ped_id=keys["ped_id"].to_numpy()[rows],
        row=rows,
    )


@dataclass(frozen=True)
class SceneMaps:
    """Every scene raster stacked and zero-padded to one size, plus an all-zero 'no map' scene last."""

    stack: torch.Tensor  # (n_scenes + 1, C, H, W)
    origins: torch.Tensor  # (n_scenes + 1, 2) world (x0, y0)
    resolution_m: float
    names: tuple[str, ...]

    @property
    def channels(self) -> int:
        return self.stack.shape[1]

    def index_of_sources(self, sources: np.ndarray) -> torch.Tensor:
        """(M,) scene index of each source; sources without a map get the zero scene."""
        lookup = {name: i for i, name in enumerate(self.names)}
        none = len(self.names)
        return torch.as_tensor([lookup.get(scene_of(s) or "", none) for s in sources], dtype=torch.long)

    def to(self, device: torch.device) -> SceneMaps:
        return SceneMaps(self.stack.to(device), self.origins.to(device), self.resolution_m, self.names)


def load_scene_maps(maps: Artifact) -> SceneMaps:
    meta = json.loads(maps.file(MAPS_TRANSFORMS_FILE).read_text())
    names = tuple(meta["scenes"])
    rasters = [np.load(maps.file(map_file(name))) for name in names]
    channels = len(meta["channels"])
    height = max([r.shape[1] for r in rasters], default=1)
    width = max([r.shape[2] for r in rasters], default=1)
    stack = torch.zeros(len(names) + 1, channels, height, width)
    for i, raster in enumerate(rasters):
        stack[i, :, : raster.shape[1], : raster.shape[2]] = torch.from_numpy(raster)
    origins = torch.tensor(
        [[meta["scenes"][n]["origin_x_m"], meta["scenes"][n]["origin_y_m"]] for n in names] + [[0.0, 0.0]]
    )
    resolution = float(next(iter(meta["scenes"].values()))["resolution_m"]) if names else 1.0
    return SceneMaps(stack, origins, resolution, names)


@dataclass(frozen=True)
class SceneBatch:
    """Windows padded to A agent slots: the data <-> model contract of the CVAE.

    xy (B, A, L, 2) world positions; agent_mask (B, A); f_dr, f_re (B, A, L, 2) stored forces; speed0
    (B, A) desired speed; group (B, A) window-local group ids (-1 alone); row (B, A) the agent_windows
    row of each slot (-1 padding).
    """

    xy: torch.Tensor
    agent_mask: torch.Tensor
    f_dr: torch.Tensor
    f_re: torch.Tensor
    speed0: torch.Tensor
    group: torch.Tensor
    row: torch.Tensor

    def map(self, fn: Callable[[torch.Tensor], torch.Tensor]) -> SceneBatch:
        """The batch with fn applied to every field."""
        return SceneBatch(*(fn(getattr(self, f.name)) for f in fields(self)))

    def to(self, device: torch.device) -> SceneBatch:
        return self.map(lambda t: t.to(device))


def pair_budget_batches(sorted_agents: np.ndarray, max_pairs: int, max_windows: int | None = None) -> list[slice]:
    """Cut windows sorted by agent count into consecutive runs of at most `max_windows` whose windows ×
    largest agent count² stays within `max_pairs`: pairwise tensors grow with agents², so this bounds memory.

    A window over the budget on its own still gets a run; a window without agents counts as one.
    """
    runs, begin = [], 0
    while begin < len(sorted_agents):
        end = begin + 1
        while (
            end < len(sorted_agents)
            and (max_windows is None or end - begin < max_windows)
            and (end + 1 - begin) * max(int(sorted_agents[end]), 1) ** 2 <= max_pairs
        ):
            end += 1
        runs.append(slice(begin, end))
        begin = end
    return runs


@dataclass(frozen=True)
class SceneSet:
    """Every window of one benchmark part with its agents' rows, ready to be cut into padded batches."""

    data: AgentWindows
    arrays: dict[str, np.ndarray]  # forces arrays restricted to data's rows
    window_start: np.ndarray  # (W + 1,) agents of window w are data rows window_start[w]:window_start[w+1]

    @property
    def windows(self) -> int:
        return len(self.window_start) - 1

    def agents(self) -> np.ndarray:
        """(W,) agents per window."""
        return np.diff(self.window_start)

    def plan(
        self, order: np.ndarray, batch_windows: int, max_pairs: int, rng: np.random.Generator, max_agents: int = 0
    ) -> list[np.ndarray]:
        """Cut windows (in the given order) into batches of similar agent counts.

        Attention cost grows with agents², so windows are sorted by agent count inside blocks of
        16 batches and cut where a batch would exceed `batch_windows` windows or `max_pairs` (windows ×
        largest agent count²); the batches are then shuffled, so the order stays random but padding small.
        max_agents: the cap `batch` will apply (0: none), so a crowded window is planned as the agents it
        will carry, not as its uncapped count.
        """
        counts = self.agents() if not max_agents else np.minimum(self.agents(), max_agents)
        batches: list[np.ndarray] = []
        block = 16 * batch_windows
        for start in range(0, len(order), block):
            chunk = order[start : start + block]
            chunk = chunk[np.argsort(counts[chunk], kind="stable")]
            batches.extend(chunk[run] for run in pair_budget_batches(counts[chunk], max_pairs, batch_windows))
        return [batches[i] for i in rng.permutation(len(batches))]

    def batch(self, windows: np.ndarray, max_agents: int = 0, rng: np.random.Generator | None = None) -> SceneBatch:
        """Pad the given windows to their largest agent count (capped at max_agents, sampled with rng)."""
        members = [np.arange(self.window_start[w], self.window_start[w + 1]) for w in windows]
        if max_agents:
            members = [
                np.sort((rng or np.random.default_rng(0)).choice(m, max_agents, replace=False))
                if len(m) > max_agents
                else m
                for m in members
            ]
        A = max(len(m) for m in members)
        index = np.full((len(windows), A), -1, dtype=np.int64)
        for i, m in enumerate(members):  # one small copy per window, not per agent
            index[i, : len(m)] = m
        mask = index >= 0
        safe = np.where(mask, index, 0)
        take = lambda a: torch.as_tensor(a[safe])  # noqa: E731
        return SceneBatch(
            xy=torch.as_tensor(self.data.xy[safe], dtype=torch.float32),
            agent_mask=torch.as_tensor(mask),
            f_dr=take(self.arrays["f_dr"]),
            f_re=take(self.arrays["f_re"]),
            speed0=take(self.arrays["speed0"])[..., 0],
            group=torch.where(torch.as_tensor(mask), take(self.arrays["group_id"]).long(), -1),
            row=torch.as_tensor(np.where(mask, self.data.row[safe], -1)),
        )


def _not_read(name: str, agents_steps: tuple[int, ...]) -> np.ndarray:
    """A forces array that was not read: zeros (group ids -1, alone) as a view of one scalar, no memory."""
    shapes = {"f_dr": (*agents_steps, 2), "f_re": (*agents_steps, 2), "velocity": (*agents_steps, 2),
              "goal": (agents_steps[0], 2), "speed0": agents_steps, "group_id": agents_steps[:1]}  # fmt: skip
    fill = np.int32(-1) if name == "group_id" else np.float32(0)
    return np.broadcast_to(fill, shapes[name])


def load_scene_set(
    windows: Artifact,
    forces: Artifact | None,
    benchmark: str,
    part: str,
    stride: int = 1,
    reads: tuple[str, ...] | None = None,
) -> SceneSet:
    """A benchmark part's windows with the forces arrays named in `reads` (default: all) of each agent-window.

    The arrays not read are zeros (group ids -1, no group) that cost no memory: a consumer can only use
    what it declared, which is what its fingerprint hashes (`Stage.reads`). Rows align by construction.
    """
    from fftool.artifacts.schema import FORCES_ARRAYS

    data = load_agent_windows(windows, benchmark, part, stride)
    reads = tuple(FORCES_ARRAYS) if reads is None else reads
    if reads and forces is None:
        raise ValueError(f"reading forces arrays {reads} needs the forces artifact")
    arrays = {
        name: np.load(forces.file(file), mmap_mode="r")[data.row] if forces is not None and name in reads else
        _not_read(name, data.xy.shape[:2])
        for name, file in FORCES_ARRAYS.items()
    }  # fmt: skip
    change = np.flatnonzero(np.diff(data.window_id)) + 1
    return SceneSet(data, arrays, np.r_[0, change, len(data)])
