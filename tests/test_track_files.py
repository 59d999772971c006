"""A user's track files (`fftool predict`, custom datasets): generated files, not only hand-written ones.

The property: a file that holds the grid data at another rate, unit or column naming gives the same tracks
on the model's grid as the original (no observation lost to floating-point rounding); and any table the
generator draws is either read into finite tracks or refused with one RawDataError, never a traceback.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from fftool.dataset.steps import to_steps
from fftool.dataset.trackfiles import read_tracks
from fftool.errors import FftoolError, RawDataError

STEP_S = 0.4
# 40 generated inputs per property in the suite; benchmarks/bench_fuzz.py runs them long (FFTOOL_FUZZ_EXAMPLES).
FUZZ_EXAMPLES = int(os.environ.get("FFTOOL_FUZZ_EXAMPLES", "40"))
FUZZ = settings(max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


@st.composite
def grid_tracks(draw: st.DrawFn) -> pd.DataFrame:
    """Agents on the 0.4 s grid: each a run of consecutive steps (at least 2) with positions in metres."""
    agents = draw(st.integers(1, 6))
    rows = []
    for agent in range(agents):
        start = draw(st.integers(0, 30))
        length = draw(st.integers(2, 25))
        x0, y0 = draw(st.floats(-50, 50)), draw(st.floats(-50, 50))
        vx, vy = draw(st.floats(-1.5, 1.5)), draw(st.floats(-1.5, 1.5))
        for step in range(start, start + length):
            k = step - start
            rows.append((step, agent + 1, round(x0 + vx * k * STEP_S, 3), round(y0 + vy * k * STEP_S, 3)))
    return pd.DataFrame(rows, columns=["step", "agent", "x", "y"])


def _steps(path: Path, **reader: object):
    return to_steps(path, read_tracks(path, **reader), STEP_S, max_gap_s=1.0)


def _at_rate(data: pd.DataFrame, frames_per_step: int) -> pd.DataFrame:
    """The same tracks sampled `frames_per_step` times per model step: the grid points and, between them, the
    positions linearly interpolated (what a sensor at that rate would have seen of a straight walk)."""
    parts = []
    for agent, rows in data.groupby("agent"):
        steps = rows["step"].to_numpy()
        frame = np.arange(steps[0] * frames_per_step, steps[-1] * frames_per_step + 1)
        at = frame / frames_per_step
        parts.append(pd.DataFrame({"frame": frame, "agent": agent, "x": np.interp(at, steps, rows["x"]),
                                   "y": np.interp(at, steps, rows["y"])}))  # fmt: skip
    return pd.concat(parts, ignore_index=True)


@FUZZ
@given(
    data=grid_tracks(),
    frames_per_step=st.sampled_from([1, 2, 4, 5, 10]),  # 2.5, 5, 10, 12.5, 25 Hz
    unit=st.sampled_from([("m", 1.0), ("cm", 100.0), ("mm", 1000.0)]),
    names=st.sampled_from([("frame", "ped_id"), ("frame_id", "track_id"), ("time", "agent_id")]),
    offset=st.integers(0, 5000),
)
def test_the_grid_data_at_another_rate_unit_or_naming_gives_the_same_tracks(
    tmp_path: Path, data: pd.DataFrame, frames_per_step: int, unit: tuple[str, float], names: tuple[str, str],
    offset: int,
) -> None:  # fmt: skip
    original = tmp_path / "original.csv"
    pd.DataFrame({"time": data["step"] * STEP_S, "agent_id": data["agent"], "x": data["x"], "y": data["y"]}).to_csv(
        original, index=False
    )
    dense = _at_rate(data, frames_per_step)
    time_col, agent_col = names
    clock = dense["frame"] + offset if time_col != "time" else (dense["frame"] + offset) * (STEP_S / frames_per_step)
    other = tmp_path / "other.csv"
    pd.DataFrame(
        {time_col: clock, agent_col: dense["agent"], "x": dense["x"] * unit[1], "y": dense["y"] * unit[1]}
    ).to_csv(other, index=False)
    expected = _steps(original)
    reader = {"seconds_per_unit": STEP_S / frames_per_step} if time_col != "time" else {}
    got = _steps(other, units=unit[0], **reader)
    assert len(got.step) == len(expected.step) == len(data)  # every observation on the grid is kept
    np.testing.assert_array_equal(got.step, expected.step)
    np.testing.assert_array_equal(got.agent, expected.agent)
    np.testing.assert_allclose(got.xy, expected.xy, atol=1e-6)


@FUZZ
@given(
    cells=st.lists(
        st.tuples(
            st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=3), st.integers(-5, 5)),
            st.one_of(st.integers(0, 3), st.text(max_size=2)),
            st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=32), st.text(max_size=3)),
            st.floats(-1e6, 1e6),
        ),
        max_size=12,
    ),
    header=st.sampled_from(["time,agent_id,x,y", "frame,ped_id,x,y", "t,id,x,y", "time,agent,x", "a,b,c,d"]),
)
@example(cells=[(0.0, 0, 0.0, 0.0), (7.190772539449264e307, 1, 0.0, 0.0)], header="time,agent_id,x,y")  # 1e308 steps
def test_any_generated_table_is_read_or_refused_in_one_line(tmp_path: Path, cells: list, header: str) -> None:
    path = tmp_path / "tracks.csv"
    path.write_text(header + "\n" + "".join(",".join(str(v) for v in row) + "\n" for row in cells))
    try:
        steps = _steps(path, frame_step_s=STEP_S)
    except FftoolError as exc:
        assert isinstance(exc, RawDataError) and "\n" not in str(exc) and str(path) in str(exc)
        return
    assert np.isfinite(steps.xy).all() and len(steps.step) > 0


def test_a_10_hz_recording_keeps_every_observation() -> None:
    """The review's case in miniature: a 10 Hz file (times frame × 0.1 s, most between grid points) whose
    grid times land a hair off the 0.4 s grid lost each agent's first or last observation (ceil/floor of
    -2.9999999997 steps)."""
    frame = np.arange(41)  # 10 Hz: 4 frames per model step
    time = frame * 0.1  # 0.30000000000000004 and friends
    tracks = pd.DataFrame({"time_s": np.r_[time, time[12:]], "agent": np.r_[[1] * 41, [2] * 29],
                           "x": np.r_[time, time[12:]], "y": 0.0})  # fmt: skip
    steps = to_steps(Path("t.csv"), tracks, STEP_S, 1.0)
    assert len(steps.step) == 11 + 8  # agent 1: steps -10..0, agent 2: -7..0
    np.testing.assert_allclose(steps.xy[:, 0], np.r_[np.arange(11), np.arange(3, 11)] * 0.4, atol=1e-12)


@pytest.mark.parametrize("text", ["", "\n"])
def test_an_empty_or_blank_file_is_refused(tmp_path: Path, text: str) -> None:
    path = tmp_path / "tracks.csv"
    path.write_text(text)
    with pytest.raises(RawDataError, match=r"tracks\.csv: "):
        _steps(path)


TOML_VALUES = st.one_of(
    st.integers(-3, 3), st.floats(allow_nan=False, allow_infinity=False, width=32), st.booleans(),
    st.text(alphabet="abcxyz./_-", max_size=8), st.lists(st.text(alphabet="abc.csv", max_size=6), max_size=3),
)  # fmt: skip
TOML_KEYS = st.sampled_from(
    ["name", "time_step_s", "units", "max_gap_s", "scene_image", "homography", "allow_shared_files", "colour"]
)


def _toml_value(value: object) -> str:
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, str):
        return '"' + value + '"'
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return repr(value)


@FUZZ
@given(
    top=st.dictionaries(TOML_KEYS, TOML_VALUES, max_size=5),
    files=st.dictionaries(st.sampled_from(["train", "val", "test", "extra"]), TOML_VALUES, max_size=4),
    columns=st.dictionaries(st.sampled_from(["time", "frame", "agent", "x", "y"]), TOML_VALUES, max_size=3),
)
def test_any_generated_dataset_toml_is_read_or_refused_in_one_line(
    tmp_path: Path, top: dict, files: dict, columns: dict
) -> None:
    from fftool.dataset.custom import load_dataset

    for name in ("a.csv", "b.csv", "c.csv"):
        (tmp_path / name).write_text("time,agent_id,x,y\n0,1,0,0\n0.4,1,0.5,0\n")
    lines = [f"{key} = {_toml_value(value)}" for key, value in top.items()]
    for table, entries in (("files", files), ("columns", columns)):
        lines += [f"[{table}]"] + [f"{key} = {_toml_value(value)}" for key, value in entries.items()]
    path = tmp_path / "dataset.toml"
    path.write_text("\n".join(lines) + "\n")
    try:
        dataset = load_dataset(path)
    except FftoolError as exc:
        assert isinstance(exc, RawDataError) and "\n" not in str(exc) and "dataset.toml" in str(exc)
        return
    assert dataset.spec.time_step_s > 0 and dataset.spec.files.train
