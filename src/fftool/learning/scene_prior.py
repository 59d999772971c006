"""A scene prior for the goal U-Net: where the training part's pedestrians walked, as one more map channel.

A pedestrian's goal lies where people walk. The benchmark's training part holds tracks of the same physical
places as its test part (zara1's test scene is zara2's and zara3's place; univ's is uni_examples'), so their
occupancy, rasterised on each scene map's grid, is an input that no test track feeds (docs/goal.md).

A window's own track would show its future in that occupancy, so training cross-fits: the tracks are split
in two folds by a hash of (source, pedestrian), and a training window reads the prior built from the other
fold's tracks only. Validation, test and every later use read the prior of all training tracks.
"""

from __future__ import annotations

import zlib
from typing import Final

import numpy as np
import torch
from scipy.ndimage import gaussian_filter

from fftool.artifacts.store import Artifact
from fftool.config import GoalConfig
from fftool.dataset.scenes import scene_of
from fftool.learning.batches import AgentWindows, SceneMaps, load_agent_windows, load_scene_maps

# Scene maps that show one physical place in one world frame (the UCY matrices are equal, docs/data.md), and
# sources of a place without a map of their own (uni_examples films univ's square; fftool gives it no map).
PLACE: Final[dict[str, str]] = {"zara1": "zara", "zara2": "zara"}
SOURCE_PLACE: Final[dict[str, str]] = {"uni_examples": "univ"}
FOLDS: Final = 2
ALL: Final = FOLDS  # the block of the prior built from every training track
BLUR_CELLS: Final = 1.0  # Gaussian blur of the counts, in map cells
SATURATION_QUANTILE: Final = 0.99  # log-counts scaled so that this quantile of the occupied cells is 1


def place_of(scene: str | None) -> str | None:
    return PLACE.get(scene, scene) if scene else None


def source_place(source: str) -> str | None:
    return SOURCE_PLACE.get(source) or place_of(scene_of(source))


def track_folds(windows: AgentWindows) -> np.ndarray:
    """(M,) fold of each window's track: stable across runs and machines (crc32, not Python's hash)."""
    source_hash = {s: zlib.crc32(s.encode()) for s in np.unique(windows.source)}
    keys = np.array([source_hash[s] for s in windows.source], dtype=np.int64) + windows.ped_id.astype(np.int64)
    return (keys % FOLDS).astype(np.int64)


def occupancy(maps: SceneMaps, tracks: AgentWindows, keep: np.ndarray) -> torch.Tensor:
    """(n_scenes + 1, 1, H, W) normalised occupancy of the kept tracks' positions on each scene map's grid;
    a position counts once however many windows hold it, and the 'no map' scene stays zero."""
    n, _, height, width = maps.stack.shape
    steps = tracks.first_step[:, None] + np.arange(tracks.xy.shape[1])
    places = np.array([source_place(s) or "" for s in tracks.source])
    prior = np.zeros((n, 1, height, width), dtype=np.float32)
    for i, name in enumerate(maps.names):
        mine = keep & (places == place_of(name))
        if not mine.any():
            continue
        source_codes = np.unique(tracks.source[mine], return_inverse=True)[1]
        key = np.stack(
            [
                np.repeat(source_codes, steps.shape[1]),
                np.repeat(tracks.ped_id[mine], steps.shape[1]),
                steps[mine].ravel(),
            ]
        )
        _, first = np.unique(key, axis=1, return_index=True)
        xy = tracks.xy[mine].reshape(-1, 2)[first]
        cells = np.floor((xy - maps.origins[i].numpy()) / maps.resolution_m).astype(np.int64)
        inside = (cells[:, 0] >= 0) & (cells[:, 0] < width) & (cells[:, 1] >= 0) & (cells[:, 1] < height)
        counts = np.zeros((height, width), dtype=np.float64)
        np.add.at(counts, (cells[inside, 1], cells[inside, 0]), 1.0)
        density = np.log1p(gaussian_filter(counts, BLUR_CELLS))
        occupied = density[density > 0]
        if occupied.size:
            prior[i, 0] = np.clip(density / np.quantile(occupied, SATURATION_QUANTILE), 0, 1)
    return torch.from_numpy(prior)


def with_prior(maps: SceneMaps, train: AgentWindows) -> SceneMaps:
    """The scene maps with the occupancy channel, in FOLDS + 1 blocks of scenes: block f holds the prior of
    the tracks outside fold f, block ALL that of every training track (index with `scene_index`)."""
    folds = track_folds(train)
    blocks = [occupancy(maps, train, folds != f) for f in range(FOLDS)] + [occupancy(maps, train, folds >= 0)]
    stack = torch.cat([torch.cat([maps.stack, prior.to(maps.stack.dtype)], 1) for prior in blocks])
    return SceneMaps(stack, maps.origins.repeat(len(blocks), 1), maps.resolution_m, maps.names)


def scene_index(maps: SceneMaps, windows: AgentWindows, *, cross_fit: bool) -> torch.Tensor:
    """(M,) index into `with_prior`'s stack: the block of the window's own fold when cross-fitting (training
    windows), else the block of every training track."""
    base = maps.index_of_sources(windows.source)
    block = torch.from_numpy(track_folds(windows)) if cross_fit else torch.full_like(base, ALL)
    return block * (len(maps.names) + 1) + base


def load_goal_scenes(maps: Artifact, windows: Artifact, benchmark: str, cfg: GoalConfig) -> SceneMaps:
    """The scene maps a goal U-Net reads: the maps artifact's, with the benchmark's occupancy prior when
    `goal.scene_prior` asks for it."""
    scene_maps = load_scene_maps(maps)
    if cfg.scene_prior == "none":
        return scene_maps
    return with_prior(scene_maps, load_agent_windows(windows, benchmark, "train"))


def goal_scene_index(maps: SceneMaps, windows: AgentWindows, cfg: GoalConfig, *, cross_fit: bool) -> torch.Tensor:
    """(M,) each window's scene in `load_goal_scenes`'s maps (cross_fit: the window trains the U-Net)."""
    if cfg.scene_prior == "none":
        return maps.index_of_sources(windows.source)
    return scene_index(maps, windows, cross_fit=cross_fit)
