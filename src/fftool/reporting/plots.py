"""Figures from evaluation artifacts: qualitative panels like the paper's Fig. 3, and metrics versus density.

Every figure reads saved predictions (evaluate/<fp>/predictions.parquet) and the windows artifact; no
model is run. Scene images are drawn under the trajectories through the world-to-pixel homography
when the scene folder has one (axes are then image pixels), else the axes are world metres.
"""

from __future__ import annotations

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
from fftool.config import ReportConfig, WindowsConfig
from fftool.dataset.scene_images import SceneImage, project, read_scene
from fftool.dataset.scenes import SOURCE_SCENE
from fftool.errors import FftoolError
from fftool.learning.batches import AgentWindows, load_agent_windows
from fftool.outputs import check_output, marked_file, replacing_file
from fftool.paper import PAPER_NAMES
from fftool.science.bootstrap import Resampling, binned_mean_intervals, window_draws, windows_of

SOFTWARE = f"fftool {__version__}"  # PNG metadata: marks a figure fftool may overwrite
COLOURS = {"cv": "#7f7f7f", "baseline": "#1f77b4", "goal": "#2ca02c", "dr": "#ff7f0e", "re": "#d62728"}


def save_figure(fig: plt.Figure, out: Path, **savefig: object) -> Path:
    """Write `fig` as PNG atomically; never overwrite a file fftool did not write (UsageError, exit 2)."""
    check_output(out, "--out", FIGURE)
    try:
        with replacing_file(out) as partial:
            fig.savefig(partial, format="png", metadata={"Software": SOFTWARE}, **savefig)
    finally:
        plt.close(fig)
    return out


def _written_by_fftool(path: Path) -> bool:
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as image:
            return str(image.info.get("Software", "")).startswith("fftool ")
    except (OSError, UnidentifiedImageError):
        return False


FIGURE = marked_file("a figure", _written_by_fftool)


@dataclass(frozen=True)
class Evaluation:
    """One evaluate artifact's predictions with what is needed to draw and title them."""

    predictor: str
    k: int
    frame: pd.DataFrame  # predictions.parquet
    protocol: str | None = None  # the goal protocol it ran under ("none": the predictor reads no goal)
    benchmark: str | None = None
    part: str | None = None

    @property
    def name(self) -> str:
        """The predictor's name in the paper (AgentFormer, ForceFormer-Dr, ...)."""
        return PAPER_NAMES.get(self.predictor, self.predictor)

    @property
    def colour(self) -> str:
        """The colour its predictions are drawn in, in every figure."""
        return COLOURS.get(self.predictor, "C0")

    @cached_property
    def by_row(self) -> pd.DataFrame:
        """The predictions indexed by agent_windows row (built once, read per drawn window)."""
        return self.frame.set_index("agent_row")

    @classmethod
    def of(cls, evaluate: Artifact) -> Evaluation:
        """The predictions of an evaluate artifact, with its benchmark, part and goal protocol."""
        stats = evaluate.manifest.stats
        return cls(
            stats["variant"],
            int(stats["k"]),
            pd.read_parquet(evaluate.file(PREDICTIONS_FILE)),
            protocol=stats.get("protocol"),
            benchmark=stats.get("benchmark"),
            part=stats.get("part"),
        )

    def futures(self, rows: np.ndarray) -> np.ndarray:
        """(len(rows), K, T, 2) predictions of the given agent_windows rows."""
        chosen = self.by_row.loc[rows, "pred"]
        return np.stack([np.asarray(p, dtype=np.float32) for p in chosen]).reshape(len(rows), self.k, -1, 2)


def setting(evaluations: Sequence[Evaluation]) -> str:
    """What a reader needs to know to read the numbers: K and the goal protocol(s), e.g.
    "K = 20 samples per agent; goal protocol 'paper' (AgentFormer reads no goal)"."""
    ks = {e.k for e in evaluations}
    if len(ks) == 1:
        text = f"K = {ks.pop()} samples per agent"
    else:
        text = "K = " + ", ".join(f"{e.k} ({e.name})" for e in evaluations) + " samples per agent"
    readers: dict[str, list[str]] = {}
    for e in evaluations:
        if e.protocol not in (None, "none"):
            readers.setdefault(str(e.protocol), []).append(e.name)
    blind = [e.name for e in evaluations if e.protocol == "none"]
    if len(readers) == 1:
        text += f"; goal protocol '{next(iter(readers))}'"
    elif readers:
        text += "; goal protocols " + ", ".join(f"'{p}' ({', '.join(names)})" for p, names in readers.items())
    if blind and readers:
        text += f" ({', '.join(blind)} {'reads' if len(blind) == 1 else 'read'} no goal)"
    elif blind:
        text += "; goal protocol 'none' (no predictor here reads a goal)"
    return text


