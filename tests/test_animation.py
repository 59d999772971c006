"""Animated scenes: one frame per prediction time drawn by the qualitative figure's code, collisions where two
agents come within γ, GIF (and MP4 where ffmpeg is installed) written atomically, never over a user's file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from PIL import Image
from typer.testing import CliRunner

from fftool.cli import app
from fftool.errors import UsageError
from fftool.reporting import animation

from .test_plots import OBS, recordings
from .test_plots import evaluation as synthetic_evaluation


def test_contacts_are_the_midpoints_of_pairs_closer_than_gamma() -> None:
    paths = np.zeros((3, 2, 4, 2))  # agents, samples, steps
    paths[0, :, :, 0] = np.arange(4)  # agent 0 walks along x
    paths[1, :, :, 0] = np.arange(4)[::-1]  # agent 1 comes the other way: they meet between steps 1 and 2
    paths[1, :, :, 1] = 0.05
    paths[2] = 10.0  # far away
    paths[1, 1] += 5.0  # in sample 1 agent 1 is elsewhere
    close = animation.contacts(paths, 1.1)
    np.testing.assert_allclose(close, [[1.5, 0.025], [1.5, 0.025]])  # steps 1 and 2 of sample 0, |dx| = 1
    assert len(animation.contacts(paths, 0.5)) == 0


def test_a_test_recording_becomes_consecutive_frames_with_one_view(tmp_path: Path) -> None:
    data = recordings({"crowds_zara01": 40, "crowds_zara02": 40}, agents=3)
    evaluations = [synthetic_evaluation(data, v, np.ones(80)) for v in ("baseline", "dr")]
    ids = animation.stretch(data, 50, 12)
    assert ids == list(range(47, 59))  # the same recording, a quarter of the frames before the start
    assert animation.stretch(data, 79, 12) == list(range(68, 80))  # clipped at the recording's end
    movie = animation.recording_movie(evaluations, data, ids, None, OBS, 0.4, False, 0.1)
    assert [f.time_s for f in movie.frames] == pytest.approx([0.4 * (w - 40) for w in ids])
    assert all(len(f.futures) == 2 and f.futures[0].shape == (3, 3, 12, 2) for f in movie.frames)
    assert len(movie.frames[0].trails[0]) == 0 and len(movie.frames[-1].trails[0]) == 11  # trails grow
    images = animation.render(movie, dpi=40)
    assert len(images) == 12 and len({image.shape for image in images}) == 1
    assert not np.array_equal(images[0], images[-1])
    out = animation.write(images, tmp_path / "a.gif", fps=5)
    with Image.open(out) as gif:
        assert gif.n_frames == 12 and gif.info["duration"] == 200 and gif.info["comment"].startswith(b"fftool ")


def test_an_animation_never_replaces_a_users_file(tmp_path: Path) -> None:
    image = [np.zeros((20, 30, 3), np.uint8)] * 2
    mine = tmp_path / "mine.gif"
    Image.fromarray(image[0]).save(mine)
    before = mine.read_bytes()
    with pytest.raises(UsageError, match="not written by fftool"):
        animation.write(image, mine, fps=2)
    assert mine.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["mine.gif"]
    ours = animation.write(image, tmp_path / "ours.gif", fps=2)
    animation.write(image, ours, fps=4)  # its own file may be replaced
    with pytest.raises(UsageError, match=r"\.gif or \.mp4"):
        animation.check_out(tmp_path / "a.avi")


@pytest.mark.skipif(animation.ffmpeg() is None, reason="imageio-ffmpeg not installed (pip install 'fftool[video]')")
def test_mp4_goes_through_ffmpeg_with_fftools_mark(tmp_path: Path) -> None:
    images = [np.full((41, 60, 3), 40 * i, np.uint8) for i in range(5)]  # odd height: cut to even for H.264
    out = animation.write(images, tmp_path / "a.mp4", fps=5)
    assert out.stat().st_size > 0 and animation._written_by_fftool(out)
    animation.write(images, out, fps=5)


def test_predict_animates_a_users_tracks(tiny_cvaes: dict[str, object], tmp_path: Path) -> None:
    root, model_id = tiny_cvaes["root"], tiny_cvaes["baseline"]
    step = np.arange(16)
    rows = {"time": np.r_[step, step] * 0.4, "agent_id": np.repeat([1, 2], 16)}
    rows |= {"x": np.r_[step * 0.5, 8 - step * 0.5], "y": np.r_[step * 0.0, 0.2 + step * 0.0]}
    tracks = tmp_path / "t.csv"
    pd.DataFrame(rows).to_csv(tracks, index=False)
    args = [
        "predict",
        str(tracks),
        "--model",
        model_id,
        "--root",
        str(root),
        "--k",
        "4",
        "--out",
        str(tmp_path / "f.pq"),
    ]
    result = CliRunner().invoke(app, [*args, "--at", "all", "--animate", str(tmp_path / "f.gif"), "--fps", "2"])
    assert result.exit_code == 0, result.output
    with Image.open(tmp_path / "f.gif") as gif:
        assert gif.n_frames == 9 and gif.info["duration"] == 500  # times 2.8 s .. 6.0 s
    result = CliRunner().invoke(app, [*args, "--animate", str(tmp_path / "g.gif")])
    assert result.exit_code == 2 and "--at all" in result.output and not (tmp_path / "g.gif").exists()
