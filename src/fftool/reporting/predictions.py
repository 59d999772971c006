"""`fftool predict`'s outputs: the Parquet file of K futures (written atomically, marked as fftool's) and
its figure of past and predicted paths, over a scene image when one is given.

An existing --out file is replaced only when it carries fftool's mark (a Parquet metadata key), as
figures carry theirs (plots.save_figure): a user's own file is never overwritten.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from fftool import __version__
from fftool.dataset.scene_images import SceneImage, project
from fftool.outputs import check_output, marked_file, replacing_file

MARK = b"fftool.predictions"  # Parquet metadata key: the file is a prediction fftool wrote and may replace


def _written_by_fftool(path: Path) -> bool:
    try:
        return MARK in (pq.read_schema(path).metadata or {})
    except (OSError, pa.ArrowInvalid):
        return False


PREDICTIONS = marked_file("a prediction file", _written_by_fftool)


def write_predictions(table: pd.DataFrame, out: Path, about: Mapping[str, object]) -> Path:
    """Write the predictions as Parquet atomically, with `about` (model, k, seed, ...) in the metadata."""
    check_output(out, "--out", PREDICTIONS)
    arrow = pa.Table.from_pandas(table, preserve_index=False)
    meta = dict(arrow.schema.metadata or {}) | {MARK: json.dumps({"fftool": __version__, **about}).encode()}
    with replacing_file(out) as partial:
        pq.write_table(arrow.replace_schema_metadata(meta), partial)
    return out


def prediction_figure(observed: pd.DataFrame, table: pd.DataFrame, scene: SceneImage | None, out: Path) -> Path:
    """Past paths (the observed rows up to the first prediction time) and every sampled future, per agent."""
    import matplotlib.pyplot as plt

    from fftool.reporting.plots import save_figure  # sets the Agg backend

    t0 = table["time_s"].min()
    first = table[table["time_s"] == t0]
    past = observed[observed["time_s"] <= t0 + 1e-9]
    fig, ax = plt.subplots(figsize=(7, 6))
    if scene is not None:
        ax.imshow(scene.image)
    agents = first["agent"].unique()
    colours = plt.get_cmap("tab10")(np.arange(len(agents)) % 10)
    for colour, agent in zip(colours, agents):
        world = past.loc[past["agent"] == agent, ["x", "y"]].to_numpy()
        path = project(scene, world)
        ax.plot(path[:, 0], path[:, 1], "-", color=colour, lw=2)
        futures = first[first["agent"] == agent]
        for _, sample in futures.groupby("sample"):  # drawing, not sampling: K lines per agent
            xy = project(scene, np.vstack([world[-1:], sample[["x", "y"]].to_numpy()]))
            ax.plot(xy[:, 0], xy[:, 1], "-", color=colour, lw=0.6, alpha=0.5)
    ax.set_title(f"{len(agents)} agents at t = {t0:.6g} s: observed (thick) and {first['sample'].nunique()} samples")
    if scene is None:
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    else:
        ax.set_axis_off()
    return save_figure(fig, out, bbox_inches="tight")
