"""Scenes you can watch move: consecutive prediction times drawn frame by frame, written as GIF or MP4.

A frame is one prediction time. Per panel (one predictor) it shows every agent's trail so far (grey), its
observed steps (black), the ground truth ahead where known (dashed) and the futures in the predictor's colour,
with red rings where two agents' futures come closer than γ: the frames are drawn by `plots.draw_window`, the
qualitative figure's code, at one extent for the whole stretch so the view stays put. GIF goes through Pillow
(always installed); MP4 through the ffmpeg binary of the imageio-ffmpeg wheel where it is installed
(`pip install "fftool[video]"`). Files are written atomically, and an existing file fftool did not write is
never replaced.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from PIL import Image

from fftool.artifacts.store import Artifact
from fftool.dataset.scene_images import SceneImage, project, read_scene
from fftool.dataset.scenes import SOURCE_SCENE
from fftool.errors import FftoolError, UsageError
from fftool.learning.batches import AgentWindows, load_agent_windows
from fftool.outputs import check_output, marked_file, replacing_file
from fftool.reporting import plots

FORMATS = ("gif", "mp4")
COLLISION_COLOUR = "#e00000"


@dataclass(frozen=True)
class Frame:
    """One prediction time, in drawing coordinates (image pixels, or metres without a scene image)."""

    time_s: float
    xy: np.ndarray  # (A, L, 2) observed steps, then the true future where known (L = obs_len without it)
    trails: list[np.ndarray]  # per agent, (n, 2) its positions before the observed steps
    futures: list[np.ndarray]  # per panel, (A, S, T, 2) the drawn samples
    contacts: list[np.ndarray]  # per panel, (n, 2) where two agents' futures come closer than γ


@dataclass(frozen=True)
class Movie:
    """What every frame shares: the panels' names and colours, the scene and the header."""

    title: str
    names: list[str]
    colours: list[str]
    scene: SceneImage | None
    obs_len: int
    frames: list[Frame]
    key: list[plt.Line2D]


def contacts(paths: np.ndarray, threshold_m: float) -> np.ndarray:
    """(n, 2) midpoints where two different agents' paths (A, S, T, 2, metres) with the same sample index come
    closer than `threshold_m` at the same step: S = 1 for each agent's chosen sample, S = K for joint samples."""
    gaps = np.linalg.norm(paths[:, None] - paths[None], axis=-1)  # (A, A, S, T)
    a, b, s, t = np.nonzero(np.triu(np.ones(gaps.shape[:2], bool), 1)[:, :, None, None] & (gaps < threshold_m))
    return (paths[a, s, t] + paths[b, s, t]) / 2