def title_of(evaluations: Sequence[Evaluation], what: str) -> str:
    """`what`, headed by the benchmark and part of the evaluations where they are known."""
    where = [f"{e.benchmark}" + (f" ({e.part} part)" if e.part else "") for e in evaluations[:1] if e.benchmark]
    return f"{where[0]}: {what}" if where else what


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
    resampling: Resampling = Resampling(),
) -> list[Path]:
    """The density curves of every benchmark in one figure, then a qualitative figure per benchmark.

    evaluations[benchmark] are drawn side by side, except the `density_only` predictors; the drawn windows
    are `window_ids`, else `pick_windows`: up to `count` distinct windows where the predictors differ most.
    The windows and every output path are checked before anything is drawn, so a refused figure leaves no
    other behind.
    """
    stats = windows.manifest.stats
    obs_len, window_len = int(stats["obs_len"]), int(stats["window_len"])
    panels = []
    for benchmark, predictors in evaluations.items():
        data = load_agent_windows(windows, benchmark, part)
        unknown = sorted(set(window_ids or ()) - set(data.window_id.tolist()))
        if unknown:
            raise FftoolError(f"--windows: {unknown} are not window ids of {benchmark}/{part}")
        drawn = [e for e in predictors if e.predictor not in density_only]
        if window_ids:
            chosen, how = list(window_ids), "windows: as requested"
        else:
            chosen = pick_windows(drawn, count, data, window_len=window_len)
            how = pick_rule(len(drawn), window_len)
        if not chosen:
            raise FftoolError(f"{benchmark}/{part}: no window with predictions of every drawn predictor")
        panels.append((drawn, data, chosen, how, out_dir / f"qualitative_{benchmark}.png"))
    density = out_dir / density_file
    for out in (density, *(panel[-1] for panel in panels)):
        check_output(out, "--out", FIGURE)
    frames = {benchmark: {e.predictor: e.frame for e in predictors} for benchmark, predictors in evaluations.items()}
    every = [e for predictors in evaluations.values() for e in predictors]
    title = f"{', '.join(evaluations)} ({part} part): {setting(every)}"
    written = [density_curves(frames, density, title=title, resampling=resampling)]
    for drawn, data, chosen, how, out in panels:
        written.append(qualitative(drawn, data, chosen, scenes_dir, obs_len, best_only, out, how=how))
    return written


MIN_AGENTS = 3  # pick_windows prefers windows with at least this many agents: interactions to look at


def pick_windows(
    evaluations: Sequence[Evaluation],
    count: int,
    data: AgentWindows | None = None,
    *,
    window_len: int = 20,
    min_agents: int = MIN_AGENTS,
) -> list[int]:
    """Up to `count` distinct, informative windows, best first.

    Ranked by the spread (max - min) across the predictors of the window's mean minADE (one predictor: its
    mean minADE, the hardest first). Windows with at least `min_agents` agents are taken first, then with 2,
    then any. A window is skipped when one already taken is from the same recording and starts fewer than
    `window_len` (obs_len + pred_len) steps away, so no two drawn windows share a time step. Without `data`
    window ids stand in for time steps (ids are in time order within a recording, so this is stricter).
    Fewer than `count` come back when no more windows are that far apart.
    """
    per = pd.concat(
        [e.frame.groupby("window_id")["min_ade"].mean().rename(str(i)) for i, e in enumerate(evaluations)], axis=1
    ).dropna()
    if per.empty or count < 1:
        return []
    score = per.max(axis=1) - per.min(axis=1) if per.shape[1] > 1 else per.iloc[:, 0]
    ranked = score.sort_values(ascending=False, kind="stable").index.to_numpy()
    agents = evaluations[0].frame.groupby("window_id")["n_agents"].first().reindex(ranked).to_numpy()
    if data is not None:
        when = pd.DataFrame({"source": data.source.astype(str), "step": data.first_step}, index=data.window_id)
        when = when[~when.index.duplicated()].reindex(ranked)
        source, step = when["source"].fillna("").to_numpy(), when["step"].fillna(-np.inf).to_numpy()
    else:
        source, step = np.full(len(ranked), ""), ranked.astype(float)
    picked: list[int] = []
    for least in (min_agents, 2, 0):
        for i in np.flatnonzero(agents >= least):
            if len(picked) == count:
                return [int(ranked[j]) for j in picked]
            clash = [j for j in picked if source[j] == source[i] and abs(step[j] - step[i]) < window_len]
            if i not in picked and not clash:
                picked.append(int(i))
    return [int(ranked[j]) for j in picked]


