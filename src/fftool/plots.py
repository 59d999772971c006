"""Figures from evaluation artifacts: qualitative panels like the paper's Fig. 3, and metrics versus density.

Every figure reads saved predictions (evaluate/<fp>/predictions.parquet) and the windows artifact; no
model is run. Scene images are drawn under the trajectories through the world-to-pixel homography
when the scene folder has one (axes are then image pixels), else the axes are world metres.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import cv2
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from fftool import __version__
from fftool.batches import AgentWindows
from fftool.errors import UsageError
from fftool.maps import read_homography
from fftool.published import PAPER_NAMES
from fftool.scenes import SOURCE_SCENE

SOFTWARE = f"fftool {__version__}"  # PNG metadata: marks a figure fftool may overwrite
COLOURS = {"cv": "#7f7f7f", "baseline": "#1f77b4", "goal": "#2ca02c", "dr": "#ff7f0e", "re": "#d62728"}


def save_figure(fig: plt.Figure, out: Path, **savefig: object) -> Path:
    """Write `fig` as PNG atomically; never overwrite a file fftool did not write (UsageError, exit 2)."""
    if out.exists() and not _written_by_fftool(out):
        raise UsageError(
            f"{out}: exists and was not written by fftool; refusing to overwrite it (choose another --out)"
        )
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = out.with_name(f".{out.name}.partial-{os.getpid()}")
    try:
        fig.savefig(partial, format="png", metadata={"Software": SOFTWARE}, **savefig)
        os.replace(partial, out)
    finally:
        partial.unlink(missing_ok=True)
        plt.close(fig)
    return out


def _written_by_fftool(path: Path) -> bool:
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as image:
            return str(image.info.get("Software", "")).startswith("fftool ")
    except (OSError, UnidentifiedImageError):
        return False


@dataclass(frozen=True)
class Evaluation:
    """One evaluate artifact's predictions with what is needed to draw them."""

    predictor: str
    k: int
    frame: pd.DataFrame  # predictions.parquet

    @cached_property
    def by_row(self) -> pd.DataFrame:
        """The predictions indexed by agent_windows row (built once, read per drawn window)."""
        return self.frame.set_index("agent_row")

    def futures(self, rows: np.ndarray) -> np.ndarray:
        """(len(rows), K, T, 2) predictions of the given agent_windows rows."""
        chosen = self.by_row.loc[rows, "pred"]
        return np.stack([np.asarray(p, dtype=np.float32) for p in chosen]).reshape(len(rows), self.k, -1, 2)


class SceneImage:
    """A scene's reference image and a world -> pixel projection (identity when the scene has none)."""

    def __init__(self, scenes_dir: Path, source: str) -> None:
        scene = SOURCE_SCENE.get(source)
        folder = scenes_dir / scene if scene else None
        self.image, self.homography = None, None
        if folder and (folder / "reference.png").is_file() and (folder / "world_to_pixel.txt").is_file():
            self.image = cv2.cvtColor(cv2.imread(str(folder / "reference.png")), cv2.COLOR_BGR2RGB)
            self.homography = read_homography(folder / "world_to_pixel.txt")

    def project(self, xy: np.ndarray) -> np.ndarray:
        if self.homography is None:
            return xy
        ones = np.ones((*xy.shape[:-1], 1))
        uvw = np.concatenate([xy, ones], -1) @ self.homography.T
        return uvw[..., :2] / uvw[..., 2:]


def pick_windows(evaluations: Sequence[Evaluation], count: int) -> list[int]:
    """Windows where the variants disagree most: largest spread of mean minADE across predictors."""
    per = pd.concat(
        [e.frame.groupby("window_id")["min_ade"].mean().rename(e.predictor) for e in evaluations], axis=1
    ).dropna()
    busy = per[per.index.isin(evaluations[0].frame.query("n_agents >= 2")["window_id"])]
    pool = busy if len(busy) >= count else per
    ranked = (pool.max(axis=1) - pool.min(axis=1)).sort_values(ascending=False)
    return [int(w) for w in ranked.index[:count]]


