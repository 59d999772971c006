"""Input `fftool predict` and the API refuse at the door, or read as the user meant: each case here was once
mishandled (a silent wrong answer, a raw Python error, or a refusal of a valid file)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from fftool.api import load, predict_tracks
from fftool.cli import app
from fftool.dataset.trackfiles import read_goals, read_tracks
from fftool.errors import InputError, RawDataError

from .test_predict import _walkers, tiny_model  # noqa: F401  (the fixture)


def _predict(tiny: tuple[Path, str], tmp_path: Path, tracks: Path, *extra: str) -> object:
    root, model_id = tiny
    args = ["predict", str(tracks), "--model", model_id, "--root", str(root), "--k", "3"]
    return CliRunner().invoke(app, [*args, "--out", str(tmp_path / "f.parquet"), *extra])


def test_a_csv_with_a_byte_order_mark_reads_like_one_without(tmp_path: Path) -> None:
    plain = _walkers(tmp_path / "plain.csv")
    marked = tmp_path / "excel.csv"
    marked.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())  # Excel's "CSV UTF-8"
    assert read_tracks(marked).equals(read_tracks(plain))


def test_agent_ids_beyond_int64_stay_apart_and_unchanged(tmp_path: Path) -> None:
    path = _walkers(tmp_path / "t.csv")
    frame = pd.read_csv(path)
    frame["agent_id"] = frame["agent_id"].map({1: str(2**64 + 1), 2: str(2**64 + 2)})
    frame.to_csv(path, index=False)
    tracks = read_tracks(path)
    assert sorted(tracks["agent"].unique()) == [str(2**64 + 1), str(2**64 + 2)]


def test_errors_name_lines_and_ids_as_written(tmp_path: Path) -> None:
    path = _walkers(tmp_path / "t.csv")
    frame = pd.read_csv(path)
    frame.loc[3, "x"] = 400.0  # agent 1 jumps 398 m in 0.4 s
    frame.to_csv(path, index=False)
    with pytest.raises(RawDataError, match=r"line 5: agent 1 moves .* at time 1\.2 s"):
        read_tracks(path)


def test_a_goals_file_naming_an_agent_twice_is_refused(tmp_path: Path) -> None:
    goals = tmp_path / "goals.csv"
    goals.write_text("agent_id,x,y\n1,5,0\n2,0,5\n1,9,9\n")
    with pytest.raises(RawDataError, match="line 4: agent 1 has a goal already"):
        read_goals(goals)


def test_seeds_outside_what_a_generator_takes_are_refused(tiny_model: tuple[Path, str], tmp_path: Path) -> None:  # noqa: F811
    tracks = _walkers(tmp_path / "t.csv")
    negative = _predict(tiny_model, tmp_path, tracks, "--seed", "-1")
    assert negative.exit_code == 2 and "--seed" in negative.output and "Traceback" not in negative.output
    model = load(tiny_model[1], root=tiny_model[0])
    for seed in (2**70, 1.5, True):
        with pytest.raises(InputError, match="expected a whole number from 0 to 2\\*\\*63 - 1"):
            predict_tracks(model, read_tracks(tracks), k=3, seed=seed)  # type: ignore[arg-type]


def test_every_prediction_time_asked_for_must_have_agents(tiny_model: tuple[Path, str], tmp_path: Path) -> None:  # noqa: F811
    tracks = _walkers(tmp_path / "t.csv")
    inside_and_after = _predict(tiny_model, tmp_path, tracks, "--at", "3.6,100")
    assert inside_and_after.exit_code == 2 and "--at 100: outside the file's times" in inside_and_after.output
    too_early = _predict(tiny_model, tmp_path, tracks, "--at", "2.0,3.6")  # 2.0 s has only 6 observed steps
    assert too_early.exit_code == 1 and "up to 2 s (asked for)" in too_early.output
    assert _predict(tiny_model, tmp_path, tracks, "--at", "1e300").exit_code == 2
    assert not (tmp_path / "f.parquet").exists()


@pytest.mark.parametrize("offset", [1e30, 1e7])
def test_positions_the_api_refuses_are_refused_by_predict_too(
    tiny_model: tuple[Path, str],  # noqa: F811
    tmp_path: Path,
    offset: float,
) -> None:
    tracks = _walkers(tmp_path / "t.csv")
    frame = pd.read_csv(tracks)
    frame["x"] += offset
    frame.to_csv(tracks, index=False)
    result = _predict(tiny_model, tmp_path, tracks)
    assert result.exit_code == 1 and "not finite coordinates within ±100000 m" in result.output
    assert not (tmp_path / "f.parquet").exists()


def test_goals_far_away_are_refused(tiny_model: tuple[Path, str], tmp_path: Path) -> None:  # noqa: F811
    goals = tmp_path / "goals.csv"
    goals.write_text("agent_id,x,y\n1,1e30,0\n2,0,5\n")
    result = _predict(tiny_model, tmp_path, _walkers(tmp_path / "t.csv"), "--goals", str(goals))
    assert result.exit_code == 1 and "agent 1: goal" in result.output
    assert np.isfinite(read_goals(goals)["x"]).all()


@pytest.mark.parametrize("flag", ["--plot", "--animate"])
def test_a_figure_path_that_cannot_be_written_is_refused_before_predicting(
    tiny_model: tuple[Path, str],  # noqa: F811
    tmp_path: Path,
    flag: str,
) -> None:
    """Once checked only after the futures were written: the Parquet stayed behind and the command failed."""
    (tmp_path / "notes.txt").write_text("a file, not a folder")
    extra = [flag, str(tmp_path / "notes.txt" / "f.gif")] + (["--at", "all"] if flag == "--animate" else [])
    result = _predict(tiny_model, tmp_path, _walkers(tmp_path / "t.csv"), *extra)
    assert result.exit_code == 2 and "notes.txt is a file, not a folder" in " ".join(result.output.split())
    assert not (tmp_path / "f.parquet").exists()


def test_a_crowd_too_large_for_memory_is_refused_before_the_work(tiny_model: tuple[Path, str], tmp_path: Path) -> None:  # noqa: F811
    """1,000 agents at one time once took 357 s and 8.7 GB; 100,000 ended in a raw allocation error."""
    step = np.arange(8) * 0.4
    agents = np.arange(3000)
    rows = pd.DataFrame(
        {"time": np.tile(step, len(agents)), "agent_id": np.repeat(agents, 8),
         "x": np.tile(step, len(agents)) + np.repeat(agents * 1.0, 8), "y": np.repeat(agents * 0.5, 8)}
    )  # fmt: skip
    rows.to_csv(tmp_path / "crowd.csv", index=False)
    result = _predict(tiny_model, tmp_path, tmp_path / "crowd.csv", "--k", "20")
    assert result.exit_code == 1 and "3000 agents at one time with k = 20" in result.output
    assert not (tmp_path / "f.parquet").exists()