def pick_rule(n_predictors: int, window_len: int, min_agents: int = MIN_AGENTS) -> str:
    """How pick_windows chose: the caption of a qualitative figure."""
    ranked = (
        "largest spread of mean minADE across the predictors" if n_predictors > 1 else "largest mean minADE (hardest)"
    )
    return (
        f"Windows chosen automatically: {ranked}, windows with ≥ {min_agents} agents first, "
        f"no two from the same recording within {window_len} steps (one window) of each other."
    )


def qualitative(
    evaluations: Sequence[Evaluation],
    data: AgentWindows,
    window_ids: Sequence[int],
    scenes_dir: Path,
    obs_len: int,
    best_only: bool,
    out: Path,
    *,
    how: str | None = None,
) -> Path:
    """A grid: one row per window, one column per predictor; observed, ground truth and predictions.

    `how`: how the windows were chosen, printed under the grid (e.g. `pick_rule`).
    """
    fig = qualitative_figure(evaluations, data, window_ids, scenes_dir, obs_len, best_only, how=how)
    return save_figure(fig, out, dpi=100)


def qualitative_figure(
    evaluations: Sequence[Evaluation],
    data: AgentWindows,
    window_ids: Sequence[int],
    scenes_dir: Path,
    obs_len: int,
    best_only: bool,
    *,
    how: str | None = None,
) -> plt.Figure:
    """The figure `qualitative` saves."""
    width = 3.6 * max(len(evaluations), 2)
    fig, axes = plt.subplots(
        len(window_ids),
        len(evaluations),
        figsize=(width, 2.5 * len(window_ids) + 1.4),
        squeeze=False,
    )
    for row, window in enumerate(window_ids):
        members = np.flatnonzero(data.window_id == window)
        if len(members) == 0:
            raise ValueError(f"window {window} has no valid agents in this part")
        source = str(data.source[members[0]])
        name = SOURCE_SCENE.get(source)
        scene = read_scene(scenes_dir / name) if name else None
        xy = project(scene, data.xy[members])  # (A, L, 2)
        drawn = [project(scene, _drawn_futures(e, data.row[members], best_only)) for e in evaluations]
        extent = extent_of([xy, *drawn], scene is not None)  # one per window: its panels compare at one scale
        for col, (evaluation, futures) in enumerate(zip(evaluations, drawn)):
            ax = axes[row, col]
            draw_window(ax, scene, xy, futures, obs_len, evaluation.colour, extent)
            ade = float(evaluation.by_row.loc[data.row[members], "min_ade"].mean())
            ax.text(
                0.02, 0.98, f"minADE {ade:.2f} m", transform=ax.transAxes, va="top", fontsize=8,
                bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none", "pad": 1.5},
            )  # fmt: skip
            if row == 0:
                ax.set_title(evaluation.name, color=evaluation.colour, fontweight="bold")
            if col == 0:
                first = int(data.first_step[members[0]])
                ax.set_ylabel(f"window {window}\n{source}, step {first}\n{len(members)} agents", fontsize=9)
    handles = legend_handles(evaluations, best_only)
    ncol = max(2, min(len(handles), int(width / 3.3)))
    header_and_key(fig, title_of(evaluations, setting(evaluations)), how, handles, ncol)
    return fig


