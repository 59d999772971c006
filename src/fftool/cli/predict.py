"""`fftool predict`: K futures of a trained model for the agents of your own track file."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import typer

from fftool.cli.app import DeviceOption, RootOption, app, boundary


def _times(value: str) -> str | list[float]:
    if value in ("last", "all"):
        return value
    try:
        times = [float(v) for v in value.split(",")]
    except ValueError:
        raise typer.BadParameter(f"{value!r}: expected last, all or comma-separated times in seconds") from None
    if not all(math.isfinite(t) for t in times):
        raise typer.BadParameter(f"{value!r}: expected finite times in seconds (not nan or inf)")
    return times


@app.command(
    epilog="Examples:\n\n"
    "  fftool predict tracks.csv --model cpu/zara1/dr --out futures.parquet   # shipped: fftool models list\n\n"
    "  fftool predict tracks.csv --model cvae/3f9c2a --goals goals.csv --out futures.parquet --plot futures.png\n\n"
    "  fftool predict tracks.csv --model cvae/3f9c2a --goals goals.csv --at all --out all.parquet"
    "   # every time with 8 observed steps\n\n"
    "  fftool predict tracks.csv --model cpu/zara1/dr --at all --animate scene.gif\n\n"
    "  fftool predict tracks.csv --model cpu/zara1/dr --most-likely --out path.parquet   # one future per agent"
)
@boundary
def predict(
    tracks: Annotated[Path, typer.Argument(help="CSV or Parquet: a time (s) or frame column, agent id, x, y.")],
    model: Annotated[
        str,
        typer.Option(
            "--model",
            help="Trained CVAE: artifact id (cvae/3f9c2a), its folder, or a shipped model's name (cpu/zara1/dr: "
            "with its DLow sampler and, for goal variants, its goal U-Net, as its profile evaluates it).",
        ),
    ],
    dlow: Annotated[
        str | None,
        typer.Option(
            "--dlow", help="A DLow sampler trained over that CVAE (dlow/…): its K codes instead of the prior."
        ),
    ] = None,
    out: Annotated[
        Path, typer.Option("--out", dir_okay=False, help="Parquet file of the futures (new, or fftool's own).")
    ] = Path("predictions.parquet"),
    at: Annotated[
        str,
        typer.Option("--at", help="Prediction time(s): last (the file's last time), all, or comma-separated seconds."),
    ] = "last",
    k: Annotated[int, typer.Option("--k", min=1, help="Samples per agent.")] = 20,
    most_likely: Annotated[
        bool,
        typer.Option(
            "--most-likely",
            help="Write one future per agent instead of K: the model's path from the centre of its prior (the mean "
            "code), toward goal 1 (the goal map's mode, or the goal given) for goal variants.",
        ),
    ] = False,
    seed: Annotated[
        int, typer.Option("--seed", min=0, max=2**63 - 1, help="Seed of the draws (evaluate's default is 0).")
    ] = 0,
    goal_model: Annotated[
        str | None, typer.Option("--goal-model", help="Goal variants: a goal U-Net artifact (K goals, no map).")
    ] = None,
    goals: Annotated[
        Path | None,
        typer.Option("--goals", help="Goal variants: CSV/Parquet of one goal per agent (agent id, x, y)."),
    ] = None,
    time_col: Annotated[
        str | None, typer.Option("--time-col", help="Time column. Default: time, t, timestamp, frame or frame_id.")
    ] = None,
    agent_col: Annotated[
        str | None, typer.Option("--agent-col", help="Agent column. Default: agent_id, agent, ped_id, track_id or id.")
    ] = None,
    x_col: Annotated[str, typer.Option("--x-col", help="x column.")] = "x",
    y_col: Annotated[str, typer.Option("--y-col", help="y column.")] = "y",
    units: Annotated[str, typer.Option("--units", help="Unit of x and y: m, cm or mm.")] = "m",
    time_step: Annotated[
        float | None,
        typer.Option(
            "--time-step",
            help="Seconds per unit of the time column. Default: 1 for a time column; for a frame column, "
            "consecutive frame numbers are one model step apart.",
            show_default=False,
        ),
    ] = None,
    max_gap: Annotated[
        float, typer.Option("--max-gap", min=0, help="Longest gap (s) in a track that may be interpolated over.")
    ] = 1.0,
    plot: Annotated[Path | None, typer.Option("--plot", help="Also draw past and predicted paths to this PNG.")] = None,
    animate: Annotated[
        Path | None,
        typer.Option(
            "--animate",
            dir_okay=False,
            help="Also animate the prediction times (with --at all: one frame each) to this .gif, or .mp4 where "
            "imageio-ffmpeg is installed.",
        ),
    ] = None,
    fps: Annotated[float, typer.Option("--fps", min=0.5, max=60, help="With --animate: frames per second.")] = 5.0,
    scene_image: Annotated[
        Path | None, typer.Option("--scene-image", help="With --plot: the image to draw on.")
    ] = None,
    homography: Annotated[
        Path | None, typer.Option("--homography", help="With --scene-image: its 3×3 world->pixel matrix (text).")
    ] = None,
    device: DeviceOption = "cpu",
    root: RootOption = None,
) -> None:
    """Predict K futures for every agent with 8 observed steps at the prediction time(s) of a track file."""
    from fftool.api import load, load_goal_sampler, predict_tracks
    from fftool.dataset.trackfiles import Columns, read_goals, read_tracks
    from fftool.errors import UsageError
    from fftool.outputs import check_output
    from fftool.reporting.predictions import PREDICTIONS, prediction_figure, write_predictions
    from fftool.ui import log, warn
    from fftool.variants import reads_goal
    from fftool.zoo import is_name

    when = _times(at)
    if time_step is not None and not time_step > 0:
        raise UsageError(f"--time-step {time_step}: expected seconds per unit of the time column, above 0")
    if (scene_image is None) != (homography is None):
        raise UsageError("--scene-image and --homography go together: the image and its world->pixel matrix")
    check_output(out, "--out", PREDICTIONS)
    if plot is not None:
        from fftool.reporting.plots import FIGURE

        check_output(plot, "--plot", FIGURE)
    if animate is not None:
        from fftool.reporting.animation import check_out as check_animation

        check_animation(animate)
        if when == "last":
            raise UsageError("--animate draws one frame per prediction time: give --at all or several times")
    chosen = load(model, root=root, device="cpu" if device == "auto" else device, dlow=dlow)
    columns = Columns(time_col, agent_col, x_col, y_col)
    observed = read_tracks(tracks, columns, units, time_step, frame_step_s=chosen.step_s)
    per_agent = None
    if goals is not None:
        goal_rows = read_goals(goals, columns, units)
        per_agent = dict(zip(goal_rows["agent"], zip(goal_rows["x"], goal_rows["y"])))
    if goal_model is None and is_name(model) and reads_goal(chosen.variant):
        goal_model = model  # a shipped goal variant brings its benchmark's goal U-Net
    sampler = load_goal_sampler(goal_model, root=root, device=chosen.device) if goal_model else None
    table, warnings = predict_tracks(
        chosen, observed, source=tracks, at=when, k=k, seed=seed, goals=per_agent, goal_sampler=sampler,
        max_gap_s=max_gap, most_likely=most_likely,
    )  # fmt: skip
    for message in warnings:
        warn(message)
    about = {
        "model": model,
        "dlow": dlow,
        "k": k,
        "most_likely": most_likely,
        "seed": seed,
        "at": at,
        "tracks": str(tracks),
        "variant": chosen.variant,
    }
    write_predictions(table, out, about)
    agents = table.groupby("time_s")["agent"].nunique()
    log(f"wrote {out}: {k} samples for {int(agents.sum())} agent(s) at {len(agents)} time(s)")
    if plot is not None or animate is not None:
        from fftool.dataset.scene_images import SceneImage, read_homography, read_image

        scene = None
        if scene_image is not None and homography is not None:
            import cv2

            image = cv2.cvtColor(read_image(scene_image, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
            scene = SceneImage(image, read_homography(homography))
        if plot is not None:
            log(f"wrote {prediction_figure(observed, table, scene, plot)}")
        if animate is not None:
            from fftool.config import EvaluateConfig
            from fftool.paper import PAPER_NAMES
            from fftool.reporting.animation import prediction_movie, render, write

            name = f"{PAPER_NAMES.get(chosen.variant, chosen.variant)} ({model})"
            gamma = EvaluateConfig().collision_threshold_m
            movie = prediction_movie(observed, table, scene, name, chosen.obs_len, chosen.step_s, gamma)
            log(f"wrote {write(render(movie), animate, fps)}")
