"""Artifact -> array loaders shared by the learning stages (goal, goals, and later cvae, evaluate).

Stages read each other's outputs only through these loaders and `schema.py`, never by import.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
import pyarrow.parquet as pq
import torch

from fftool.scenes import SOURCE_SCENE
from fftool.schema import AGENT_WINDOWS_FILE, MAPS_TRANSFORMS_FILE, WINDOWS_FILE, map_file
from fftool.store import Artifact


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
    agents = pq.read_table(windows.file(AGENT_WINDOWS_FILE), columns=["benchmark", "part", "window_id", "ped_id"])
    keys = agents.to_pandas()
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
    xy_column = pq.read_table(windows.file(AGENT_WINDOWS_FILE), columns=["xy"]).column("xy").take(rows)
    window_len = int(windows.manifest.stats["window_len"])
    xy = xy_column.combine_chunks().flatten().to_numpy().reshape(len(rows), window_len, 2).copy()  # writable
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
        return torch.as_tensor([lookup.get(SOURCE_SCENE.get(s) or "", none) for s in sources], dtype=torch.long)

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