def header_and_key(fig: plt.Figure, title: str, caption: str | None, handles: list, ncol: int) -> None:
    """Title (and an italic caption under it) on top, the key at the bottom, the axes laid out between."""
    width, height = fig.get_size_inches()
    lines = _wrap(title, 9 * width)
    notes = _wrap(caption, 15 * width) if caption else []
    fig.suptitle("\n".join(lines), fontsize=11, y=1 - 0.08 / height, va="top")
    top = 0.12 + 0.2 * len(lines)
    if notes:
        fig.text(0.5, 1 - top / height, "\n".join(notes), ha="center", va="top", fontsize=8, style="italic")
        top += 0.05 + 0.15 * len(notes)
    rows = -(-len(handles) // ncol)
    fig.legend(handles=handles, loc="lower center", ncol=ncol, frameon=False, fontsize=9)
    fig.tight_layout(rect=(0, (0.1 + 0.22 * rows) / height, 1, 1 - (top + 0.05) / height))


def _wrap(text: str, width: float) -> list[str]:
    import textwrap

    return textwrap.wrap(text, max(int(width), 30))


def legend_handles(evaluations: Sequence[Evaluation], best_only: bool) -> list[plt.Line2D]:
    """The qualitative figure's key: observed and ground truth in black, then each predictor in its colour."""
    handles = [
        plt.Line2D([], [], color="black", lw=2, label="observed (past)"),
        plt.Line2D([], [], color="black", lw=1, ls="--", label="ground truth (future)"),
    ]
    for e in evaluations:
        what = f"best of K = {e.k} samples" if best_only else f"K = {e.k} samples"
        handles.append(plt.Line2D([], [], color=e.colour, lw=1.5, label=f"{e.name}: {what}"))
    return handles


def _drawn_futures(evaluation: Evaluation, rows: np.ndarray, best_only: bool) -> np.ndarray:
    """(A, K, T, 2) futures of the agent-window rows, or (A, 1, T, 2) each agent's best-ADE sample."""
    futures = evaluation.futures(rows)
    if best_only:
        best = evaluation.by_row.loc[rows, "best_k"].to_numpy()
        futures = futures[np.arange(len(rows)), best][:, None]
    return futures


def extent_of(paths: Sequence[np.ndarray], pixels: bool) -> tuple[np.ndarray, np.ndarray]:
    """The (low, high) corners that hold every point of `paths` with a margin (pixels or metres)."""
    everything = np.concatenate([p.reshape(-1, 2) for p in paths])
    low, high = everything.min(0), everything.max(0)
    pad = 0.15 * max(high - low) + (20 if pixels else 0.5)
    return low - pad, high + pad


def draw_window(
    ax,
    scene: SceneImage | None,
    xy: np.ndarray,
    futures: np.ndarray,
    obs_len: int,
    colour: str,
    extent: tuple[np.ndarray, np.ndarray],
) -> None:
    """Observed paths (black), ground truth (dashed) and the futures in `colour`, within `extent`."""
    low, high = extent
    if scene is not None:
        ax.imshow(scene.image, alpha=0.8)
    for agent in range(len(xy)):
        for sample in futures[agent]:
            path = np.concatenate([xy[agent, obs_len - 1 : obs_len], sample])
            ax.plot(path[:, 0], path[:, 1], color=colour, lw=0.8, alpha=0.5 if len(futures[agent]) > 1 else 1)
        ax.plot(xy[agent, :obs_len, 0], xy[agent, :obs_len, 1], color="black", lw=2)
        ax.plot(xy[agent, obs_len - 1 :, 0], xy[agent, obs_len - 1 :, 1], color="white", lw=1.5, ls="--")
        ax.plot(xy[agent, obs_len - 1 :, 0], xy[agent, obs_len - 1 :, 1], color="black", lw=0.6, ls="--")
    ax.set_xlim(low[0], high[0])
    if scene is not None:
        ax.set_ylim(high[1], low[1])  # image rows grow downward
    else:
        ax.set_ylim(low[1], high[1])
        ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])


def density_curves(
    results: Mapping[str, Mapping[str, pd.DataFrame]],
    out: Path,
    *,
    title: str | None = None,
    resampling: Resampling = Resampling(),
) -> Path:
    """Per scene: minFDE and collisions per window against the number of agents in the window.

    results[benchmark][predictor] = predictions frame. Agent counts are binned so every bin holds data;
    grey bars (right axis) give how many agent-windows / windows each bin holds. `title`: the figure's
    title, e.g. the benchmarks, K and the goal protocol (`setting`). Error bars: `density_figure`.
    """
    return save_figure(density_figure(results, title=title, resampling=resampling), out, dpi=100)


