"""The tables as a picture: per benchmark, minFDE and NC of every predictor with their intervals, the
constant-velocity reference drawn as a line to beat, the paper's numbers as open markers."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fftool.paper import TABLE3_FDE, TABLE4_COLLISIONS
from fftool.reporting.plots import COLOURS, plt, save_figure
from fftool.reporting.tables import Grid

# NC runs from a handful (eth, hotel) to thousands (univ): on a linear axis the dense scene hides the others,
# so its panel is symmetric-log (linear below 10 collisions, logarithmic above, 0 still drawn).
PANELS = (
    ("min_fde", "minFDE@K (m)", TABLE3_FDE, "linear"),
    ("nc", "collisions NC (symlog scale)", TABLE4_COLLISIONS, "symlog"),
)


def scores_figure(grid: Grid, out: Path, title: str) -> Path:
    """One panel per metric: benchmarks along x, a bar per CVAE predictor with its interval, constant velocity
    as a dashed line per benchmark, the paper's number as an open circle where it has one."""
    scenes = grid.scenes
    models = [p for p in grid.predictors if p != "cv"]
    fig, axes = plt.subplots(1, len(PANELS), figsize=(3.2 + 1.6 * len(scenes) * len(PANELS), 4.2), squeeze=False)
    width = 0.8 / max(len(models), 1)
    for ax, (metric, label, published, scale) in zip(axes[0], PANELS):
        for index, predictor in enumerate(models):
            x = np.arange(len(scenes)) + (index - (len(models) - 1) / 2) * width
            found = [grid.scores[(s, predictor, metric)] for s in scenes]
            value = np.array([f.estimate for f in found])
            bounds = np.array([f.interval(grid.level) for f in found])  # (S, 2)
            error = np.abs(bounds - value[:, None]).T
            ax.bar(x, value, width, yerr=error, capsize=2, color=COLOURS[predictor], label=grid.method(predictor))
            paper = [published.get(predictor, {}).get(s, np.nan) for s in scenes]
            ax.scatter(x, paper, s=28, facecolors="none", edgecolors="black", zorder=3,
                       label="paper" if index == 0 else None)  # fmt: skip
        if "cv" in grid.predictors:
            for column, scene in enumerate(scenes):
                cv = grid.scores[(scene, "cv", metric)].estimate
                ax.hlines(cv, column - 0.45, column + 0.45, colors=COLOURS["cv"], linestyles="dashed",
                          label=grid.method("cv") if column == 0 else None)  # fmt: skip
        ax.set_xticks(np.arange(len(scenes)), scenes)
        ax.set_ylabel(label)
        ax.set_yscale(scale, **({"linthresh": 10} if scale == "symlog" else {}))
        ax.grid(axis="y", alpha=0.3)
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 4), frameon=False, fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0, 0.12, 1, 0.95))
    return save_figure(fig, out, dpi=110)