def stretch(data: AgentWindows, start: int, frames: int) -> list[int]:
    """`frames` consecutive window ids of `start`'s recording around it (a quarter of them before)."""
    source = data.source[np.flatnonzero(data.window_id == start)[0]]
    ids = np.unique(data.window_id[data.source == source])
    at = int(np.searchsorted(ids, start))
    first = max(0, min(at - frames // 4, len(ids) - frames))
    return [int(w) for w in ids[first : first + frames]]


def recording_movie(
    evaluations: Sequence[plots.Evaluation],
    data: AgentWindows,
    window_ids: Sequence[int],
    scene: SceneImage | None,
    obs_len: int,
    dt_s: float,
    best_only: bool,
    threshold_m: float,
) -> Movie:
    """A stretch of a test recording: one frame per window, every evaluation a panel; collisions are the
    paper's NC pairs (each agent's best-ADE sample)."""
    rows = np.flatnonzero(np.isin(data.window_id, window_ids))
    steps = data.first_step[rows, None] + np.arange(data.xy.shape[1])  # (n, L) absolute steps
    known = pd.DataFrame(
        {"ped": np.repeat(data.ped_id[rows], steps.shape[1]), "step": steps.ravel()}
        | dict(zip("xy", project(scene, data.xy[rows]).reshape(-1, 2).T))
    ).drop_duplicates(["ped", "step"])
    frames = []
    for window in window_ids:
        members = np.flatnonzero(data.window_id == window)
        first = int(data.first_step[members[0]])
        earlier = known[known["step"] < first]
        trails = [earlier.loc[earlier["ped"] == ped, ["x", "y"]].to_numpy() for ped in data.ped_id[members]]
        futures, rings = [], []
        for e in evaluations:
            world = e.futures(data.row[members])  # (A, K, T, 2)
            best = world[np.arange(len(members)), e.by_row.loc[data.row[members], "best_k"].to_numpy()][:, None]
            futures.append(project(scene, best if best_only else world))
            rings.append(project(scene, contacts(best, threshold_m)))
        xy = project(scene, data.xy[members])
        frames.append(Frame(first * dt_s, xy, trails, futures, rings))
    names, colours = [e.name for e in evaluations], [e.colour for e in evaluations]
    title = f"{plots.title_of(evaluations, plots.setting(evaluations))}; {data.source[rows[0]]}"
    return Movie(title, names, colours, scene, obs_len, frames, plots.legend_handles(evaluations, best_only))


def prediction_movie(
    observed: pd.DataFrame,
    table: pd.DataFrame,
    scene: SceneImage | None,
    name: str,
    obs_len: int,
    step_s: float,
    threshold_m: float,
) -> Movie:
    """`fftool predict --animate`: one frame per prediction time of `table` (the futures `predict_tracks` wrote),
    observed = each agent's track at the model's last obs_len grid times; collisions among joint samples (sample
    j of every agent), as no future is known to pick a best one."""
    times = np.sort(table["time_s"].unique())
    if len(times) < 2:
        raise UsageError("--animate draws one frame per prediction time and there is one: add --at all")
    k, pred_len = int(table["sample"].max()) + 1, int(table["step"].max())
    frames = []
    for t in times:
        now = table[table["time_s"] == t].sort_values(["agent", "sample", "step"], kind="stable")
        agents = now["agent"].unique()
        world = now[["x", "y"]].to_numpy().reshape(len(agents), k, pred_len, 2)
        grid = t - step_s * np.arange(obs_len - 1, -1, -1)
        xy, trails = [], []
        for agent in agents:
            track = observed[observed["agent"] == agent]
            when = track["time_s"].to_numpy()
            xy.append(np.column_stack([np.interp(grid, when, track[c].to_numpy()) for c in ("x", "y")]))
            trails.append(project(scene, track.loc[when < grid[0], ["x", "y"]].to_numpy()))
        frames.append(
            Frame(float(t), project(scene, np.array(xy)), trails, [project(scene, world)],
                  [project(scene, contacts(world, threshold_m))])
        )  # fmt: skip
    key = [
        plt.Line2D([], [], color="black", lw=2, label="observed (past)"),
        plt.Line2D([], [], color=plots.COLOURS.get("dr"), lw=1.5, label=f"{name}: K = {k} samples"),
    ]
    title = f"{name}: K = {k} futures per agent at each prediction time"
    return Movie(title, [name], [plots.COLOURS.get("dr", "C1")], scene, obs_len, frames, key)


def render(movie: Movie, dpi: int = 72) -> list[np.ndarray]:
    """Every frame as an (H, W, 3) uint8 image: one figure, redrawn per frame."""
    panels = len(movie.names)
    size = (3.6 * panels, 4.4) if panels > 1 else (6.0, 5.6)
    fig, axes = plt.subplots(1, panels, figsize=size, dpi=dpi, squeeze=False)
    # The view holds every observed, true and trailed position of the stretch; futures may leave it (one wild
    # sample would otherwise shrink the scene for every frame).
    everything = [f.xy for f in movie.frames] + [trail for f in movie.frames for trail in f.trails if len(trail)]
    extent = plots.extent_of(everything, movie.scene is not None)
    trail_colour = "white" if movie.scene is not None else "0.55"  # seen on a photograph and on white alike
    trail = plt.Line2D([], [], color="0.55", lw=1.5, label="trail (earlier steps)")
    ring = plt.Line2D([], [], color=COLLISION_COLOUR, marker="o", mfc="none", ls="none", label="collision (< γ)")
    key = [*movie.key, trail, ring]
    clock = fig.text(0.01, 0.99, "", fontsize=10, family="monospace", va="top")
    images = []
    for frame in movie.frames:
        for ax, name, colour, futures, rings in zip(axes[0], movie.names, movie.colours, frame.futures, frame.contacts):
            ax.clear()
            plots.draw_window(ax, movie.scene, frame.xy, futures, movie.obs_len, colour, extent)
            for trail in frame.trails:
                ax.plot(trail[:, 0], trail[:, 1], color=trail_colour, lw=1.5, alpha=0.8)
            ax.plot(rings[:, 0], rings[:, 1], "o", mfc="none", mec=COLLISION_COLOUR, ms=9, mew=1.5)
            ax.set_title(name, color=colour, fontweight="bold", fontsize=10)
        if not images:
            plots.header_and_key(fig, movie.title, None, key, max(2, min(len(key), panels + 1)))
        clock.set_text(f"t = {frame.time_s:.1f} s")
        fig.canvas.draw()
        images.append(np.asarray(fig.canvas.buffer_rgba())[..., :3].copy())
    plt.close(fig)
    return images


def write(images: Sequence[np.ndarray], out: Path, fps: float) -> Path:
    """Frames as a GIF or MP4 (by out's suffix), atomically; an existing file fftool did not write is refused."""
    kind = check_out(out)
    with replacing_file(out) as partial:
        (_write_gif if kind == "gif" else _write_mp4)(images, partial, fps)
    return out


def check_out(out: Path) -> str:
    """The format (gif, mp4) of an animation path that may be written, before any work; else a UsageError."""
    kind = out.suffix.lower().lstrip(".")
    if kind not in FORMATS:
        raise UsageError(f"--animate {out}: expected a file ending in .gif or .mp4")
    if kind == "mp4" and ffmpeg() is None:
        raise UsageError(f"--animate {out}: MP4 needs ffmpeg: pip install 'fftool[video]' (imageio-ffmpeg), or a .gif")
    check_output(out, "--animate", ANIMATION)
    return kind


def _palette(first: np.ndarray) -> Image.Image:
    """One palette for every frame: the first frame's 236 main colours and the drawn colours exactly (a
    palette of the photograph alone turns a thin blue line green), so colours neither drift nor flicker."""
    drawn = ["#000000", "#ffffff", "#8c8c8c", COLLISION_COLOUR, *plots.COLOURS.values()]
    exact = [int(h[i : i + 2], 16) for h in (c.lstrip("#") for c in drawn) for i in (0, 2, 4)]
    scene = Image.fromarray(first).quantize(colors=256 - len(drawn), method=Image.Quantize.MEDIANCUT)
    palette = Image.new("P", (1, 1))
    palette.putpalette(scene.getpalette()[: 3 * (256 - len(drawn))] + exact)
    return palette


def _write_gif(images: Sequence[np.ndarray], out: Path, fps: float) -> None:
    palette = _palette(images[0])
    frames = [Image.fromarray(image).quantize(palette=palette, dither=Image.Dither.NONE) for image in images]
    frames[0].save(
        out, format="GIF", save_all=True, append_images=frames[1:], duration=round(1000 / fps), loop=0,
        comment=plots.SOFTWARE.encode(),
    )  # fmt: skip


def ffmpeg() -> str | None:
    """The ffmpeg binary of the imageio-ffmpeg wheel, or None where it is not installed."""
    try:
        import imageio_ffmpeg
    except ImportError:
        return None
    return imageio_ffmpeg.get_ffmpeg_exe()


def _write_mp4(images: Sequence[np.ndarray], out: Path, fps: float) -> None:
    import imageio_ffmpeg

    height, width = (d - d % 2 for d in images[0].shape[:2])  # H.264 wants even sides
    writer = imageio_ffmpeg.write_frames(
        str(out), (width, height), fps=fps, codec="libx264", pix_fmt_out="yuv420p", macro_block_size=1,
        output_params=["-metadata", f"comment={plots.SOFTWARE}", "-f", "mp4"], ffmpeg_log_level="error",
    )  # fmt: skip
    writer.send(None)
    for image in images:
        writer.send(np.ascontiguousarray(image[:height, :width]))
    writer.close()


def _written_by_fftool(path: Path) -> bool:
    """A GIF with fftool's comment, or an MP4 with it in its metadata."""
    if path.suffix.lower() == ".mp4":
        return b"fftool " in path.read_bytes()  # ffmpeg keeps the comment in the file's metadata box
    try:
        with Image.open(path) as image:
            return image.info.get("comment", b"").decode(errors="replace").startswith("fftool ")
    except OSError:
        return False


ANIMATION = marked_file("an animation", _written_by_fftool)


def animate_test(
    evaluations: Sequence[plots.Evaluation],
    windows: Artifact,
    part: str,
    scenes_dir: Path,
    out: Path,
    *,
    dt_s: float,
    threshold_m: float,
    start: int | None = None,
    frames: int = 40,
    fps: float = 5.0,
    dpi: int = 72,
    best_only: bool = False,
) -> Path:
    """`fftool plot --animate`: `frames` consecutive windows of one test recording, every evaluation a panel.

    The stretch holds `start` (a window id), else the window `plots.pick_windows` ranks first (the predictors
    differ most there, three or more agents).
    """
    benchmark = evaluations[0].benchmark or ""
    data = load_agent_windows(windows, benchmark, part)
    stats = windows.manifest.stats
    if start is None:
        picked = plots.pick_windows(evaluations, 1, data, window_len=int(stats["window_len"]))
        if not picked:
            raise FftoolError(f"{benchmark}/{part}: no window with predictions of every predictor")
        start = picked[0]
    elif start not in set(data.window_id.tolist()):
        raise FftoolError(f"--windows: {start} is not a window id of {benchmark}/{part}")
    ids = stretch(data, start, frames)
    name = SOURCE_SCENE.get(str(data.source[np.flatnonzero(data.window_id == start)[0]]))
    scene = read_scene(scenes_dir / name) if name else None
    movie = recording_movie(evaluations, data, ids, scene, int(stats["obs_len"]), dt_s, best_only, threshold_m)
    return write(render(movie, dpi), out, fps)
