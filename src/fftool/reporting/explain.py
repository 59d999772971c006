"""Draw one window's pedestrians with their driving and repulsive forces over the scene image.

Run: `fftool forces --explain zara1 3900` (scene = a benchmark's test recording, frame = the raw
frame id of the last observed step). People understand forces by looking at them.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from fftool.artifacts.schema import AGENT_WINDOWS_FILE, FORCES_ARRAYS, TRACKS_FILE, WINDOWS_FILE
from fftool.artifacts.store import Artifact
from fftool.dataset.scene_images import project, read_scene
from fftool.dataset.scenes import BENCHMARK_TEST_SOURCES
from fftool.errors import FftoolError


def _find_window(windows: Artifact, scene: str, frame_id: int, source: str | None) -> tuple[int, str, int]:
    if scene not in BENCHMARK_TEST_SOURCES:
        raise FftoolError(f"unknown scene {scene!r}; scenes: {', '.join(BENCHMARK_TEST_SOURCES)}")
    table = pq.read_table(
        windows.file(WINDOWS_FILE), filters=[("benchmark", "=", scene), ("part", "=", "test")]
    ).to_pandas()
    hits = table[(table["t0_frame_id"] == frame_id) & ((table["source"] == source) if source else True)]
    if hits.empty:
        near = table["t0_frame_id"].to_numpy()
        closest = near[np.argsort(np.abs(near - frame_id))[:5]]
        raise FftoolError(
            f"no {scene} test window whose last observed frame is {frame_id}"
            + (f" in {source}" if source else "")
            + f"; nearest frames with valid pedestrians: {', '.join(map(str, sorted(set(closest.tolist()))))}"
        )
    if len(hits) > 1:
        raise FftoolError(
            f"frame {frame_id} exists in several {scene} recordings ({', '.join(hits['source'].astype(str))}); "
            "choose one with --source"
        )
    row = hits.iloc[0]
    return int(row["window_id"]), str(row["source"]), int(row["t0_step"])


@dataclass(frozen=True)
class _Window:
    """One test window's observed paths (A, T, 2), forces and groups at the last observed step, and the
    other pedestrians present then (not valid agent-windows themselves)."""

    source: str
    obs_len: int
    xy: np.ndarray
    f_dr: np.ndarray
    f_re: np.ndarray
    group: np.ndarray
    bystanders: np.ndarray


def _read_window(
    scene: str, frame_id: int, windows: Artifact, forces: Artifact, tracks: Artifact, source: str | None
) -> _Window:
    window_id, source, t0_step = _find_window(windows, scene, frame_id, source)
    obs_len = int(windows.manifest.stats["obs_len"])
    agents = pq.read_table(windows.file(AGENT_WINDOWS_FILE), columns=["benchmark", "part", "window_id", "ped_id", "xy"])
    keys = agents.select(["benchmark", "part", "window_id"]).to_pandas()
    rows = np.flatnonzero(
        (keys["benchmark"] == scene).to_numpy()
        & (keys["part"] == "test").to_numpy()
        & (keys["window_id"] == window_id).to_numpy()
    )
    xy = np.stack(agents.column("xy").take(rows).to_numpy(zero_copy_only=False)).reshape(len(rows), -1, 2)
    ped_ids = agents.column("ped_id").take(rows).to_numpy()
    arrays = {name: np.load(forces.file(file), mmap_mode="r") for name, file in FORCES_ARRAYS.items()}
    f_dr, f_re = arrays["f_dr"][rows, obs_len - 1], arrays["f_re"][rows, obs_len - 1]
    group = arrays["group_id"][rows]
    bystanders = pq.read_table(
        tracks.file(TRACKS_FILE), filters=[("source", "=", source), ("split", "=", "all"), ("step", "=", t0_step)]
    ).to_pandas()
    bystanders = bystanders[~bystanders["ped_id"].isin(ped_ids)][["x", "y"]].to_numpy()
    return _Window(source, obs_len, xy, f_dr, f_re, group, bystanders)


def explain_window(
    *,
    scene: str,
    frame_id: int,
    out: Path,
    windows: Artifact,
    forces: Artifact,
    tracks: Artifact,
    scenes_dir: Path,
    source: str | None = None,
    dr_scale_s2: float = 2.0,
    re_scale_s2: float = 10.0,
) -> Path:
    """Render the window ending at `frame_id` of `scene`'s test recording to a PNG; return its path."""
    import matplotlib.pyplot as plt

    from fftool.reporting.plots import save_figure  # sets the Agg backend

    window = _read_window(scene, frame_id, windows, forces, tracks, source)
    xy, f_dr, f_re, group, bystanders = window.xy, window.f_dr, window.f_re, window.group, window.bystanders
    obs_len, source = window.obs_len, window.source
    now = xy[:, obs_len - 1]
    background = read_scene(scenes_dir / scene)  # None: draw in metres
    pixels = partial(project, background)
    fig, ax = plt.subplots(figsize=(10, 8), dpi=110)
    if background:
        ax.imshow(background.image)
    for path in xy[:, :obs_len]:
        ax.plot(*pixels(path).T, color="white" if background else "grey", lw=1.2, alpha=0.9)
    if len(bystanders):
        ax.scatter(*pixels(bystanders).T, s=18, c="lightgrey", edgecolors="black", lw=0.5, label="others present")
    ax.scatter(*pixels(now).T, s=36, c="yellow", edgecolors="black", lw=0.7, zorder=3, label="valid pedestrians")
    for a, b in itertools.combinations(range(len(xy)), 2):
        if group[a] >= 0 and group[a] == group[b]:
            ax.plot(*pixels(now[[a, b]]).T, ls="--", color="cyan", lw=1.5, zorder=2)
    for force, scale, color, name in ((f_dr, dr_scale_s2, "lime", "F_dr"), (f_re, re_scale_s2, "red", "F_re")):
        start, end = pixels(now), pixels(now + scale * force)
        for (x0, y0), (x1, y1) in zip(start, end):
            ax.annotate("", xy=(x1, y1), xytext=(x0, y0), arrowprops={"arrowstyle": "->", "color": color, "lw": 2})
        ax.plot([], [], color=color, lw=2, label=f"{name} × {scale:g} s² (m)")
    ax.plot([], [], ls="--", color="cyan", label="group (no mutual repulsion)")
    ax.set_title(
        f"{scene} ({source}), frame {frame_id}: forces at the last observed step"
        + ("\n(background: the scene's reference image, not this frame)" if background else ""),
        fontsize=10,
    )
    ax.legend(loc="upper right", fontsize=8, framealpha=0.8)
    if background:
        ax.set_axis_off()
    else:
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    return save_figure(fig, out, bbox_inches="tight")