def density_figure(
    results: Mapping[str, Mapping[str, pd.DataFrame]],
    *,
    title: str | None = None,
    resampling: Resampling = Resampling(),
) -> plt.Figure:
    """The figure `density_curves` saves: each bin's mean with its percentile interval under `resampling`, the
    moving-block bootstrap over test windows the tables use (a bin holds few windows: the bars say how sure)."""
    benchmarks = list(results)
    fig, axes = plt.subplots(
        2, len(benchmarks), figsize=(4.6 * max(len(benchmarks), 1.5), 7.4), squeeze=False, layout="constrained"
    )
    for col, benchmark in enumerate(benchmarks):
        frames = results[benchmark]
        if not frames:
            continue
        reference = next(iter(frames.values()))  # every predictor of a benchmark has the same windows
        edges = np.unique(np.r_[0, np.quantile(reference["n_agents"], np.linspace(0, 1, 7)).round()])
        ids, _ = windows_of(reference["window_id"].to_numpy())
        draws = window_draws(len(ids), resampling.resamples, [resampling.seed, col], resampling.block)
        for predictor, frame in frames.items():
            own, window = windows_of(frame["window_id"].to_numpy())
            if not np.array_equal(own, ids):
                raise FftoolError(f"{benchmark}: the {predictor} predictions cover other test windows")
            windows = frame.groupby("window_id").agg(n=("n_agents", "first"), nc=("collisions", "sum"))
            bins = pd.cut(windows["n"], edges).cat.codes.to_numpy()  # (W,) each window's bin, ids in sorted order
            style = {"color": COLOURS.get(predictor), "marker": "o", "label": PAPER_NAMES.get(predictor, predictor)}
            style |= {"capsize": 2, "lw": 1.2, "elinewidth": 0.8}
            every_window = np.arange(len(ids))
            for ax, values, of in (
                (axes[0, col], frame["min_fde"], window),
                (axes[1, col], windows["nc"], every_window),
            ):
                values = values.to_numpy(np.float64)
                count = np.bincount(bins[of], minlength=len(edges) - 1)
                mean = np.bincount(bins[of], weights=values, minlength=len(edges) - 1) / np.maximum(count, 1)
                x = np.bincount(bins[of], weights=windows["n"].to_numpy()[of], minlength=len(edges) - 1)
                low, high = binned_mean_intervals(draws, values, of, bins, len(edges) - 1, resampling.level)
                held = count > 0
                error = np.vstack([mean - low, high - mean])[:, held]
                ax.errorbar(x[held] / count[held], mean[held], yerr=np.clip(error, 0, None), **style)
        windows = reference.groupby("window_id")["n_agents"].first()
        _bin_counts(axes[0, col], reference["n_agents"], edges, "agent-windows per bin")
        _bin_counts(axes[1, col], windows, edges, "windows per bin")
        axes[0, col].set_title(benchmark)
        axes[0, col].set_ylabel("minFDE@K (m), mean over agents")
        axes[1, col].set_ylabel("collisions per window\n(ordered pair-steps, mean)")
        axes[1, col].set_xlabel("valid agents in the window (bins)")
    handles = list({h.get_label(): h for ax in axes[0] for h in ax.get_legend_handles_labels()[0]}.values())
    handles.append(
        plt.Rectangle((0, 0), 1, 1, color="0.6", alpha=0.35, label="grey bars: bin span and count (right axis)")
    )
    level, block = f"{resampling.level:.0%}", resampling.block
    handles.append(
        plt.Line2D([], [], color="0.3", marker="|", ls="none", label=f"error bars: {level} interval of the mean\n"
        f"(block bootstrap, {block} windows per block)")
    )  # fmt: skip
    ncol = min(len(handles), max(2, int(fig.get_size_inches()[0] / 3.5)))
    fig.legend(handles=handles, loc="outside lower center", ncol=ncol, frameon=False, fontsize=9)
    heading = "minFDE and collisions against crowd density"
    fig.suptitle(f"{heading}\n" + "\n".join(_wrap(title, 10 * fig.get_size_inches()[0])) if title else heading)
    return fig


def _bin_counts(ax, values: pd.Series, edges: np.ndarray, label: str) -> None:
    """Grey bars on a twin axis: one per bin (a, b], over the integers a+1..b it holds, as high as its count,
    labelled with it."""
    counts = pd.cut(values, edges).value_counts(sort=False).to_numpy()
    twin = ax.twinx()
    bars = twin.bar(edges[:-1] + 0.5, counts, width=np.diff(edges), align="edge", color="0.6", alpha=0.35, lw=0)
    twin.bar_label(bars, labels=[str(c) for c in counts], fontsize=7, color="0.35", padding=1)
    twin.set_ylim(0, counts.max() * 3 if counts.max() else 1)  # the bars keep to the lower third
    twin.set_ylabel(f"{label} (grey bars)", color="0.4")
    twin.tick_params(axis="y", colors="0.4", labelsize=8)
    ax.set_zorder(twin.get_zorder() + 1)  # curves over the bars
    ax.patch.set_visible(False)


def resampling_of(report: ReportConfig, windows: WindowsConfig) -> Resampling:
    """The resampling of a report's tables, for its figures' intervals."""
    return Resampling(
        report.bootstrap_resamples, report.bootstrap_seed, report.block_length(windows), report.confidence
    )
