"""Figures from evaluation artifacts: qualitative panels like the paper's Fig. 3, and metrics versus density.

Every figure reads saved predictions (evaluate/<fp>/predictions.parquet) and the windows artifact; no
model is run. Scene images are drawn under the trajectories through the world-to-pixel homography
when the scene folder has one (axes are then image pixels), else the axes are world metres.
"""

from __future__ import annotations

import os
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from fftool import __version__
from fftool.artifacts.schema import PREDICTIONS_FILE
from fftool.artifacts.store import Artifact
from fftool.dataset.scene_images import SceneImage, project, read_scene
from fftool.dataset.scenes import SOURCE_SCENE
from fftool.errors import FftoolError, UsageError
from fftool.learning.batches import AgentWindows, load_agent_windows
from fftool.paper import PAPER_NAMES

SOFTWARE = f"fftool {__version__}"  # PNG metadata: marks a figure fftool may overwrite
COLOURS = {"cv": "#7f7f7f", "baseline": "#1f77b4", "goal": "#2ca02c", "dr": "#ff7f0e", "re": "#d62728"}


def save_figure(fig: plt.Figure, out: Path, **savefig: object) -> Path:
    """Write `fig` as PNG atomically; never overwrite a file fftool did not write (UsageError, exit 2)."""
    _check_replaceable(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = out.with_name(f".{out.name}.partial-{os.getpid()}")
    try:
        fig.savefig(partial, format="png", metadata={"Software": SOFTWARE}, **savefig)
        os.replace(partial, out)
    finally:
        partial.unlink(missing_ok=True)
        plt.close(fig)
    return out


def _check_replaceable(out: Path) -> None:
    if out.exists() and not _written_by_fftool(out):
        raise UsageError(
            f"{out}: exists and was not written by fftool; refusing to overwrite it (choose another --out)"
        )


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

    @classmethod
    def of(cls, evaluate: Artifact) -> Evaluation:
        """The predictions of an evaluate artifact."""
        stats = evaluate.manifest.stats
        return cls(stats["variant"], int(stats["k"]), pd.read_parquet(evaluate.file(PREDICTIONS_FILE)))

    def futures(self, rows: np.ndarray) -> np.ndarray:
        """(len(rows), K, T, 2) predictions of the given agent_windows rows."""
        chosen = self.by_row.loc[rows, "pred"]
        return np.stack([np.asarray(p, dtype=np.float32) for p in chosen]).reshape(len(rows), self.k, -1, 2)


def figures(
    evaluations: Mapping[str, Sequence[Evaluation]],
    windows: Artifact,
    part: str,
    scenes_dir: Path,
    out_dir: Path,
    *,
    density_file: str = "density.png",
    density_only: Collection[str] = (),
    window_ids: Sequence[int] | None = None,
    count: int = 3,
    best_only: bool = False,
) -> list[Path]:
    """The density curves of every benchmark in one figure, then a qualitative figure per benchmark.

    evaluations[benchmark] are drawn side by side, except the `density_only` predictors; the drawn windows
    are `window_ids`, else the `count` where the predictors differ most. The windows and every output path
    are checked before anything is drawn, so a refused figure leaves no other behind.
    """
    obs_len = int(windows.manifest.stats["obs_len"])
    panels = []
    for benchmark, predictors in evaluations.items():
        data = load_agent_windows(windows, benchmark, part)
        unknown = sorted(set(window_ids or ()) - set(data.window_id.tolist()))
        if unknown:
            raise FftoolError(f"--windows: {unknown} are not window ids of {benchmark}/{part}")
        drawn = [e for e in predictors if e.predictor not in density_only]
        chosen = list(window_ids) if window_ids else pick_windows(drawn, count)
        panels.append((drawn, data, chosen, out_dir / f"qualitative_{benchmark}.png"))
    density = out_dir / density_file
    for out in (density, *(panel[-1] for panel in panels)):
        _check_replaceable(out)
    frames = {benchmark: {e.predictor: e.frame for e in predictors} for benchmark, predictors in evaluations.items()}
    written = [density_curves(frames, density)]
    for drawn, data, chosen, out in panels:
        written.append(qualitative(drawn, data, chosen, scenes_dir, obs_len, best_only, out))
    return written


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
        name = SOURCE_SCENE.get(str(data.source[members[0]]))
        scene = read_scene(scenes_dir / name) if name else None
        xy = project(scene, data.xy[members])  # (A, L, 2)
        for col, evaluation in enumerate(evaluations):
            ax = axes[row, col]
            futures = evaluation.futures(data.row[members])  # (A, K, T, 2)
            best = evaluation.by_row.loc[data.row[members], "best_k"].to_numpy()
            if best_only:
                futures = futures[np.arange(len(members)), best][:, None]
            futures = project(scene, futures)
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


def _draw_window(ax, scene: SceneImage | None, xy: np.ndarray, futures: np.ndarray, obs_len: int, colour: str) -> None:
    everything = np.concatenate([xy.reshape(-1, 2), futures.reshape(-1, 2)])
    low, high = everything.min(0), everything.max(0)
    pad = 0.15 * max(high - low) + (20 if scene is not None else 0.5)
    if scene is not None:
        ax.imshow(scene.image, alpha=0.8)
    for agent in range(len(xy)):
        for sample in futures[agent]:
            path = np.concatenate([xy[agent, obs_len - 1 : obs_len], sample])
            ax.plot(path[:, 0], path[:, 1], color=colour, lw=0.8, alpha=0.5 if len(futures[agent]) > 1 else 1)
        ax.plot(xy[agent, :obs_len, 0], xy[agent, :obs_len, 1], color="black", lw=2)
        ax.plot(xy[agent, obs_len - 1 :, 0], xy[agent, obs_len - 1 :, 1], color="white", lw=1.5, ls="--")
        ax.plot(xy[agent, obs_len - 1 :, 0], xy[agent, obs_len - 1 :, 1], color="black", lw=0.6, ls="--")
    ax.set_xlim(low[0] - pad, high[0] + pad)
    if scene is not None:
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