def qualitative(
    evaluations: Sequence[Evaluation],
    data: AgentWindows,
    window_ids: Sequence[int],
    scenes_dir: Path,
    obs_len: int,
    best_only: bool,
    out: Path,
) -> Path:
    """A grid: one row per window, one column per predictor; observed, ground truth and predictions."""
    fig, axes = plt.subplots(
        len(window_ids), len(evaluations), figsize=(3.6 * len(evaluations), 3.4 * len(window_ids)), squeeze=False
    )
    for row, window in enumerate(window_ids):
        members = np.flatnonzero(data.window_id == window)
        if len(members) == 0:
            raise ValueError(f"window {window} has no valid agents in this part")
        scene = SceneImage(scenes_dir, str(data.source[members[0]]))
        xy = scene.project(data.xy[members])  # (A, L, 2)
        for col, evaluation in enumerate(evaluations):
            ax = axes[row, col]
            futures = evaluation.futures(data.row[members])  # (A, K, T, 2)
            best = evaluation.by_row.loc[data.row[members], "best_k"].to_numpy()
            if best_only:
                futures = futures[np.arange(len(members)), best][:, None]
            futures = scene.project(futures)
            _draw_window(ax, scene, xy, futures, obs_len, COLOURS.get(evaluation.predictor, "C0"))
            if row == 0:
                ax.set_title(PAPER_NAMES.get(evaluation.predictor, evaluation.predictor))
            if col == 0:
                ax.set_ylabel(f"window {window}")
    handles = [
        plt.Line2D([], [], color="black", lw=2, label="observed"),
        plt.Line2D([], [], color="black", lw=1, ls="--", label="ground truth"),
        plt.Line2D([], [], color="C1", lw=1, label="best prediction" if best_only else "K predictions"),
    ]
    fig.legend(handles=handles, loc="lower center", ncol=3, frameon=False)
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    return save_figure(fig, out, dpi=120)


def _draw_window(ax, scene: SceneImage, xy: np.ndarray, futures: np.ndarray, obs_len: int, colour: str) -> None:
    everything = np.concatenate([xy.reshape(-1, 2), futures.reshape(-1, 2)])
    low, high = everything.min(0), everything.max(0)
    pad = 0.15 * max(high - low) + (20 if scene.image is not None else 0.5)
    if scene.image is not None:
        ax.imshow(scene.image, alpha=0.8)
    for agent in range(len(xy)):
        for sample in futures[agent]:
            path = np.concatenate([xy[agent, obs_len - 1 : obs_len], sample])
            ax.plot(path[:, 0], path[:, 1], color=colour, lw=0.8, alpha=0.5 if len(futures[agent]) > 1 else 1)
        ax.plot(xy[agent, :obs_len, 0], xy[agent, :obs_len, 1], color="black", lw=2)
        ax.plot(xy[agent, obs_len - 1 :, 0], xy[agent, obs_len - 1 :, 1], color="white", lw=1.5, ls="--")
        ax.plot(xy[agent, obs_len - 1 :, 0], xy[agent, obs_len - 1 :, 1], color="black", lw=0.6, ls="--")
    ax.set_xlim(low[0] - pad, high[0] + pad)
    if scene.image is not None:
        ax.set_ylim(high[1] + pad, low[1] - pad)  # image rows grow downward
    else:
        ax.set_ylim(low[1] - pad, high[1] + pad)
        ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])


def density_curves(results: Mapping[str, Mapping[str, pd.DataFrame]], out: Path) -> Path:
    """Per scene: minFDE and collisions per window against the number of agents in the window.

    results[benchmark][predictor] = predictions frame. Agent counts are binned so every bin holds data.
    """
    benchmarks = list(results)
    fig, axes = plt.subplots(2, len(benchmarks), figsize=(4.2 * len(benchmarks), 6.4), squeeze=False)
    for col, benchmark in enumerate(benchmarks):
        for predictor, frame in results[benchmark].items():
            edges = np.unique(np.r_[0, np.quantile(frame["n_agents"], np.linspace(0, 1, 7)).round()])
            agents = frame.groupby(pd.cut(frame["n_agents"], edges), observed=True)
            windows = frame.groupby("window_id").agg(n=("n_agents", "first"), nc=("collisions", "sum"))
            per_window = windows.groupby(pd.cut(windows["n"], edges), observed=True)
            style = {"color": COLOURS.get(predictor), "marker": "o", "label": PAPER_NAMES.get(predictor, predictor)}
            axes[0, col].plot(agents["n_agents"].mean(), agents["min_fde"].mean(), **style)
            axes[1, col].plot(per_window["n"].mean(), per_window["nc"].mean(), **style)
        axes[0, col].set_title(benchmark)
        axes[0, col].set_ylabel("minFDE@K (m)")
        axes[1, col].set_ylabel("collisions per window (ordered pair-steps)")
        axes[1, col].set_xlabel("valid agents in the window")
    axes[0, 0].legend(frameon=False)
    fig.tight_layout()
    return save_figure(fig, out, dpi=120)
